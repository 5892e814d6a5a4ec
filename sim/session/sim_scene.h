// The virtual probe's world without the renderer: the scene (procedural typodont or a mesh file),
// the hand trajectory (a scan style, quadrant or a TUM file) and the burst clock. SimSession adds
// the renderer; what only needs the truth of a scan (d3d-scan --reference) uses this and does not
// link Embree.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "common/core/status.h"
#include "common/mesh/mesh.h"
#include "sim/trajectory/scan_path.h"
#include "sim/trajectory/scan_styles.h"
#include "sim/typodont/typodont.h"

namespace d3d {

struct SimSceneOptions {
  std::string model = "typodont";  // "typodont" or a mesh file (PLY/STL/OBJ, millimetres)
  std::string trajectory =
      "full-arch";  // a scan style (scan_styles.h: full-arch, lifts, ...), quadrant, or a TUM file
  uint32_t seed = 1;            // hand motion (scan path)
  double burst_rate_hz = 30.0;  // bursts per second of trajectory time
  int64_t frame_interval_ns =
      2'500'000;  // between the frames of a burst (RenderOptions::frame_interval_ns)
  TypodontOptions typodont;
  ScanPathOptions scan_path;  // its seed is replaced by `seed`
  void Check() const;         // throws std::invalid_argument
};

class SimScene {
 public:
  // Builds the scene and the trajectory. NOT_FOUND/PARSE_ERROR/... for a model or trajectory file
  // that cannot be read, INVALID_ARGUMENT for a mesh that is not an arch (when a scan path must be
  // generated for it). Throws std::invalid_argument for invalid options.
  [[nodiscard]] static Status Create(const SimSceneOptions& options, SimScene* out);

  const SimSceneOptions& options() const { return options_; }
  const TriangleMesh& scene() const { return scene_; }
  const Trajectory& trajectory() const { return trajectory_; }
  // Pass structure of a generated scan path (empty for a trajectory read from a file).
  const std::vector<ScanSegment>& segments() const { return segments_; }
  // Burst i starts at StartNs + i / rate (ns).
  int64_t BurstStartNs(int64_t index) const;
  // Bursts of `frames` frames whose frames all lie within the trajectory.
  int64_t NumBursts(int frames) const;
  // The middle of burst i of `frames` frames (ns): the time of its true pose.
  int64_t BurstMiddleNs(int64_t index, int frames) const;

 private:
  SimSceneOptions options_;
  TriangleMesh scene_;
  Trajectory trajectory_;
  std::vector<ScanSegment> segments_;
};

}  // namespace d3d
