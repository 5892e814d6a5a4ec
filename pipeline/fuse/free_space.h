// Free-space test of a view before fusion: a point that lies in space earlier views saw through is
// not fused.
//
// Why: a region unwrapped a whole fringe order (or two) too near puts its points 1.4–3.8 mm along
// their rays in front of the true surface, where nothing is. When the true surface is already in
// the model, the TSDF cannot remove them: its updates reach only truncation (0.2 mm) in front of
// each measured surface, so the wrong points fuse into a ghost surface in front of the teeth. Real
// arch seed 3, burst 1193: 6,906 pixels two orders off, with no marker stripe in that part for the
// unwrapper to test, fused 0.8–1.0 mm outside a molar (228 mesh vertices; trueness RMS 20.5 µm,
// p95 14 µm).
//
// Method (the free-space violation of visibility-based depth-map fusion: Merrell et al. 2007,
// "Real-time visibility-based fusion of depth maps", ICCV, §3.2): every `reference_every`-th
// fused view is kept as a reference, its depth (z of its points, mm) on a pinhole grid of half the
// camera's size, each cell holding the nearest depth seen through it (lens distortion removed by
// projecting the reference's own 3-D points). A new point p is tested against the nearest
// `nearest_references` references (camera centres within `max_centre_distance_mm`): a reference
// votes when p projects into its grid, ≥ 5 of the 3 × 3 cells around it hold a depth, and the
// smallest of those depths is more than `margin_mm` beyond p's depth in that reference (the
// reference saw through p to a surface behind it; the 3 × 3 minimum keeps a ray that grazed an
// edge next to p from voting). `min_votes` votes reject p. Points are tested on a 2 × 2 pixel
// lattice, the first point of each block deciding for the block. A surface that newly occludes an
// old one gets no vote: the references that saw the old one saw this surface too, or did not see p
// at all. Points behind known surfaces are left to the TSDF's own occlusion test (tsdf.h).
//
// Threads: one FreeSpaceTest per fuser, used by one thread at a time; references are kept in a
// ring of preallocated grids (no allocation after max_references references).
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <utility>
#include <vector>

#include "calib/model/camera_model.h"
#include "common/core/rigid.h"

namespace d3d {

struct FreeSpaceOptions {
  bool enabled = true;
  int reference_every = 6;             // every this many tested views becomes a reference
  int max_references = 32;             // ring of the newest references (~300 KB each at 640 × 480)
  int nearest_references = 6;          // tested per view: the nearest by camera centre ...
  double max_centre_distance_mm = 15;  // ... within this distance
  double margin_mm =
      1.0;             // depth beyond p (along the reference's axis) that counts as seen through
  int min_votes = 2;   // references that must have seen through p
  void Check() const;  // throws std::invalid_argument
};

class FreeSpaceTest {
 public:
  // camera: intrinsics of the views (H×W = their size). Throws std::invalid_argument for invalid
  // options.
  FreeSpaceTest(const PinholeBrownConrady& camera, const FreeSpaceOptions& options = {});

  // Tests one view (points_in_cam: H×W CV_32FC3, mm, NaN = none; its registered pose) against the
  // references, writes `rejected` (H×W CV_8U, 255 = a point in space the references saw through,
  // reused if allocated) and returns how many points it rejected. Then, every reference_every-th
  // call, keeps the view (its points not rejected) as a reference. Without references (or
  // disabled) nothing is rejected. Throws std::invalid_argument unless points_in_cam is the
  // camera's H×W CV_32FC3.
  int64_t TestAndRemember(const cv::Mat& points_in_cam, const Rigid3d& world_from_cam,
                          cv::Mat* rejected);

  int references() const { return static_cast<int>(refs_.size()); }
  const FreeSpaceOptions& options() const { return o_; }

 private:
  struct Reference {
    Rigid3d cam_from_world = Rigid3d::Identity();
    Eigen::Vector3d centre_in_world = Eigen::Vector3d::Zero();
    cv::Mat depth;  // (H/2)×(W/2) CV_32F, mm; +inf = no depth
  };
  void Remember(const cv::Mat& points_in_cam, const Rigid3d& world_from_cam,
                const cv::Mat& rejected);

  PinholeBrownConrady camera_;
  FreeSpaceOptions o_;
  double fx_, fy_, cx_, cy_;  // of the half-size pinhole grid
  std::vector<Reference> refs_;
  size_t next_ = 0;  // ring position of the next reference
  int64_t calls_ = 0;
  // Per call, reused: references by distance, those tested, and ref_from_cam of each.
  std::vector<std::pair<double, int>> order_;
  std::vector<int> near_;
  std::vector<Eigen::Matrix3f> rot_;
  std::vector<Eigen::Vector3f> trans_;
};

}  // namespace d3d
