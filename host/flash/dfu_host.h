// The host's USB DFU 1.1 layer: one implementation of the request sequence (DFU 1.1 spec §6–7,
// Appendix A) over any DfuTransport, so the simulated link exercises exactly what a real probe
// gets.
//
// Flash sequence (FlashImage):
//   1. GET_DESCRIPTOR (device, configuration with the DFU functional descriptor: wTransferSize,
//      attributes; serial) and the vendor request GET_FIRMWARE_INFO (version before).
//   2. Run-time mode: DFU_DETACH (wValue = wDetachTimeOut); a STALL means the probe refused —
//      DFU_GETSTATUS + the iString descriptor give the reason (e.g. streaming). Then a USB reset
//      (bitWillDetach = 0) and re-enumeration in DFU mode. A probe already in DFU mode is brought
//      to dfuIDLE (DFU_CLRSTATUS from dfuERROR, DFU_ABORT otherwise).
//   3. Per block n = 0, 1, …: DFU_DNLOAD(wValue = n, ≤ wTransferSize bytes), then DFU_GETSTATUS
//      until dfuDNLOAD-IDLE, sleeping bwPollTimeout while dfuDNBUSY. dfuERROR ends the transfer
//      with the probe's reason.
//   4. DFU_DNLOAD with wLength = 0, then DFU_GETSTATUS through dfuMANIFEST-SYNC / dfuMANIFEST
//      (the probe verifies size, hash, signature, hardware id, counter) until dfuIDLE
//      (manifestation tolerant) or dfuMANIFEST-WAIT-RESET.
//   5. USB reset: the probe reboots into the new slot (trial boot, health check); re-enumerate and
//      read the firmware info again (version after, confirmed / rolled back).
// On a refusal the host clears the error (DFU_CLRSTATUS), resets the probe back to run-time mode
// and reads the version it still runs.
#pragma once

#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "common/core/status.h"
#include "firmware/update/dfu_protocol.h"
#include "host/flash/dfu_transport.h"

namespace d3d::flash {

struct DfuDeviceInfo {
  uint16_t vendor_id = 0, product_id = 0;
  std::string serial, product;
  uint8_t interface_number = 0;
  bool dfu_mode = false;  // interface protocol 2
  dfu::FunctionalDescriptor functional;
};

// The DFU class requests, one control transfer each, counting transfers.
class DfuHost {
 public:
  explicit DfuHost(DfuTransport* transport) : t_(transport) {}
  DfuTransport* transport() { return t_; }

  // Device and configuration descriptors (DFU interface, functional descriptor) and strings.
  Status ReadDescriptors(DfuDeviceInfo* out);
  Status GetStatus(dfu::StatusReport* out);
  Status GetState(uint8_t* out);
  // The following return kUnavailable on a link failure and kUnsupported "stalled" on a STALL.
  Status Detach(uint16_t timeout_ms);
  Status Dnload(uint16_t block, std::span<const uint8_t> data);
  Status ClrStatus();
  Status Abort();
  Status GetString(uint8_t index, std::string* out);
  Status GetFirmwareInfo(dfu::FirmwareInfo* out);
  Status SetSimStreaming(bool on);  // simulation control (d3d-update-agent --sim-controls)
  // DFU_GETSTATUS until the state is no longer dfuDNBUSY / dfuMANIFEST (or the manifestation-sync
  // step that follows), sleeping bwPollTimeout between polls. Returns the last report.
  Status PollWhileBusy(dfu::StatusReport* out);
  // "errFILE (unknown-key: ...)" for a report in dfuERROR (reads the iString).
  std::string DescribeError(const dfu::StatusReport& r);

  int64_t control_transfers() const { return transfers_; }
  double poll_wait_ms() const { return poll_wait_ms_; }

 private:
  ControlResult In(uint8_t type, uint8_t request, uint16_t value, uint16_t length,
                   std::vector<uint8_t>* out);
  ControlResult Out(uint8_t type, uint8_t request, uint16_t value, std::span<const uint8_t> data);
  static Status Check(const ControlResult& r, const char* what);

  DfuTransport* t_;
  uint16_t interface_ = 0;
  bool manifestation_tolerant_ = true;
  int64_t transfers_ = 0;
  double poll_wait_ms_ = 0;
  std::vector<uint8_t> scratch_;
};

enum class FlashOutcome {
  kUpdated,     // the probe runs the new image, confirmed
  kRefused,     // the probe refused the image (reason given); it still runs the old version
  kRolledBack,  // the new image did not confirm its health check; the probe runs the old one
  kDryRun,      // nothing was sent
  kLinkLost,    // the link dropped (unplugged / power loss); the probe boots a good version
  kError,       // anything else (protocol error)
};
const char* FlashOutcomeName(FlashOutcome o);

struct FlashOptions {
  bool dry_run = false;
  int reconnect_timeout_ms = 15000;
  // Called after every block: bytes sent, total bytes.
  std::function<void(uint64_t, uint64_t)> progress;
  // Called once the probe's descriptors and firmware info are read (before anything changes).
  std::function<void(const DfuDeviceInfo&, const dfu::FirmwareInfo&)> on_connected;
  // Stop after sending this many blocks (tests: cut the transfer at block k); -1 = never.
  int64_t stop_after_blocks = -1;
};

struct FlashReport {
  FlashOutcome outcome = FlashOutcome::kError;
  std::string reason;      // the probe's exact reason, or what failed on the host
  uint8_t dfu_status = 0;  // bStatus of a refusal
  DfuDeviceInfo device;
  dfu::FirmwareInfo before, after;
  bool have_after = false;
  uint64_t bytes = 0;
  int64_t blocks = 0;
  int64_t control_transfers = 0;   // all of them, descriptors to final info
  int64_t download_transfers = 0;  // DNLOAD + GETSTATUS of the blocks
  double download_s = 0, manifest_s = 0, reboot_s = 0, total_s = 0;
  double poll_wait_ms = 0;  // time spent honouring bwPollTimeout
};

// Runs the whole sequence above. Never throws; the report says what happened.
FlashReport FlashImage(DfuTransport* transport, std::span<const uint8_t> image,
                       const FlashOptions& options);

}  // namespace d3d::flash
