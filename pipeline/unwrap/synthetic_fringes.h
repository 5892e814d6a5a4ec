// Synthetic wrapped-phase scenes with analytic truth, for the unwrapping tests and benchmarks.
//
// Geometry: a rectified camera–projector pair (both pinhole, no distortion, parallel axes, the
// projector shifted by `baseline_mm` along camera x), so a surface point seen by camera pixel
// (x, y) at depth Z [mm] lands on projector column
//   u(x, Z) = fp·(x − cx)/fc − fp·b/Z + proj_cx,
// and its absolute phase is Φ = 2π(u − phase_origin_px)/T (calib/model/probe_calibration.h).
// Φ grows with Z, so the measurement volume [z_min, z_max] gives phase_min = Φ(x, z_min) and
// phase_max = Φ(x, z_max). The defaults follow the probe head (sim/render/probe_design.h):
// fc = 2000 px, fp = 2100 px, b = 10.63 mm, T = 24 px, 42–58 mm (≈ 6 orders per pixel), marker
// stripes at orders 4, 14, 24, 34.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>

namespace d3d {

struct SyntheticProbe {
  int width = 640, height = 480;
  double fc = 2000.0;  // camera focal length [px]
  double fp = 2100.0;  // projector focal length [px]
  double baseline_mm = 10.63;
  double period_px = 24.0;  // fringe period T on the projector [px]
  double phase_origin_px = 0.0;
  double proj_width = 912.0;  // projector columns: outside [0, proj_width) there is no light
  double proj_cx = 902.5;     // projector column of the camera centre ray at 50 mm: 456 + fp·b/50
  double z_min = 42.0, z_max = 58.0;
  int marker_first_order = 4, marker_spacing_orders = 10;

  // The same probe for another camera size (focal length scaled with the width).
  static SyntheticProbe ForSize(int width, int height);
  double ColumnAt(double x, double z_mm) const;  // projector column u
  double PhaseAt(double x, double z_mm) const;   // absolute phase Φ [rad]
};

struct SyntheticNoise {
  double modulation = 40.0;          // B on a surface facing the camera [DN]
  double intensity_sigma = 2.0;      // σ_I [DN]: phase noise σ_φ = σ_I·√(2/4) / B
  double marker_miss_rate = 0.05;    // share of true stripe pixels not detected
  double marker_false_rate = 0.002;  // share of other pixels detected as marker
  uint64_t seed = 1;
};

struct SyntheticScene {
  cv::Mat depth;       // CV_32F [mm], NaN where nothing is seen (the input)
  cv::Mat Phi_true;    // CV_32F absolute phase, NaN where nothing is lit
  cv::Mat order_true;  // CV_32S k = floor(Φ/2π), −1 where nothing is lit
  cv::Mat phi;         // CV_32F wrapped phase with noise, [0, 2π), NaN where nothing is lit
  cv::Mat modulation;  // CV_32F B [DN]
  cv::Mat valid;       // CV_8U 255 where lit
  cv::Mat marker;      // CV_8U 255 in detected marker stripes
  cv::Mat phase_min;   // CV_32F Φ(x, z_min)
  cv::Mat phase_max;   // CV_32F Φ(x, z_max)
};

// Renders a depth map (CV_32F mm, NaN = background) into a wrapped-phase scene. B falls with the
// surface slope (B·n_z); zero-modulation `holes` (CV_8U nonzero, optional) become shadows.
SyntheticScene MakeFringeScene(const cv::Mat& depth, const SyntheticProbe& probe,
                               const SyntheticNoise& noise, const cv::Mat& holes = cv::Mat());

// Depth maps with analytic truth (CV_32F mm, NaN = background), sizes from `probe`:
// a plane Z = z0 + gx·(x − cx) + gy·(y − cy) [mm, mm/px] over the whole image.
cv::Mat PlaneDepth(const SyntheticProbe& probe, double z0, double gx, double gy);
// A spherical cap of radius r_mm (centre at camera pixel (px, py), apex at z_apex) on background.
cv::Mat SphereDepth(const SyntheticProbe& probe, double px, double py, double r_mm, double z_apex);
// "Teeth": a row of `count` dome-shaped blobs (ellipses, 0.7 of the image height, separated by gaps
// of `gap_px` background), their base depths alternating around 50 mm; the last two overlap so that
// one occludes the other (a depth step without a gap). Deterministic in `seed`.
cv::Mat TeethDepth(const SyntheticProbe& probe, int count, double gap_px, uint64_t seed);

}  // namespace d3d
