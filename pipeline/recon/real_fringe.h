// Real-image validation of pipeline/phase and pipeline/unwrap on real camera images
// (../shared/data/fringe, see its README.md).
//
//  1. kamino410/object2: a real camera (1936 × 1216) watching a real projector (1920 × 1080). The
//     3-step set of period 200/3 px along projector x (pat00–02) goes through ComputePhase,
//     ComputeQualityMap and the Unwrapper; each region is anchored by per-pixel phase bounds taken
//     from the OpenCV Gray-code frames (pat12–29, 100-px cells, pat30/31 white/black): a pixel
//     whose decoded cell is j admits Φ ∈ 2π/T·[100 j − m, 100 (j+1) + m]. The projector column from
//     our phase, c = Φ·T/2π, agrees when it lies in the decoded cell ± tolerance. The Gray decoding
//     and c are also compared with the author's decoded map vizualized.png (B = x mod 256, G = y
//     mod 256, R = 128 where valid), and with the column from the 100-px set pat03–05 (its
//     3rd-harmonic gamma error has another spatial period, so |c(66.67) − c(100)| measures the
//     phase error). The results so far: docs/decisions/0017.
//  2. kylemcdonald/{zhang,kyle}: 3-step captures without calibration or Gray code; relative
//     unwrapping (see UnwrapRelative) and a continuity check of the unwrapped Φ.
//
// The analysis is a library (d3d_real_fringe) shared by the tool d3d-real-fringe and
// tests/real_fringe_test.cpp.
#pragma once

#include <opencv2/core.hpp>
#include <string>

#include "common/core/status.h"
#include "pipeline/phase/phase.h"
#include "pipeline/unwrap/unwrap.h"

namespace d3d::real_fringe {

struct KaminoOptions {
  std::string dir;  // .../fringe/kamino410/object2
  PhaseAlgorithm algorithm = PhaseAlgorithm::kAdaptiveHarmonic;
  double gamma = 1.64;             // the author's projector gamma estimate
  double period_px = 200.0 / 3.0;  // fringe period of pat00–02, projector px
  double cell_px = 100.0;          // Gray-code cell, projector px
  double bound_margin_px = 12.0;   // m: margin of the Gray-code phase bounds (cell-edge errors)
  double agree_tol_px = 1.5;       // c within the decoded cell ± this: agreement
  int black_threshold = 5;         // the author's GrayCodePattern thresholds
  int white_threshold = 40;
  int min_region_pixels = 2000;  // 2.3 Mpx images: drop specks below this
  int monotonic_x = 1;           // projector x grows with camera x here (measured, see report)
  // QualityOptions::modulation_edge_ratio, pinned here (its default is tuned for teeth and moves):
  // on this scene of textured mugs and a tiled wall, albedo edges are everywhere.
  double modulation_edge_ratio = 1.15;
  double depth_fraction = 0.97;  // UnwrapOptions::depth_fraction (the module's default)
  bool cross_check = true;       // also unwrap the 100-px set and compare the columns
};

struct KaminoReport {
  int width = 0, height = 0;
  // Frame order check: mean |W(φ_ours − φ_author)| with the author's formula
  // φ = atan2(√3(I1 − I3), 2 I2 − I1 − I3), I1..3 = pat00..02, over valid pixels [rad].
  double order_check_rad = 0.0;
  double order_check_swapped_rad = 0.0;  // the same for the naive order (pat00, pat01, pat02)
  double monotonic_corr = 0.0;           // share of Gray-valid horizontal steps where x cell grows
  int64_t phase_valid = 0, gray_valid = 0, unwrapped_valid = 0;
  int64_t both_valid = 0, agree = 0;  // unwrapped & Gray valid; of those c in the cell ± tol
  double agree_share = 0.0;
  double median_abs_err_px = 0.0;  // median distance of c outside its cell (0 inside), both valid
  // Gray decoding vs vizualized.png (x and y cell vs B, G mod 256 within ± agree_tol_px).
  int64_t viz_valid = 0, gray_viz_both = 0, gray_viz_agree = 0;
  double gray_viz_share = 0.0;
  // Our column c vs vizualized.png x (mod 256, wrap accounted for).
  int64_t c_viz_both = 0;
  double c_viz_median_px = 0.0, c_viz_within2_share = 0.0;
  // Column from the 66.67-px set vs from the 100-px set (pat03–05), both unwrapped [projector px].
  int64_t cross_count = 0;
  double cross_median_px = 0.0, cross_rms_px = 0.0, cross_signed_median_px = 0.0;
  // Signed median of c − viz x (the author's map stores an integer column).
  double c_viz_signed_median_px = 0.0;
  UnwrapStats stats;
  int regions_anchored = 0;
  double seconds = 0.0;
  cv::Mat disagreement;  // BGR: green agree, red disagree, grey only one valid, black neither
  cv::Mat viz_diff;      // BGR: |c − viz x| (mod 256): green ≤ 2 px, red > 2 px, grey one valid
  cv::Mat Phi;           // CV_32F unwrapped Φ, NaN where dropped
};

struct RelativeOptions {
  std::string dir;  // .../fringe/kylemcdonald/zhang or .../kyle
  PhaseAlgorithm algorithm = PhaseAlgorithm::kStandard;  // no calibration: no gamma to compensate
  double gamma = 1.0;
  int min_region_pixels = 400;
  int window_orders = 200;  // half-width W of the bound window [−2πW, 2πW] (int16 orders inside)
  double modulation_edge_ratio =
      0.0;  // QualityOptions, pinned: off (no teeth here; see KaminoOptions)
};

struct RelativeReport {
  int width = 0, height = 0;
  int64_t phase_valid = 0, unwrapped_valid = 0;
  int64_t pairs = 0, continuous = 0;  // 4-neighbour pairs in one region, of those |ΔΦ| < π
  double continuity_share = 0.0;
  double coverage = 0.0;  // unwrapped_valid / phase_valid
  int regions_anchored = 0, regions_total = 0;
  double seconds = 0.0;
  cv::Mat Phi;  // CV_32F, NaN where dropped; each region's Φ is relative (arbitrary 2π offset)
};

// kamino410/object2: phase, Gray-anchored unwrapping and the comparisons above. NOT_FOUND /
// PARSE_ERROR for missing or unreadable images.
[[nodiscard]] Status RunKamino(const KaminoOptions& options, KaminoReport* report);
// kylemcdonald/{zhang,kyle}: relative unwrapping and its continuity.
[[nodiscard]] Status RunRelative(const RelativeOptions& options, RelativeReport* report);
// Colour image of an unwrapped phase map (jet over its finite range, black where NaN).
cv::Mat PhaseImage(const cv::Mat& Phi);

}  // namespace d3d::real_fringe
