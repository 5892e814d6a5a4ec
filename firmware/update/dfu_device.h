// The USB DFU 1.1 device state machine of the probe (DFU 1.1 spec, Appendix A, "Interface state
// transition diagram" and tables A.2.1–A.2.11). Transport-agnostic: it receives DFU class requests
// (SETUP packet + OUT data) and USB bus resets, and delegates the work (refusing to detach while
// streaming, writing blocks, verifying and marking the slot) to a DfuBackend.
//
// Behaviour in each state (requests not listed stall and, in DFU mode, enter dfuERROR with
// errSTALLEDPKT):
//   appIDLE        DETACH → appDETACH (or stall with the backend's refusal in GETSTATUS/iString);
//                  GETSTATUS, GETSTATE.
//   appDETACH      GETSTATUS, GETSTATE; USB reset → dfuIDLE; wDetachTimeOut elapses → appIDLE.
//   dfuIDLE        DNLOAD (wLength > 0) → dfuDNLOAD-SYNC; ABORT; GETSTATUS; GETSTATE.
//   dfuDNLOAD-SYNC GETSTATUS: the block is written now; → dfuDNBUSY with bwPollTimeout (or
//                  dfuDNLOAD-IDLE when busy reporting is off), → dfuERROR on failure; after the
//                  busy period, GETSTATUS → dfuDNLOAD-IDLE.
//   dfuDNBUSY      any request before bwPollTimeout elapsed stalls (→ dfuERROR).
//   dfuDNLOAD-IDLE DNLOAD (wLength > 0, next block number) → dfuDNLOAD-SYNC; DNLOAD (wLength = 0)
//                  → dfuMANIFEST-SYNC, or stall + errNOTDONE when the image is incomplete;
//                  ABORT → dfuIDLE.
//   dfuMANIFEST-SYNC GETSTATUS: manifestation (verification, mark slot) runs → dfuMANIFEST, or
//                  dfuERROR with the reason; once done (manifestation tolerant) → dfuIDLE.
//   dfuMANIFEST    after bwPollTimeout → dfuMANIFEST-SYNC (tolerant) / dfuMANIFEST-WAIT-RESET.
//   dfuERROR       GETSTATUS, GETSTATE; CLRSTATUS → dfuIDLE.
//   any DFU-mode state: USB reset → the probe reboots (appIDLE), dropping a partial download.
// When bStatus is not OK, GETSTATUS carries iString = dfu::kStrLastError, a string descriptor
// holding the exact reason ("<token>: <details>").
//
// Thread safety: none; one thread (the transport's) calls Handle/OnBusReset.
#pragma once

#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "firmware/update/dfu_protocol.h"

namespace d3d::dfu {

// A backend's answer: bStatus (kOk or an error), the reason, and the busy time it models.
struct BackendReply {
  uint8_t status = kOk;
  std::string message;
  uint32_t poll_ms = 0;
  bool ok() const { return status == kOk; }
};

class DfuBackend {
 public:
  virtual ~DfuBackend() = default;
  // Run-time mode: may the probe leave for DFU mode now? (e.g. not while streaming)
  virtual BackendReply Detach() = 0;
  // First DNLOAD block of a download.
  virtual BackendReply BeginDownload() = 0;
  // Writes one block (called while answering the GETSTATUS that follows its DNLOAD).
  virtual BackendReply DownloadBlock(std::span<const uint8_t> data) = 0;
  // DNLOAD wLength = 0: does the probe hold the whole image? `why_not` gets the reason otherwise.
  virtual bool DownloadComplete(std::string* why_not) = 0;
  // Manifestation: verify the image and mark it bootable.
  virtual BackendReply Manifest() = 0;
  // ABORT, CLRSTATUS, USB reset: drop a partial download.
  virtual void AbortDownload() = 0;
};

struct DfuDeviceOptions {
  uint16_t transfer_size = 4096;      // wTransferSize (max DNLOAD data per request), bytes
  uint16_t detach_timeout_ms = 1000;  // wDetachTimeOut
  uint8_t attributes = kAttrCanDnload | kAttrManifestationTolerant;
  bool report_busy = true;  // dfuDNBUSY after each block, as a device that programs flash does
  int fixed_poll_ms = -1;   // ≥ 0: report this bwPollTimeout instead of the backend's model
  std::function<int64_t()> clock_ms;  // monotonic milliseconds; default std::chrono::steady_clock
  // Throws std::invalid_argument when transfer_size is 0 or upload is requested (not supported).
  void Check() const;
};

struct ControlResponse {
  bool stall = false;
  std::vector<uint8_t> data;  // IN data stage
};

class DfuDevice {
 public:
  DfuDevice(DfuBackend* backend, DfuDeviceOptions options);

  // One DFU class request (bmRequestType 0x21 / 0xA1). `out_data` is the OUT data stage.
  ControlResponse Handle(const SetupPacket& setup, std::span<const uint8_t> out_data);

  enum class ResetAction { kNone, kEnterDfuMode, kReboot };
  // USB bus reset: appDETACH → DFU mode; DFU mode → reboot into run-time mode.
  ResetAction OnBusReset();

  uint8_t state() const { return state_; }
  uint8_t status() const { return status_; }
  const std::string& last_error() const { return error_; }
  bool dfu_mode() const { return state_ >= kDfuIdle; }
  FunctionalDescriptor functional_descriptor() const;
  const DfuDeviceOptions& options() const { return options_; }

 private:
  int64_t Now() const;
  void ApplyTimedTransitions(int64_t now);
  ControlResponse Report(uint32_t poll_ms) const;
  ControlResponse StallError(const SetupPacket& setup);
  void Fail(uint8_t status, std::string message);
  uint32_t Poll(uint32_t modelled) const;

  DfuBackend* backend_;
  DfuDeviceOptions options_;
  uint8_t state_ = kAppIdle;
  uint8_t status_ = kOk;
  std::string error_;
  int64_t deadline_ms_ = 0;  // appDETACH timeout / end of dfuDNBUSY or dfuMANIFEST
  uint16_t next_block_ = 0;
  bool block_written_ = false;
  bool manifest_done_ = false;
  std::vector<uint8_t>
      block_;  // the block between DNLOAD and its GETSTATUS (wTransferSize bytes reserved)
};

}  // namespace d3d::dfu
