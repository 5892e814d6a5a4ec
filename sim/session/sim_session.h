// A simulated scanning session: the scene (procedural typodont or a mesh file), the hand
// trajectory, the virtual probe, and the burst clock. Shared by d3d-sim, and by the tools of later
// stages that scan with the virtual probe (d3d-probe --sim, d3d-recon --sim, d3d-fuse --sim).
#pragma once

#include <memory>
#include <string>

#include "common/burst/burst.h"
#include "common/core/status.h"
#include "sim/render/virtual_probe.h"
#include "sim/session/sim_scene.h"
#include "sim/trajectory/scan_path.h"
#include "sim/trajectory/scan_styles.h"
#include "sim/typodont/typodont.h"

namespace d3d {

struct SimSessionOptions {
  std::string model = "typodont";  // "typodont" or a mesh file (PLY/STL/OBJ, millimetres)
  std::string trajectory =
      "full-arch";  // a scan style (scan_styles.h: full-arch, lifts, ...), quadrant, or a TUM file
  uint32_t seed = 1;            // hand motion (scan path) and sensor noise
  double burst_rate_hz = 30.0;  // bursts per second of trajectory time
  int camera_width = 640;       // 640 × 480 or 1280 × 1024 (probe_design.h)
  int camera_height = 480;
  bool texture_frame = false;  // bursts get a 5th, uniformly lit frame (probe pattern set)
  RenderOptions render;
  TypodontOptions typodont;
  ScanPathOptions scan_path;  // its seed is replaced by `seed`
  // The scene's part of these options (what SimScene builds; the frame interval is the render's).
  SimSceneOptions Scene() const;
  void Check() const;  // throws std::invalid_argument
};

class SimSession {
 public:
  // Builds the scene, the trajectory and the probe. NOT_FOUND/PARSE_ERROR/... for a model or
  // trajectory file that cannot be read, INVALID_ARGUMENT for a mesh that is not an arch (when a
  // scan path must be generated for it). Throws std::invalid_argument for invalid options.
  [[nodiscard]] static Status Create(const SimSessionOptions& options,
                                     std::unique_ptr<SimSession>* out);

  const SimSessionOptions& options() const { return options_; }
  const TriangleMesh& scene() const { return world_.scene(); }
  const Trajectory& trajectory() const { return world_.trajectory(); }
  // Pass structure of a generated scan path (empty for a trajectory read from a file).
  const std::vector<ScanSegment>& segments() const { return world_.segments(); }
  // The scene, the trajectory and the burst clock (no renderer).
  const SimScene& world() const { return world_; }
  VirtualProbe& probe() { return *probe_; }
  const ProbeCalibration& calibration() const { return probe_->calibration(); }

  // Bursts of the trajectory at burst_rate_hz: burst i starts at StartNs + i / rate and all its
  // frames lie within the trajectory.
  int64_t NumBursts() const;
  int64_t BurstStartNs(int64_t index) const;
  // Renders burst `index` (sequence = index), noise seeded from (seed, index).
  Burst RenderBurst(int64_t index, bool with_truth);

 private:
  SimSession() = default;
  SimSessionOptions options_;
  SimScene world_;
  std::unique_ptr<VirtualProbe> probe_;
};

}  // namespace d3d
