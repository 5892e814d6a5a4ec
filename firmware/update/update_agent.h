// The probe's firmware update agent: the USB DFU 1.1 interface (dfu_device.h) over the A/B slot
// manager (slot_manager.h), plus the probe's USB descriptors and d3dscan vendor requests, behind a
// transport-neutral "one control transfer / one bus reset" API. The simulated probe
// (d3d-update-agent) serves it over a Unix socket; a real probe serves it from its USB gadget.
//
// Hosting it in a probe process (d3d-probe) takes a few lines:
//   ProbeUpdateHooks hooks{...};                       // implements ProbeHooks below
//   std::unique_ptr<fw::Flash> flash; fw::Flash::OpenFile(dir + "/flash.bin", geometry, &flash);
//   fw::UpdateAgent agent(flash.get(), pubkey, options, &hooks);
//   agent.PowerOn();                                   // bootloader + health check →
//   OnRunningFirmware ProbeInfo.firmware_version = agent.Info().VersionString();   // and again in
//   OnRunningFirmware
//   // on the USB/sim thread: agent.HandleControl(setup, data) / agent.BusReset()
//
// Thread safety: every method runs on one thread (the transport's). Hooks are called on that
// thread; IsStreaming() must be safe against the streaming thread (e.g. an atomic flag).
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <span>
#include <string>

#include "common/core/status.h"
#include "firmware/update/dfu_device.h"
#include "firmware/update/dfu_protocol.h"
#include "firmware/update/flash_model.h"
#include "firmware/update/image_format.h"
#include "firmware/update/slot_manager.h"

namespace d3d::fw {

enum class HealthResult {
  kHealthy,    // confirms the trial boot
  kUnhealthy,  // the firmware reports failure: immediate rollback
  kNoAnswer,   // the firmware never confirms (hangs): the watchdog resets it until trials run out
};

// What the process hosting the agent provides.
class ProbeHooks {
 public:
  virtual ~ProbeHooks() = default;
  // True while the probe streams bursts; the agent then refuses to enter DFU mode (errVENDOR,
  // "streaming: ..."). Called on the agent's thread.
  virtual bool IsStreaming() const = 0;
  // DFU mode begins (true) / ends (false); the probe must not start streaming in between.
  virtual void OnDfuMode(bool entering) { (void)entering; }
  // The running firmware is known or changed (power-on, confirm, rollback): publish it, e.g. in
  // DDS ProbeInfo.
  virtual void OnRunningFirmware(const dfu::FirmwareInfo& info) { (void)info; }
  // Health check of a new firmware on its trial boot.
  virtual HealthResult HealthCheck(const ImageHeader& running) {
    (void)running;
    return HealthResult::kHealthy;
  }
  // Simulation only (vendor request kVendorSimSetStreaming): start/stop streaming. False = refused.
  virtual bool SimSetStreaming(bool on) {
    (void)on;
    return false;
  }
};

struct UpdateAgentOptions {
  SlotManagerOptions slots;
  dfu::DfuDeviceOptions dfu;
  uint16_t vendor_id = 0x1209;   // pid.codes
  uint16_t product_id = 0x0010;  // pid.codes test PID (placeholder until one is allocated)
  std::string serial = "SIM0001";
  bool sim_controls = false;     // answer kVendorSimSetStreaming
  double verify_mb_per_s = 100;  // modelled verification speed for dfuMANIFEST's bwPollTimeout
};

class UpdateAgent : private dfu::DfuBackend {
 public:
  UpdateAgent(Flash* flash, const PublicKey& trusted_key, UpdateAgentOptions options,
              ProbeHooks* hooks);

  // Power-on / reboot: bootloader, then the new firmware's health check (confirm, or rollback and
  // reboot). kUnavailable/kIoError on flash failure (a power cut); kNotFound when no slot boots.
  Status PowerOn();
  dfu::FirmwareInfo Info() const;
  const BootOutcome& running() const { return slots_.running(); }
  // What the last power-on / reboot did ("trial boot of slot B (1.1.0, ...); health check passed:
  // confirmed"); empty after a bus reset that did not reboot.
  const std::string& boot_log() const { return boot_log_; }
  SlotManager& slots() { return slots_; }
  const dfu::DfuDevice& dfu() const { return dfu_; }
  // True after a flash operation failed with a power cut (the simulated probe then dies).
  bool flash_dead() const { return flash_->power_cut(); }

  // One USB control transfer (standard GET_DESCRIPTOR, DFU class requests, vendor requests).
  dfu::ControlResponse HandleControl(const dfu::SetupPacket& setup,
                                     std::span<const uint8_t> out_data);
  // USB bus reset: enter DFU mode after DETACH, or reboot (PowerOn) from DFU mode.
  Status BusReset();

  std::vector<uint8_t> DeviceDescriptor() const;
  std::vector<uint8_t> ConfigurationDescriptor() const;

 private:
  dfu::BackendReply Detach() override;
  dfu::BackendReply BeginDownload() override;
  dfu::BackendReply DownloadBlock(std::span<const uint8_t> data) override;
  bool DownloadComplete(std::string* why_not) override;
  dfu::BackendReply Manifest() override;
  void AbortDownload() override;
  std::string StringDescriptorText(uint8_t index) const;
  static dfu::BackendReply FromUpdate(const UpdateResult& r);

  Flash* flash_;
  UpdateAgentOptions options_;
  ProbeHooks* hooks_;
  SlotManager slots_;
  dfu::DfuDevice dfu_;
  std::string boot_log_;
};

}  // namespace d3d::fw
