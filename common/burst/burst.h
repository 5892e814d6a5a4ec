// A phase-shift burst: the camera frames captured under successive projector frames, with their
// capture timestamps and, for simulated bursts, the ground truth of every pixel.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "common/core/rigid.h"

namespace d3d {

// Ground truth of one frame at its timestamp (simulation only). Maps are H×W like the image.
struct FrameTruth {
  Rigid3d world_from_probe = Rigid3d::Identity();  // probe (= camera) pose at the timestamp
  cv::Mat depth_mm;       // CV_32F: camera-frame z of the visible surface, NaN where none
  cv::Mat points_in_cam;  // CV_32FC3: the visible surface point, mm, NaN where none
  cv::Mat projector_uv;   // CV_32FC2: projector pixel lighting the point, NaN where not lit
  cv::Mat visibility;  // CV_8U: 0 no surface, 1 surface not lit (shadow/outside/back-facing), 2 lit
  cv::Mat label;       // CV_8U: SurfaceLabel of the visible surface (0 where none)
  cv::Mat face_index;  // CV_32S: triangle of the scene mesh, −1 where none (or an analytic shape)
  bool has_maps() const { return !depth_mm.empty(); }
};

struct BurstFrame {
  std::string pattern;       // projector frame name, e.g. "phase4-marker/2", "texture"
  cv::Mat image;             // H×W CV_8U (CV_16U for sensors deeper than 8 bits)
  int64_t timestamp_ns = 0;  // middle of the exposure
  FrameTruth truth;          // pose always set by the simulator; maps only when requested
};

struct Burst {
  uint64_t sequence = 0;
  std::vector<BurstFrame> frames;  // in projection order
  // Simulation only: the truth at the burst's reference time, the middle between the first and the
  // last exposure, which is what a reconstruction of the whole burst measures when the probe moves.
  int64_t reference_ns = 0;
  FrameTruth reference_truth;  // maps empty unless rendered with truth
  // false: no frame's truth pose is known (a burst exported from a recording): burst.json leaves
  // world_from_probe out rather than write the identity.
  bool poses_known = true;
};

}  // namespace d3d
