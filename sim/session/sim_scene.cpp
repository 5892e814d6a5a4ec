#include "sim/session/sim_scene.h"

#include <cmath>
#include <filesystem>

#include "common/mesh/mesh_io.h"

namespace d3d {

void SimSceneOptions::Check() const {
  D3D_CHECK_MSG(!model.empty(), "model must be 'typodont' or a mesh file");
  D3D_CHECK_MSG(!trajectory.empty(),
                "trajectory must be a scan style (scan_styles.h), quadrant or a TUM file");
  D3D_CHECK_MSG(burst_rate_hz > 0 && burst_rate_hz <= 1000,
                "burst rate must be in (0, 1000] Hz, got " << burst_rate_hz);
  D3D_CHECK_MSG(frame_interval_ns > 0, "frame interval must be > 0 ns, got " << frame_interval_ns);
  typodont.Check();
}

Status SimScene::Create(const SimSceneOptions& options, SimScene* out) {
  options.Check();
  SimScene s;
  s.options_ = options;
  if (options.model == "typodont") {
    s.scene_ = MakeTypodont(options.typodont);
  } else {
    D3D_RETURN_IF_ERROR(LoadMesh(options.model, &s.scene_));
    if (s.scene_.face_labels.empty() && !s.scene_.face_colors.empty())
      LabelFacesFromColors(&s.scene_);
  }
  const std::string& t = options.trajectory;
  if (t == "quadrant" || IsScanStyle(t)) {
    ScanPathOptions path = options.scan_path;
    path.seed = options.seed;
    ScanPathResult result = t == "quadrant"
                                ? MakeScanTrajectory(s.scene_, ScanKind::kQuadrant, path)
                                : MakeStyledScan(s.scene_, t, path);
    if (!result.ok())
      return {result.status.code(),
              "scan path for '" + options.model + "': " + result.status.message()};
    s.trajectory_ = std::move(result.trajectory);
    s.segments_ = std::move(result.segments);
  } else {
    if (!std::filesystem::exists(t)) {
      return NotFound("scan path '" + t + "': neither a scan style (" + ScanStyleList(", ") +
                      "), quadrant, nor a TUM file");
    }
    D3D_RETURN_IF_ERROR(Trajectory::LoadTum(t, &s.trajectory_));
  }
  *out = std::move(s);
  return Status::Ok();
}

int64_t SimScene::BurstStartNs(int64_t index) const {
  return trajectory_.StartNs() + static_cast<int64_t>(std::llround(static_cast<double>(index) *
                                                                   1e9 / options_.burst_rate_hz));
}

int64_t SimScene::NumBursts(int frames) const {
  const int64_t burst_span = (frames - 1) * options_.frame_interval_ns;
  const double usable_s =
      static_cast<double>(trajectory_.EndNs() - trajectory_.StartNs() - burst_span) * 1e-9;
  return usable_s < 0 ? 0 : static_cast<int64_t>(std::floor(usable_s * options_.burst_rate_hz)) + 1;
}

int64_t SimScene::BurstMiddleNs(int64_t index, int frames) const {
  return BurstStartNs(index) + (frames - 1) * options_.frame_interval_ns / 2;
}

}  // namespace d3d
