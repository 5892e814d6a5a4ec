#include "firmware/probe/capture_backend.h"

namespace d3d {

void CaptureOptions::Check() const {
  D3D_CHECK_MSG(rate_hz > 0 && rate_hz <= 1000,
                "burst rate must be in (0, 1000] Hz, got " << rate_hz);
  D3D_CHECK_MSG(sim_cycle >= 1, "sim_cycle must be ≥ 1, got " << sim_cycle);
  D3D_CHECK_MSG(max_bursts >= 0, "max_bursts must be ≥ 0");
  D3D_CHECK_MSG(sim_fault_rate >= 0 && sim_fault_rate <= 1,
                "sim_fault_rate must be in [0, 1], got " << sim_fault_rate);
  D3D_CHECK_MSG((width == 640 && height == 480) || (width == 1280 && height == 1024),
                "camera must be 640x480 or 1280x1024");
}

void CaptureBackendRegistry::Register(const std::string& name, Factory factory, bool real_camera) {
  D3D_CHECK_MSG(!name.empty() && name != "auto", "backend name must be non-empty and not 'auto'");
  D3D_CHECK_MSG(entries_.count(name) == 0, "capture backend '" << name << "' registered twice");
  entries_[name] = {std::move(factory), real_camera};
  order_.push_back(name);
}

std::vector<std::string> CaptureBackendRegistry::Names() const { return order_; }

Status CaptureBackendRegistry::CreateAndOpen(const std::string& name, const CaptureOptions& options,
                                             std::unique_ptr<CaptureBackend>* out) const {
  options.Check();
  if (name == "auto") {
    std::string tried;
    for (const std::string& n : order_) {
      const Entry& e = entries_.at(n);
      if (!e.real_camera) continue;
      std::unique_ptr<CaptureBackend> b = e.factory(options);
      const Status s = b->Open();
      if (s.ok()) {
        *out = std::move(b);
        return s;
      }
      tried.append(tried.empty() ? "" : "; ").append(n).append(": ").append(s.message());
    }
    return Unavailable("no camera found (" +
                       (tried.empty() ? std::string("no real-camera backend built in") : tried) +
                       "); use --sim typodont|MESH for the virtual probe");
  }
  const auto it = entries_.find(name);
  if (it == entries_.end()) {
    std::string known;
    for (const auto& n : order_) known.append(" ").append(n);
    return InvalidArgument("unknown capture backend '" + name + "' (known: auto" + known + ")");
  }
  std::unique_ptr<CaptureBackend> b = it->second.factory(options);
  D3D_RETURN_IF_ERROR(b->Open());
  *out = std::move(b);
  return Status::Ok();
}

void RegisterBuiltinCaptureBackends(CaptureBackendRegistry* registry) {
  registry->Register("sim", MakeSimCaptureBackend, /*real_camera=*/false);
  registry->Register("libcamera", MakeLibcameraCaptureBackend, /*real_camera=*/true);
}

}  // namespace d3d
