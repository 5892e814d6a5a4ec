// Step 4a of the calibration: the projector as an inverse camera. The phase-shift images of the
// target along both projector axes give, at every camera pixel, the projector pixel that lights
// it (absolute phase → projector coordinate); every target feature seen by the camera is then
// mapped to the projector, which yields "projector images" of the target (Zhang & Huang 2006,
// "Novel method for structured light system calibration", Opt. Eng. 45(8):083601).
//
// Phase: N-step phase shift per period in the convention of the patterns (frame n shows ½ + ½
// cos(2πc/T − δ_n), δ_n = 2πn/N, so Σ I_n e^{iδ_n} ∝ e^{iΦ} and Φ = atan2(Σ I_n sin δ_n, Σ I_n cos
// δ_n) = 2πc/T mod 2π), and B = (2/N)|Σ I_n e^{iδ_n}|. Temporal (hierarchical) unwrapping over the
// periods, coarse to fine (Huntley & Saldner 1993; Zuo et al. 2016, "Temporal phase unwrapping
// algorithms for fringe projection profilometry: a comparative review", Opt. Lasers Eng. 85:84–103,
// sect. 2.2): the first period covers the projector (Φ₁ is absolute), then
//   c_j = T_j/(2π) · (φ_j + 2π·round((2π c_{j−1}/T_j − φ_j) / 2π)).
//
// Feature mapping: around each feature (camera px), the decoded projector coordinates of the
// pixels with good modulation (≥ modulation_fraction × the window's 90th percentile: the black
// print and its blurred edges are left out) are fitted with a quadratic polynomial in the camera
// coordinates (a homography plus both lenses' distortion, to second order across the window),
// by least squares with one round of 3σ rejection; the fit's value at the feature is its
// projector position. The fit's RMS residual is reported.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "common/core/status.h"

namespace d3d {

struct PhaseDecodeOptions {
  int steps = 4;
  std::vector<double> periods_px = {1200.0, 120.0,
                                    24.0};  // coarse → fine; periods_px[0] ≥ projector extent
  double min_modulation_dn = 3.0;           // B of the finest period below this: invalid
  void Check() const;                       // throws std::invalid_argument
};

struct ProjectorCoordinateMap {
  cv::Mat coord_px;    // H×W CV_32F projector coordinate along the axis, NaN where invalid
  cv::Mat modulation;  // H×W CV_32F B of the finest period, DN
};

// frames: steps × periods frames, period-major (all steps of periods_px[0] first), H×W CV_8U or
// CV_16U, all of one size. INVALID_ARGUMENT for a wrong count, size or type.
[[nodiscard]] Status DecodeProjectorCoordinate(const std::vector<cv::Mat>& frames,
                                               const PhaseDecodeOptions& options,
                                               ProjectorCoordinateMap* out);

struct FeatureMappingOptions {
  double window_radius_px = 20.0;    // fit window around each feature, camera px
  double modulation_fraction = 0.5;  // pixels with B < this × p90(B in the window) are left out
  int min_samples = 40;              // fewer good pixels: the feature is not mapped
  double max_fit_rms_px = 0.5;       // a worse fit (projector px): not mapped
  void Check() const;
};

struct MappedFeature {
  bool ok = false;
  Eigen::Vector2d projector_px = Eigen::Vector2d::Zero();
  double fit_rms_px = 0;  // RMS residual of the fit, projector px (u and v together)
  int samples = 0;
  std::string reason;
};

// Maps camera points (px) to the projector with the u (axis x) and v (axis y) maps.
std::vector<MappedFeature> MapFeaturesToProjector(const ProjectorCoordinateMap& u_map,
                                                  const ProjectorCoordinateMap& v_map,
                                                  const std::vector<Eigen::Vector2d>& camera_px,
                                                  const FeatureMappingOptions& options = {});

}  // namespace d3d
