// Step 4b of the calibration: the camera–projector pair. The camera (step 3) and the projector as
// an inverse camera (its features from projector_mapping.h) are first calibrated separately
// (Tsai start + refinement each); cam_from_proj starts as the rotation-averaged (chordal L2 mean
// of the quaternions) and translation-averaged proj_from_target ∘ cam_from_target⁻¹ over the
// views; then a bundle adjustment (Ceres, Levenberg–Marquardt) refines both devices' intrinsics
// and distortion, the rigid proj_from_cam and every target pose together, minimising the
// reprojection errors in the camera (circle-centre model when the target has circles) and in the
// projector (point model: its features are images of the circles' centres).
#pragma once

#include <Eigen/Core>
#include <array>
#include <string>
#include <vector>

#include "calib/camera/camera_calibration.h"

namespace d3d {

struct StereoView {
  std::string name;
  std::vector<Eigen::Vector3d> object_points;  // mm, target frame, z = 0
  std::vector<Eigen::Vector2d> camera_px;      // as detected (circle centroids or corners)
  std::vector<Eigen::Vector2d> projector_px;   // images of the feature points in the projector
  std::vector<uint8_t> projector_valid;        // 1 where projector_px is valid
};

struct StereoCalibrationOptions {
  CameraCalibrationOptions camera;  // camera.circle_radius_mm: circle model for the camera features
  CameraCalibrationOptions projector;  // its circle_radius_mm is ignored (point model)
  int max_iterations = 200;
  double max_extrinsic_sigma_mm = 0.05;  // σ of the baseline above this: ill-conditioned
  // σ of the rotation above this: ill-conditioned. The rotation is strongly correlated with the
  // projector's principal point (1 px ≈ 0.5 mrad at f = 2100 px), which the 3-D measurement does
  // not see; σ ≈ 1 mrad is normal for 10–15 views of the probe.
  double max_extrinsic_sigma_rad = 5e-3;
  void Check() const;  // throws std::invalid_argument
};

struct StereoCalibrationResult {
  bool ok = false;
  std::string reason;
  CameraCalibrationResult camera_only;     // step 3 alone
  CameraCalibrationResult projector_only;  // step 4a alone
  Rigid3d initial_cam_from_proj = Rigid3d::Identity();
  PinholeBrownConrady camera, projector;
  Rigid3d cam_from_proj = Rigid3d::Identity();
  std::vector<Rigid3d> cam_from_target;
  double camera_rms_px = 0, projector_rms_px = 0;  // after the bundle adjustment
  std::vector<double> camera_view_rms_px, projector_view_rms_px;
  std::vector<std::vector<Eigen::Vector2d>> camera_residuals_px,
      projector_residuals_px;                               // observed − predicted
  std::array<double, 9> camera_sigma{}, projector_sigma{};  // (fx, fy, cx, cy, k1, k2, p1, p2, k3)
  std::array<double, 6> extrinsic_sigma{};  // proj_from_cam: angle-axis (rad), t (mm)
  double reciprocal_condition = 0;
};

// Throws std::invalid_argument for inconsistent views. Failures (either device cannot be
// calibrated, too few projector features, ill-conditioned) return ok = false with the reason.
StereoCalibrationResult CalibrateStereo(const std::vector<StereoView>& views, int camera_width,
                                        int camera_height, int projector_width,
                                        int projector_height,
                                        const StereoCalibrationOptions& options = {});

// Mean of rigid transforms: chordal L2 mean of the rotations (principal eigenvector of Σ q qᵀ),
// arithmetic mean of the translations. Throws std::invalid_argument for an empty list.
Rigid3d AverageRigid(const std::vector<Rigid3d>& poses);

}  // namespace d3d
