#include "firmware/sim/session/sim_session.h"

#include <cmath>
#include <filesystem>

#include "common/mesh/mesh_io.h"

namespace d3d {

void SimSessionOptions::Check() const {
  D3D_CHECK_MSG(!model.empty(), "model must be 'typodont' or a mesh file");
  D3D_CHECK_MSG(!trajectory.empty(), "trajectory must be a scan style (scan_styles.h), quadrant or a TUM file");
  D3D_CHECK_MSG(burst_rate_hz > 0 && burst_rate_hz <= 1000, "burst rate must be in (0, 1000] Hz, got " << burst_rate_hz);
  render.Check();
  typodont.Check();
}

Status SimSession::Create(const SimSessionOptions& options, std::unique_ptr<SimSession>* out) {
  options.Check();
  std::unique_ptr<SimSession> s(new SimSession());
  s->options_ = options;
  if (options.model == "typodont") {
    s->scene_ = MakeTypodont(options.typodont);
  } else {
    D3D_RETURN_IF_ERROR(LoadMesh(options.model, &s->scene_));
    if (s->scene_.face_labels.empty() && !s->scene_.face_colors.empty()) LabelFacesFromColors(&s->scene_);
  }
  const std::string& t = options.trajectory;
  if (t == "quadrant" || IsScanStyle(t)) {
    ScanPathOptions path = options.scan_path;
    path.seed = options.seed;
    ScanPathResult result = t == "quadrant" ? MakeScanTrajectory(s->scene_, ScanKind::kQuadrant, path) : MakeStyledScan(s->scene_, t, path);
    if (!result.ok()) return {result.status.code(), "scan path for '" + options.model + "': " + result.status.message()};
    s->trajectory_ = std::move(result.trajectory);
    s->segments_ = std::move(result.segments);
  } else {
    if (!std::filesystem::exists(t)) {
      return NotFound("scan path '" + t + "': neither a scan style (" + ScanStyleList(", ") + "), quadrant, nor a TUM file");
    }
    D3D_RETURN_IF_ERROR(Trajectory::LoadTum(t, &s->trajectory_));
  }
  ProbeDesign design = MakeDefaultProbeDesign(options.camera_width, options.camera_height);
  if (IsScanStyle(t)) {  // the style's scene: wet teeth for "glare"
    design.enamel.specular_r0 *= ScanStyleWetness(t);
    design.gingiva.specular_r0 *= ScanStyleWetness(t);
  }
  design.calibration.pattern.texture_frame = options.texture_frame;
  s->probe_ = std::make_unique<VirtualProbe>(s->scene_, design, options.render);
  *out = std::move(s);
  return Status::Ok();
}

int64_t SimSession::BurstStartNs(int64_t index) const {
  return trajectory_.StartNs() + static_cast<int64_t>(std::llround(static_cast<double>(index) * 1e9 / options_.burst_rate_hz));
}

int64_t SimSession::NumBursts() const {
  const auto frames = static_cast<int64_t>(probe_->burst_patterns().frames.size());
  const int64_t burst_span = (frames - 1) * options_.render.frame_interval_ns;
  const double usable_s = static_cast<double>(trajectory_.EndNs() - trajectory_.StartNs() - burst_span) * 1e-9;
  return usable_s < 0 ? 0 : static_cast<int64_t>(std::floor(usable_s * options_.burst_rate_hz)) + 1;
}

Burst SimSession::RenderBurst(int64_t index, bool with_truth) {
  const PoseAtTime pose = [this](int64_t t_ns) { return trajectory_.WorldFromProbe(t_ns); };
  return probe_->RenderBurst(pose, BurstStartNs(index), static_cast<uint64_t>(index), options_.seed, with_truth);
}

}  // namespace d3d
