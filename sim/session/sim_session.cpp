#include "sim/session/sim_session.h"

namespace d3d {

SimSceneOptions SimSessionOptions::Scene() const {
  SimSceneOptions o;
  o.model = model;
  o.trajectory = trajectory;
  o.seed = seed;
  o.burst_rate_hz = burst_rate_hz;
  o.frame_interval_ns = render.frame_interval_ns;
  o.typodont = typodont;
  o.scan_path = scan_path;
  return o;
}

void SimSessionOptions::Check() const {
  render.Check();
  Scene().Check();
}

Status SimSession::Create(const SimSessionOptions& options, std::unique_ptr<SimSession>* out) {
  options.Check();
  std::unique_ptr<SimSession> s(new SimSession());
  s->options_ = options;
  D3D_RETURN_IF_ERROR(SimScene::Create(options.Scene(), &s->world_));
  const std::string& t = options.trajectory;
  ProbeDesign design = MakeDefaultProbeDesign(options.camera_width, options.camera_height);
  if (IsScanStyle(t)) {  // the style's scene: wet teeth for "glare"
    design.enamel.specular_r0 *= ScanStyleWetness(t);
    design.gingiva.specular_r0 *= ScanStyleWetness(t);
  }
  design.calibration.pattern.texture_frame = options.texture_frame;
  s->probe_ = std::make_unique<VirtualProbe>(s->world_.scene(), design, options.render);
  *out = std::move(s);
  return Status::Ok();
}

int64_t SimSession::BurstStartNs(int64_t index) const { return world_.BurstStartNs(index); }

int64_t SimSession::NumBursts() const {
  return world_.NumBursts(static_cast<int>(probe_->burst_patterns().frames.size()));
}

Burst SimSession::RenderBurst(int64_t index, bool with_truth) {
  const PoseAtTime pose = [this](int64_t t_ns) { return world_.trajectory().WorldFromProbe(t_ns); };
  return probe_->RenderBurst(pose, BurstStartNs(index), static_cast<uint64_t>(index), options_.seed,
                             with_truth);
}

}  // namespace d3d
