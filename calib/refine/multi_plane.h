// Step 5 of the calibration: global refinement on the multi-plane model. The scanner measures
// points by intersecting camera rays with projector coordinates; on a calibration view every such
// point must lie on the target plane of that view. With the dense decoded projector coordinates
// of the target's white paper (thousands of pixels per view, not just the features), the whole
// system — camera and projector intrinsics and distortion, cam_from_proj and every target pose —
// is optimised so that the error between the system model and the physical target is smallest:
//   for a camera pixel p with decoded projector coordinates (u, v) in view i, the point the model
//   predicts is X = camera ray(p) ∩ plane_i (the target plane of pose i), and the residual is the
//   projector reprojection of X minus (u, v) (projector px; 1 px ≈ 24 µm across the fringes, the
//   measuring direction, at 50 mm),
// together with the feature reprojection residuals of the bundle adjustment, which carry the
// target's metric scale (planarity alone has none). Ceres, Levenberg–Marquardt, Huber loss on the
// dense residuals (1 px) against stray pixels.
//
// What it gains is measured as the planarity of the triangulated points: each dense sample is
// triangulated like the scanner does (camera ray ∩ the projector column u, with both
// distortions), a plane is fitted per view by least squares, and the RMS distance (µm) before and
// after the refinement is reported, as is the RMS distance to the target plane of the view's pose.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "calib/projector/projector_mapping.h"
#include "calib/projector/stereo_calibration.h"

namespace d3d {

struct PlaneSample {
  Eigen::Vector2d camera_px;
  Eigen::Vector2d projector_px;  // decoded (u, v)
};

struct MultiPlaneOptions {
  int sample_step_px = 6;  // dense samples on this camera-pixel grid
  double modulation_fraction =
      0.6;  // keep pixels with B ≥ this × the view's 90th percentile (paper, not print)
  double edge_guard_px = 3.0;  // and at least this far from any low-modulation pixel
  int max_iterations = 50;
  double huber_px = 1.0;  // robust loss scale of the dense residuals (projector px)
  void Check() const;     // throws std::invalid_argument
};

// Dense samples of one view from its decoded u and v maps (H×W, projector_mapping.h).
std::vector<PlaneSample> SampleDensePlane(const ProjectorCoordinateMap& u_map,
                                          const ProjectorCoordinateMap& v_map,
                                          const MultiPlaneOptions& options);

// Scanner-style triangulation: the point on the camera ray of pixel p whose projection in the
// projector has column u (both distortions; Newton/secant along the ray). false if it fails.
bool TriangulateColumn(const PinholeBrownConrady& camera, const PinholeBrownConrady& projector,
                       const Rigid3d& cam_from_proj, const Eigen::Vector2d& camera_px,
                       double projector_u, Eigen::Vector3d* p_in_cam);

struct PlanarityFigures {
  double fit_rms_um = 0;     // RMS distance to the least-squares plane of the view's points
  double target_rms_um = 0;  // RMS distance to the target plane of the view's pose
  int points = 0;
};

// Planarity of every view's dense samples under a calibration (see above).
std::vector<PlanarityFigures> MeasurePlanarity(const PinholeBrownConrady& camera,
                                               const PinholeBrownConrady& projector,
                                               const Rigid3d& cam_from_proj,
                                               const std::vector<Rigid3d>& cam_from_target,
                                               const std::vector<std::vector<PlaneSample>>& dense);

struct MultiPlaneResult {
  bool ok = false;
  std::string reason;
  PinholeBrownConrady camera, projector;
  Rigid3d cam_from_proj = Rigid3d::Identity();
  std::vector<Rigid3d> cam_from_target;
  int samples = 0;
  double dense_rms_before_px = 0, dense_rms_after_px = 0;  // dense residuals (u, v), projector px
  double camera_rms_px = 0, projector_rms_px = 0;          // feature reprojection after
  std::vector<PlanarityFigures> before, after;
  double plane_fit_rms_before_um = 0, plane_fit_rms_after_um = 0;  // over all views
  double target_plane_rms_before_um = 0, target_plane_rms_after_um = 0;
};

// views: the stereo views (features) of the bundle adjustment; dense: per view (same order) the
// dense samples; start: the stereo calibration to refine; stereo_options: which parameters are
// fixed, the circle radius.
MultiPlaneResult RefineMultiPlane(const std::vector<StereoView>& views,
                                  const std::vector<std::vector<PlaneSample>>& dense,
                                  const StereoCalibrationResult& start,
                                  const StereoCalibrationOptions& stereo_options,
                                  const MultiPlaneOptions& options = {});

}  // namespace d3d
