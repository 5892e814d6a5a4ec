#include "firmware/probe/probe_update.h"

#include <cstdio>

#include "firmware/update/sim_link_server.h"

namespace d3d {

void ProbeUpdateHooks::OnDfuMode(bool entering) {
  app_->SetStreamingInhibit(entering ? "firmware update in progress (DFU mode)" : "");
}

void ProbeUpdateHooks::OnRunningFirmware(const dfu::FirmwareInfo& info) {
  app_->SetFirmwareVersion(info.VersionString());
  if (const Status s = app_->PublishInfo(); !s.ok())
    std::fprintf(stderr, "d3d-probe: update agent: republishing ProbeInfo: %s\n",
                 s.ToString().c_str());
}

fw::HealthResult ProbeUpdateHooks::HealthCheck(const fw::ImageHeader& running) {
  (void)running;
  return app_->state().state() == ProbeState::kError ? fw::HealthResult::kUnhealthy
                                                     : fw::HealthResult::kHealthy;
}

void ProbeUpdateOptions::Check() const {
  setup.Check();
  D3D_CHECK_MSG(!socket_path.empty(), "the update link's socket path is required");
}

ProbeUpdateService::ProbeUpdateService(ProbeApp* app, ProbeUpdateOptions options)
    : app_(app), options_(std::move(options)), hooks_(app) {
  D3D_CHECK_MSG(app_ != nullptr, "ProbeUpdateService needs the probe app");
  options_.Check();
}

ProbeUpdateService::~ProbeUpdateService() { Stop(); }

Status ProbeUpdateService::Start() {
  D3D_CHECK_MSG(!thread_.joinable(), "ProbeUpdateService::Start called twice");
  D3D_RETURN_IF_ERROR(fw::OpenUpdateAgent(options_.setup, options_.agent, &hooks_, &setup_));
  D3D_RETURN_IF_ERROR(setup_.agent->PowerOn());
  boot_log_ = setup_.agent->boot_log();
  thread_ = std::thread([this] {
    fw::SimLinkServerOptions so;
    so.socket_path = options_.socket_path;
    so.on_reset = [this](const Status& s) {
      if (!s.ok())
        std::fprintf(stderr, "d3d-probe: update agent: reboot: %s\n", s.ToString().c_str());
      else if (!setup_.agent->boot_log().empty())
        std::fprintf(stderr, "d3d-probe: update agent: reboot: %s\n",
                     setup_.agent->boot_log().c_str());
    };
    const Status s = fw::ServeSimLink(setup_.agent.get(), so, &stop_);
    if (!s.ok()) std::fprintf(stderr, "d3d-probe: update agent: %s\n", s.ToString().c_str());
    std::lock_guard<std::mutex> lock(serve_mu_);
    serve_status_ = s;
  });
  return Status::Ok();
}

void ProbeUpdateService::Stop() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
}

Status ProbeUpdateService::serve_status() const {
  std::lock_guard<std::mutex> lock(serve_mu_);
  return serve_status_;
}

}  // namespace d3d
