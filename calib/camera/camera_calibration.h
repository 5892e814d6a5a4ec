// Step 3 of the calibration: a camera (or a projector, as an inverse camera) from views of a
// planar target.
//
// Start values: Tsai's radial alignment constraint (RAC) for coplanar targets (R. Y. Tsai, "A
// versatile camera calibration technique for high-accuracy 3D machine vision metrology using
// off-the-shelf TV cameras and lenses", IEEE J. Robotics and Automation 3(4):323–344, 1987,
// sect. III.B). With the principal point taken at the image centre, the direction from it to an
// image point is parallel to the direction from the optical axis to the target point whatever
// the radial distortion and the focal length: for each feature (x_d, y_d) relative to the
// principal point and target point (X, Y, 0),
//     y_d (r1 X + r2 Y + tx) − x_d (r4 X + r5 Y + ty) = 0,
// homogeneous and linear in v = (r1, r2, tx, r4, r5, ty): solved by linear least squares (the
// right singular vector of the smallest singular value). The scale λ of v follows from the
// orthonormality of R's first two columns (λ² = (‖A‖² + √(‖A‖⁴ − 4 det²A)) / 2 for the 2×2
// block A, Tsai's eq. (12) in this form), its sign from the image quadrants, the third row of R
// from the cross product; then f and tz by linear least squares from
//     x_d (r7 X + r8 Y + tz) = f (r1 X + r2 Y + tx)   (and the same in y),
// with R's sign ambiguity resolved by f > 0. f is undetermined for a fronto-parallel view (r7 =
// r8 = 0): such views do not vote; the start f is the median of the tilted views' votes.
//
// Refinement: Levenberg–Marquardt (Ceres) on the reprojection error of all features of all views
// over intrinsics, distortion (k1, k2, p1, p2, k3) and every view's pose, with the feature model
// of projection.h (point, or circle centre with its perspective bias).
//
// Conditioning: the covariance of the intrinsics (inverse Gauss–Newton normal matrix, scaled by
// the residual variance) is computed; a rank-deficient problem or a relative standard deviation
// of fx, fy above max_relative_sigma makes the calibration fail with that figure as the reason —
// a calibration that looks valid but is not is never returned as ok.
#pragma once

#include <Eigen/Core>
#include <array>
#include <string>
#include <vector>

#include "calib/model/camera_model.h"
#include "common/core/rigid.h"

namespace d3d {

// The features of one view of a planar target (z = 0 on the target).
struct TargetView {
  std::string name;
  std::vector<Eigen::Vector3d> object_points;  // mm, target frame, z = 0
  std::vector<Eigen::Vector2d> image_points;   // px, same order
};

struct TsaiPoseResult {
  bool ok = false;
  std::string reason;
  Rigid3d device_from_target = Rigid3d::Identity();
  double f_px = 0;      // focal length (fx) from this view; 0 when the view cannot tell
  double tilt_rad = 0;  // angle between the target normal and the optical axis
};

// Tsai's RAC start for one view (see above), principal point (cx, cy), aspect ratio fy/fx.
// fixed_f_px > 0: f is not estimated, only tz (for the poses once f is known).
TsaiPoseResult TsaiPlanarPose(const TargetView& view, double cx, double cy, double aspect,
                              double fixed_f_px = 0.0, double min_tilt_rad = 0.05);

struct CameraCalibrationOptions {
  bool fix_aspect_ratio = false;  // fy = aspect_ratio · fx (OpenCV's CALIB_FIX_ASPECT_RATIO)
  double aspect_ratio = 1.0;
  bool fix_principal_point = false;  // cx, cy stay at the image centre
  bool fix_tangential = false;       // p1 = p2 = 0
  bool fix_k3 = false;               // k3 = 0
  double circle_radius_mm =
      0.0;  // > 0: image points are centroids of imaged circles (projection.h)
  int min_views = 3;
  int min_points_per_view = 6;
  double min_tilt_deg = 3.0;         // flatter views do not vote for f in the start values
  double max_relative_sigma = 0.01;  // σ(fx)/fx, σ(fy)/fy above this: ill-conditioned, fails
  int max_iterations = 200;
  void Check() const;  // throws std::invalid_argument
};

struct CameraViewResult {
  std::string name;
  Rigid3d device_from_target = Rigid3d::Identity();
  double rms_px = 0;                          // reprojection RMS of this view
  std::vector<Eigen::Vector2d> residuals_px;  // observed − predicted, per feature
  double tsai_f_px = 0;                       // the view's vote for f (0: too flat)
  double tilt_deg = 0;
};

struct CameraCalibrationResult {
  bool ok = false;
  std::string reason;  // why it failed (too few views, fronto-parallel, ill-conditioned ...)
  PinholeBrownConrady camera;   // refined
  PinholeBrownConrady initial;  // Tsai start (no distortion)
  double initial_rms_px = 0;    // reprojection RMS of the start values
  double rms_px = 0;            // sqrt(Σ|e|² / features), OpenCV's "avg reprojection error"
  int features = 0;
  std::vector<CameraViewResult> views;
  // Standard deviations of (fx, fy, cx, cy, k1, k2, p1, p2, k3); 0 for fixed parameters.
  std::array<double, 9> sigma{};
  double reciprocal_condition =
      0;  // of the column-scaled normal matrix (1 = perfect, < 1e-12 = rank-deficient)
  int iterations = 0;
};

// Throws std::invalid_argument for invalid options or views whose point lists differ in length.
// Expected failures (too few views/points, all views fronto-parallel, no convergence,
// ill-conditioned) return ok = false with the reason.
CameraCalibrationResult CalibrateCamera(const std::vector<TargetView>& views, int width, int height,
                                        const CameraCalibrationOptions& options = {});

// Reprojection of one view with a known camera and pose: observed − predicted per feature.
std::vector<Eigen::Vector2d> ReprojectionResiduals(const TargetView& view,
                                                   const PinholeBrownConrady& camera,
                                                   const Rigid3d& device_from_target,
                                                   double circle_radius_mm);

// Pixel of the centre of the image of a circle of radius r (projection.h's circle model); r = 0:
// the plain projection.
Eigen::Vector2d ProjectTargetFeature(const PinholeBrownConrady& camera,
                                     const Rigid3d& device_from_target, const Eigen::Vector3d& X,
                                     double circle_radius_mm);

// Pose as a 6-vector (angle-axis, t) and back.
std::array<double, 6> PoseToParams(const Rigid3d& pose);
Rigid3d ParamsToPose(const double* params);

}  // namespace d3d
