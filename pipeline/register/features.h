// Initial alignment by image features: SIFT (Lowe 2004, OpenCV's implementation) on the 2-D
// texture image and on the 2.5-D range image (camera-frame z rendered as an 8-bit image) of an
// organised view; keypoints lifted to 3-D through the organised cloud; descriptor matches (Lowe's
// ratio test, mutual) → 3-D correspondences → RansacRigid (rigid Kabsch/Umeyama per sample).
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <type_traits>
#include <vector>

#include "common/core/rigid.h"
#include "pipeline/register/rigid_fit.h"

namespace d3d {

// How the 2.5-D range image is rendered for SIFT.
enum class RangeRendering {
  kDepth,   // camera-frame z, percentile-scaled (RangeImage)
  kShaded,  // the surface lit from the camera: |n·view| of the grid normals (ShadedRangeImage),
            // which changes less with the viewpoint than depth does
  kBoth,    // both, matched separately
};

struct FeatureOptions {
  bool use_texture = true;  // SIFT on the texture image
  bool use_range = true;    // SIFT on the range image
  RangeRendering range_rendering = RangeRendering::kBoth;
  double max_gap_mm = 0.3;           // grid normals of the shaded rendering (GridNormals)
  int max_features = 1500;           // per image (strongest kept)
  double contrast_threshold = 0.02;  // OpenCV SIFT contrastThreshold (lower: more keypoints)
  // SIFT runs on the images downsampled by this factor, (0, 1]; keypoints are mapped back to the
  // full-resolution grid. OpenCV's SIFT doubles its input before the first octave, so at 0.5 the
  // finest scale it searches is the camera's own pixel. The tracker's keyframes use 0.5 (see
  // KeyframeGraphOptions::features); the Stanford bunny's range grids need 1.0 (bun045 → bun000
  // fails at 0.5).
  double image_scale = 1.0;
  double ratio = 0.8;    // Lowe's ratio test
  bool mutual = true;    // keep a match only when it is the best in both directions
  int lift_window = 1;   // keypoint → 3-D: nearest finite point within ±window px
  RansacOptions ransac;  // inlier threshold etc. (mm)
  void Check() const;    // throws std::invalid_argument
};

// Features of one view, in that view's frame.
struct ViewFeatures {
  std::vector<Eigen::Vector3f> texture_points;  // 3-D position (mm) of each texture keypoint
  cv::Mat texture_descriptors;                  // N×128 CV_32F
  std::vector<Eigen::Vector3f> range_points;    // depth rendering
  cv::Mat range_descriptors;
  std::vector<Eigen::Vector3f> shaded_points;  // shaded rendering
  cv::Mat shaded_descriptors;
  size_t size() const { return texture_points.size() + range_points.size() + shaded_points.size(); }

  // Moves are declared noexcept: cv::Mat's move constructor is not (OpenCV 4.6), so without this a
  // std::vector of ViewFeatures, or of a struct holding them (the tracker's keyframes, the feature
  // worker's results), copied every element each time it grew. Measured on a 60-s dwell over one
  // tooth: at 64 and 128 keyframes the tracker thread copied ~90 MB within one view, a latency
  // spike whose freed pages the heap kept (RSS +31 and +80 MB in steps). cv::Mat's move only takes
  // the other's pointers and cannot throw.
  ViewFeatures() = default;
  ViewFeatures(const ViewFeatures&) = default;
  ViewFeatures(ViewFeatures&&) noexcept = default;
  ViewFeatures& operator=(const ViewFeatures&) = default;
  ViewFeatures& operator=(ViewFeatures&&) noexcept = default;
  ~ViewFeatures() = default;
};
static_assert(std::is_nothrow_move_constructible_v<ViewFeatures>,
              "containers of ViewFeatures must move them, not copy");

// points: H×W CV_32FC3 (mm, NaN = none); texture: H×W CV_8U or empty (texture features skipped).
// Keypoints without a finite point within lift_window are dropped.
ViewFeatures ExtractViewFeatures(const cv::Mat& points, const cv::Mat& texture,
                                 const FeatureOptions& options = {});

// The range image of an organised cloud: z (mm) mapped linearly from its [1st, 99th] percentile
// over the finite points onto 1..255, 0 where no point; *mask = 255 where a point is.
cv::Mat RangeImage(const cv::Mat& points, cv::Mat* mask);

// The range image lit from the camera: 255 · |n · v| (v the unit ray to the point), 0 where no
// normal; *mask = 255 where a value is. points: H×W CV_32FC3.
cv::Mat ShadedRangeImage(const cv::Mat& points, double max_gap_mm, cv::Mat* mask);

struct FeatureAlignResult {
  bool ok = false;
  std::string reason;  // why not ok
  Rigid3d target_from_source = Rigid3d::Identity();
  int matches = 0;  // 3-D correspondences offered to RANSAC
  int inliers = 0;
  double inlier_rmse_mm = 0;
};

// Matches source to target features (texture with texture, range with range) and fits the rigid
// transform by RANSAC. Fails cleanly (reason) with too few matches or no consensus.
FeatureAlignResult AlignByFeatures(const ViewFeatures& source, const ViewFeatures& target,
                                   const FeatureOptions& options = {});

}  // namespace d3d
