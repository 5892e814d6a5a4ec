// The dissertation's calibration method end to end, from calibration images to the probe's
// calibration.json (ProbeCalibration):
//   1. pre-treatment: each white-light image is assessed (calib/features/image_quality.h) and
//      rejected when blurred, noisy or without contrast;
//   2. target features: chessboard corners or moment-based circle centres
//   (calib/features/detect.h);
//   3. camera: Tsai RAC start + refinement (calib/camera), circle-centre model when the target has
//      circles (the diameter, if not given, estimated from the blobs' areas: area = π r² |det J|
//      with J the Jacobian of the target → image map at the centre, median over all blobs);
//   4. projector: absolute projector coordinates from the phase sets along both axes, features
//      mapped to the projector after removing the camera's perspective bias of circle centroids
//      (the mapping moves points, and the centroid is not the image of a point), projector
//      calibration, then the stereo bundle adjustment (calib/projector);
//   5. global refinement on the multi-plane model (calib/refine).
// Every step's figures are kept for the report.
#pragma once

#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "calib/camera/camera_calibration.h"
#include "calib/features/detect.h"
#include "calib/features/image_quality.h"
#include "calib/features/target.h"
#include "calib/model/probe_calibration.h"
#include "calib/projector/projector_mapping.h"
#include "calib/projector/stereo_calibration.h"
#include "calib/refine/multi_plane.h"
#include "common/core/status.h"

namespace d3d {

struct CalibrationImage {
  std::string name;
  cv::Mat white;  // H×W CV_8U or CV_16U: the target under white light
  std::vector<cv::Mat>
      phase_x;  // phase sets along projector x (PhaseDecodeOptions order); empty = none
  std::vector<cv::Mat> phase_y;  // ... along projector y
};

struct SystemCalibrationOptions {
  ImageQualityOptions quality;
  FeatureOptions features;
  CameraCalibrationOptions camera;  // circle_radius_mm is set from the target
  CameraCalibrationOptions projector;
  PhaseDecodeOptions phase;
  FeatureMappingOptions mapping;  // window_radius_px ≤ 0: 0.8 × the features' spacing in the image
  MultiPlaneOptions refine;
  bool global_refinement = true;  // step 5
  int projector_width = 0;        // needed when images carry phase sets
  int projector_height = 0;
  double projector_gamma = 1.0;     // written to calibration.json (not measured here)
  double depth_margin_mm = 4.0;     // measurement volume: target depths seen ± this
  int min_projector_features = 12;  // per view, else the view is left out of the projector steps
  SystemCalibrationOptions();
  void Check() const;  // throws std::invalid_argument
};

struct ImageReport {
  std::string name;
  ImageQuality quality;
  bool used = false;
  std::string rejected;                              // why not used ("" when used)
  std::vector<Eigen::Vector2d> camera_px;            // detected features
  std::vector<Eigen::Vector2d> camera_residuals_px;  // after the final step (observed − predicted)
  double camera_rms_px = 0;
  int projector_features = 0;
  std::vector<Eigen::Vector2d> projector_px;  // mapped features (NaN where not mapped)
  std::vector<Eigen::Vector2d> projector_residuals_px;
  double projector_rms_px = 0;
  double plane_rms_before_um = 0, plane_rms_after_um = 0;  // dense points vs their fitted plane
};

struct SystemCalibrationResult {
  bool ok = false;
  std::string reason;
  bool has_projector = false;
  ProbeCalibration calibration;   // the result; without phase sets only .camera (and the depth
                                  // range) is calibrated: has_projector = false, and the rest
                                  // of it must not be used (the tool writes a camera-only file)
  double circle_diameter_mm = 0;  // given or estimated
  bool circle_diameter_estimated = false;
  CameraCalibrationResult camera;  // step 3 (camera alone, final camera-only result)
  StereoCalibrationResult stereo;  // step 4
  MultiPlaneResult refine;         // step 5
  std::vector<ImageReport> images;
  int views_used = 0;
  double camera_rms_px = 0, projector_rms_px = 0;  // of the final calibration
};

// Expected failures (images of different sizes, target not found, too few usable views, all
// views fronto-parallel, ill-conditioned) return ok = false with the reason naming the cause;
// nothing is returned as ok that the conditioning checks reject. Throws std::invalid_argument for
// invalid options or target.
SystemCalibrationResult CalibrateSystem(const CalibrationTarget& target,
                                        const std::vector<CalibrationImage>& images,
                                        const SystemCalibrationOptions& options);

// Reads a folder of calibration images (PNG/JPG/BMP/TIF, sorted by name; 8- or 16-bit grey or
// colour, converted to grey) and, with phase_dir, for each image stem S the folder phase_dir/S
// with the frames AXIS_PERIODINDEX_STEP.png described by phase_dir/phase.json (written by
// d3d-sim --calibration-session), filling options->phase and the projector size from it.
// NOT_FOUND / PARSE_ERROR / INVALID_ARGUMENT naming the file.
[[nodiscard]] Status LoadCalibrationImages(const std::string& images_dir,
                                           const std::string& phase_dir,
                                           std::vector<CalibrationImage>* out,
                                           SystemCalibrationOptions* options);

}  // namespace d3d
