// The firmware-update agent hosted in the probe's acquisition process (issue 8 wiring): the
// agent (firmware/update) sees the probe through ProbeUpdateHooks, and ProbeUpdateService owns the
// flash, the agent and the thread serving its transport.
//
// Threads and ownership:
//   - Start() (caller's thread, once, after ProbeApp::Start()): opens the flash, provisions a blank
//     one, powers the agent on (boot + health check → ProbeInfo.firmware_version), then starts the
//     transport thread. After that only the transport thread touches the agent and the flash.
//   - the transport thread: ServeSimLink (our machines: USB control transfers over a Unix socket;
//     on the hardware the USB gadget's EP0 handler calls agent.HandleControl / BusReset instead).
//     The hooks it calls only use ProbeApp's thread-safe methods.
//   - Stop() / the destructor (caller's thread): asks the transport thread to stop and joins it.
//
// Behaviour the probe guarantees (issue 8): DETACH is refused while the probe streams ("streaming:
// ..."); during the DFU session CMD_START_STREAMING is refused (UNAVAILABLE, "firmware update in
// progress"); when the session ends, rejected or not, streaming commands are accepted again; the
// running firmware (version after power-on, confirm or rollback) is republished in ProbeInfo.
#pragma once

#include <atomic>
#include <mutex>
#include <string>
#include <thread>

#include "common/core/status.h"
#include "firmware/probe/probe_app.h"
#include "firmware/update/agent_setup.h"
#include "firmware/update/update_agent.h"

namespace d3d {

// fw::ProbeHooks on a running ProbeApp (borrowed; must outlive the hooks).
class ProbeUpdateHooks final : public fw::ProbeHooks {
 public:
  explicit ProbeUpdateHooks(ProbeApp* app) : app_(app) {}
  bool IsStreaming() const override { return app_->state().IsStreaming(); }
  // Inhibits streaming starts for the DFU session, lifts the inhibit when it ends.
  void OnDfuMode(bool entering) override;
  // ProbeInfo.firmware_version = info.VersionString(), re-published.
  void OnRunningFirmware(const dfu::FirmwareInfo& info) override;
  // Healthy unless the probe is in its error state (camera, projector and DDS came up: Start()
  // succeeded before the agent powers on).
  fw::HealthResult HealthCheck(const fw::ImageHeader& running) override;
  // Vendor request of the sim link (UpdateAgentOptions::sim_controls): start/stop streaming.
  bool SimSetStreaming(bool on) override { return app_->SetStreaming(on).ok(); }

 private:
  ProbeApp* app_;
};

struct ProbeUpdateOptions {
  fw::AgentSetupOptions setup;   // flash directory, trusted key, factory image
  fw::UpdateAgentOptions agent;  // slots (hw id, slot size), DFU, USB ids
  std::string socket_path;       // the sim link's Unix socket
  void Check() const;            // throws std::invalid_argument
};

class ProbeUpdateService {
 public:
  // `app` is borrowed and must outlive the service. Throws for invalid options.
  ProbeUpdateService(ProbeApp* app, ProbeUpdateOptions options);
  ~ProbeUpdateService();  // Stop()
  ProbeUpdateService(const ProbeUpdateService&) = delete;
  ProbeUpdateService& operator=(const ProbeUpdateService&) = delete;

  // See the thread notes above. The key/flash/image file errors of fw::OpenUpdateAgent;
  // NOT_FOUND when no slot holds a bootable signed image (the probe has no firmware to run).
  [[nodiscard]] Status Start();
  void Stop();
  // What power-on did, e.g. "boot slot A (1.0.0, confirmed)". Valid after Start().
  const std::string& boot_log() const { return boot_log_; }
  // The transport thread's final status (OK after Stop(); an error if it could not bind the
  // socket).
  Status serve_status() const;

 private:
  ProbeApp* app_;
  ProbeUpdateOptions options_;
  ProbeUpdateHooks hooks_;
  fw::AgentSetup setup_;
  std::string boot_log_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
  mutable std::mutex serve_mu_;
  Status serve_status_;  // guarded by serve_mu_
};

}  // namespace d3d
