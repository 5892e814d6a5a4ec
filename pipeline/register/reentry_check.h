// Visibility check of a re-entry: before a view that had lost the model is placed on it again, the
// keyframes near the candidate pose must not contradict what the view saw from there.
//
// Why: after a loss, a single view of a smooth stretch (the end of the arch) fits a neighbouring
// tooth by ICP with a residual and an overlap like a true re-entry (typodont full arch, seed 5
// burst 184: 9.3 µm, overlap 0.48, 2.3 mm and 12.7° off; seed 6 burst 154: 11.7 mm, 24° off), and
// the rest of the scan is built on it. ICP only asks whether the view's points lie near model
// surface; a wrong pose also puts points where the model has seen empty space, and puts model
// surface in front of what the view saw. That is the free-space violation of visibility-based depth
// map fusion (Merrell et al. 2007, "Real-time visibility-based fusion of depth maps", ICCV, §3.2),
// tested here both ways between the view and each keyframe near the candidate:
//  - a view point that a keyframe saw through (the keyframe's depth along that ray lies more than
//    margin_mm beyond it) is a violation;
//  - a keyframe point that the view saw through is a violation too.
// A point that lies within agree_mm of the other's depth agrees; one behind the other's surface
// (occluded) or outside its image says nothing. The candidate passes when violations are at most
// max_violation_fraction of the points that met the other's surface (violations + agreements),
// tested over enough of them (min_tested); with fewer the check cannot judge and passes.
//
// Depth images: each side's samples (camera frame) projected into a pinhole grid `grid_scale` of
// the camera's size, each cell the nearest depth through it. A point compares with the 3 × 3 cells
// around its projection: a violation needs at least 5 of them to hold a depth and the nearest of
// them beyond the point (a ray that grazed an edge next to it does not count), agreement any of
// them within agree_mm.
//
// Threads: one ReentryCheck per tracker, used by Track()'s thread only; its grids are reused.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "calib/model/camera_model.h"
#include "common/core/rigid.h"
#include "pipeline/register/icp.h"
#include "pipeline/register/surface_points.h"

namespace d3d {

struct ReentryCheckOptions {
  bool enabled = true;
  // The keyframes it is tested against: the nearest by surface centre (the centroid of the view's
  // points at the candidate pose against each keyframe's) ...
  int keyframes = 4;
  double max_centre_distance_mm = 6;  // ... within this distance (a view is ~16 × 12 mm)
  double grid_scale = 0.25;           // depth grid size / camera image size (a cell per 4 × 4 px)
  double margin_mm = 0.5;             // depth beyond a point that counts as seen through it
  double agree_mm = 0.15;             // within this depth a point agrees with the other's surface
  double max_violation_fraction = 0.05;  // of violations + agreements
  int64_t min_tested = 200;              // fewer violations + agreements: no verdict (passes)
  void Check() const;                    // throws std::invalid_argument
};

// What the keyframes near a candidate pose say of a view placed there.
struct ReentryEvidence {
  bool ok = true;            // passes (also when not enough was tested)
  int keyframes = 0;         // keyframes compared
  int64_t agreeing = 0;      // points on the other's surface (both ways, all keyframes)
  int64_t seen_through = 0;  // points the other saw through
  double violation_fraction() const {
    const int64_t n = agreeing + seen_through;
    return n > 0 ? static_cast<double>(seen_through) / static_cast<double>(n) : 0.0;
  }
  std::string reason;  // why not ok
};

// A keyframe as the check sees it: its samples in its camera frame, its pose, and the centroid of
// its samples (world, mm).
struct ReentryKeyframe {
  const SurfacePoints* samples = nullptr;
  Rigid3d world_from_cam = Rigid3d::Identity();
  Eigen::Vector3d centre_in_world = Eigen::Vector3d::Zero();
};

class ReentryCheck {
 public:
  // camera: the views' camera (H×W their size; its pinhole part is used: the grids are coarse).
  // Throws std::invalid_argument for invalid options or camera.
  ReentryCheck(const PinholeBrownConrady& camera, const ReentryCheckOptions& options = {});

  // Tests view samples (camera frame, mm) at world_from_cam against the given keyframes (the
  // caller's, nearest first: the first `keyframes` of those whose centre lies within
  // max_centre_distance_mm of the view's are used). Disabled: ok with nothing tested.
  ReentryEvidence Test(const SurfacePoints& view_in_cam, const Rigid3d& world_from_cam,
                       const std::vector<ReentryKeyframe>& keyframes);

  const ReentryCheckOptions& options() const { return o_; }

 private:
  // Depth grid of samples (their camera frame) into *depth ((H·s)×(W·s) CV_32F, mm; +inf = none).
  void DepthGrid(const SurfacePoints& samples, cv::Mat* depth) const;
  // Compares `points` (frame A) moved by b_from_a with grid `depth_b` of frame B; adds to *e.
  void Compare(const SurfacePoints& points, const Rigid3d& b_from_a, const cv::Mat& depth_b,
               ReentryEvidence* e) const;

  PinholeIntrinsics grid_;  // the camera scaled to the grid
  ReentryCheckOptions o_;
  cv::Mat view_depth_, kf_depth_;  // reused per call
};

}  // namespace d3d
