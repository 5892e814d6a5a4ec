// Synthetic images of a calibration target for tests with ground truth: a printed target
// (black features on white, outside the features white) seen by a pinhole + Brown–Conrady camera
// at a known pose, with area sampling (n × n sub-pixels per pixel), Gaussian blur, seeded Gaussian
// noise and 8-bit quantisation. Not a physical renderer (the virtual probe is, sim); this
// one is cheap and exact in geometry, for unit tests of the calibration steps.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>

#include "calib/features/target.h"
#include "calib/model/camera_model.h"
#include "common/core/rigid.h"

namespace d3d {

struct SyntheticImageOptions {
  int supersample = 4;          // n × n sub-pixels per pixel
  double blur_sigma_px = 0.7;   // Gaussian blur after sampling (0 = none)
  double noise_dn = 1.0;        // σ of additive Gaussian noise, DN (0 = none)
  double white_dn = 200.0;      // level of the white paper
  double black_dn = 30.0;       // level of the black print
  double background_dn = 60.0;  // where the ray misses the target plane (behind the camera)
  uint64_t seed = 1;
  void Check() const;  // throws std::invalid_argument
};

// Albedo of the printed target at target point (x, y) mm: 1 on white, 0 on black. Circles need
// target.circle_diameter_mm > 0 (throws std::invalid_argument otherwise).
double TargetAlbedo(const CalibrationTarget& target, double x_mm, double y_mm);

// H×W CV_8U image of the camera's size.
cv::Mat RenderSyntheticTarget(const CalibrationTarget& target, const PinholeBrownConrady& camera,
                              const Rigid3d& cam_from_target,
                              const SyntheticImageOptions& options = {});

}  // namespace d3d
