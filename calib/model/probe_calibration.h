// The probe's calibration: camera and projector intrinsics, the stereo extrinsics cam_from_proj,
// the measurement volume and the fringe pattern set the probe projects. Written as
// `calibration.json` by the factory calibration (calib/) and by the virtual probe, published by the
// probe in ProbeInfo; it is the only description of the probe that downstream stages may use.
#pragma once

#include <string>

#include "calib/model/camera_model.h"
#include "common/core/rigid.h"
#include "common/core/status.h"

namespace d3d {

// The phase-shift pattern set with the embedded absolute-phase marker.
//
// Coordinates: `c` is the projector pixel coordinate along `axis` (u for "x", v for "y"), OpenCV
// convention (centre of the first column at 0). Absolute phase Φ(c) = 2π (c − phase_origin_px) / T,
// fringe order k = floor(Φ / 2π), wrapped phase φ = Φ − 2πk ∈ [0, 2π).
// Frame n (n = 0..N−1) shows p_n(c) = ½ + ½ cos(Φ(c) − δ_n), δ_n = 2πn/N, so that
//   Φ = atan2(Σ I_n sin δ_n, Σ I_n cos δ_n)  for I_n = A + B cos(Φ − δ_n).
// Marker (dissertation D3DscannerII, 4 images instead of 5): in frame `marker_frame`, inside
// stripes of fringe order k_m = marker_first_order + j·marker_spacing_orders (j ≥ 0; only j = 0 if
// spacing is 0), over Φ ∈ [2πk_m + π(1−w), 2πk_m + π(1+w)) with w = marker_width_periods, the
// pattern value is replaced by p' = p + ½ if p < ½ else p − ½. For N = 4 and marker_frame = 3 the
// consistency residual I_0 + I_2 − I_1 − I_3 is then ±½·(projector amplitude) in the stripe and 0
// elsewhere, while frames 0–2 (a 3-step set with π/2 shifts) still give Φ there. Stripes are spaced
// farther apart than the fringe orders the measurement volume admits at one pixel, so a detected
// stripe's order is unique.
struct FringePatternSpec {
  std::string name = "phase4-marker";  // id published with every burst
  char axis = 'x';                     // coded projector axis: 'x' (columns, default) or 'y'
  int steps = 4;                       // N of the N-step phase shift (≥ 3)
  double fringe_period_px = 24.0;      // fringe period T, projector pixels
  double phase_origin_px = 0.0;        // projector coordinate where Φ = 0
  int marker_frame = 3;                // frame that carries the marker; -1 = no marker
  int marker_first_order = 4;          // fringe order of the first marker stripe
  int marker_spacing_orders = 10;      // orders between stripes; 0 = one stripe
  double marker_width_periods = 1.0;   // stripe width w in periods, (0, 1]
  bool texture_frame = false;  // a 5th, uniformly lit frame (default: texture = mean of the 4)

  void Check() const;  // throws std::invalid_argument
  bool HasMarker() const { return marker_frame >= 0; }
  double AbsolutePhase(double coord_px) const;
  // True if projector coordinate c lies in a marker stripe (in any frame; the stripe is drawn only
  // in marker_frame).
  bool InMarker(double coord_px) const;
  // Pattern value p ∈ [0, 1] of frame n at coordinate c (before the projector's gamma).
  double PatternValue(int frame, double coord_px) const;
};

struct ProbeCalibration {
  PinholeBrownConrady camera;
  PinholeBrownConrady projector;
  Rigid3d cam_from_proj = Rigid3d::Identity();  // p_in_cam = cam_from_proj * p_in_proj, mm
  // Intensity response of the projector: emitted radiance ∝ (DMD value / 255)^γ. Measured by the
  // calibration (a real DMD with an uncorrected video path has γ ≈ 2.2); phase algorithms that
  // compensate the non-sinusoidal error take it from here.
  double projector_gamma = 1.0;
  double depth_min_mm = 0.0;  // measurement volume along the camera's z
  double depth_max_mm = 0.0;
  FringePatternSpec pattern;
  std::string source;  // who made it: "virtual-probe", "d3d-calibrate", ...

  void Check() const;          // throws std::invalid_argument
  std::string ToJson() const;  // pretty-printed calibration.json
  [[nodiscard]] static Status FromJson(const std::string& text, ProbeCalibration* out);
  [[nodiscard]] Status Save(const std::string& path) const;
  [[nodiscard]] static Status Load(const std::string& path, ProbeCalibration* out);
  // Angle between the camera and projector optical axes (radians).
  double TriangulationAngleRad() const;
};

// The calibration of the same probe read out with camera pixels binned `factor` × `factor`
// (BinnedCamera, camera_model.h); projector, pose, pattern and volume unchanged. Throws
// std::invalid_argument for factor < 1 or a camera size not divisible by it.
ProbeCalibration BinnedCalibration(const ProbeCalibration& calibration, int factor);

}  // namespace d3d
