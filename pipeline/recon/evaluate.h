// Accuracy of a single-view reconstruction against the simulator's ground truth.
//
// Distance of a reconstructed point X (camera frame) to the true surface: the true surface point
// X_t hit by the same camera ray at the burst's reference pose, and its true normal n (the scene
// triangle's normal, from FrameTruth::face_index), give d = n · (X − X_t): the distance to the
// tangent plane, exact to second order in the lateral offset (≤ 1e-3 µm for the offsets here).
// For analytic shapes without a face the depth difference is used.
#pragma once

#include <opencv2/core.hpp>

#include "calib/model/probe_calibration.h"
#include "common/burst/burst.h"
#include "common/mesh/mesh.h"

namespace d3d {

struct CloudErrors {
  int64_t points = 0;    // reconstructed points that see a true surface
  int64_t spurious = 0;  // reconstructed points where the truth has no surface
  double rms_um = 0, mean_um = 0, mean_abs_um = 0, p95_um = 0, max_um = 0;  // |d| statistics, µm
  int64_t order_checked = 0;  // points with a true projector coordinate
  int64_t order_errors = 0;   // of those, |Φ − Φ_true| > π: a wrong fringe order (comparing
                              // k with floor(Φ_true/2π) would count noise across a wrap)
  double order_error_pct = 0;
  int64_t tooth_lit = 0;    // truth: tooth pixels lit by the projector
  int64_t tooth_valid = 0;  // of those, reconstructed
  double tooth_valid_pct = 0;
};

// points_in_cam: H×W CV_32FC3 (NaN = no point); Phi: H×W CV_32F absolute phase (NaN = none) or
// empty; truth: FrameTruth at the reference time with maps; scene: the mesh the truth refers to.
// error_um (optional): H×W CV_32F signed distance in µm, NaN where not evaluated.
CloudErrors EvaluateCloud(const cv::Mat& points_in_cam, const cv::Mat& Phi, const FrameTruth& truth,
                          const TriangleMesh& scene, const FringePatternSpec& spec,
                          cv::Mat* error_um = nullptr);

// The truth of `truth`'s frame as a camera binned factor × factor sees it (BinFrame, BinnedCamera),
// to evaluate a binned reconstruction with EvaluateCloud: a binned pixel whose block sees one
// smooth piece of surface (every pixel a surface, depth span ≤ 0.1 mm) gets the block's mean
// surface point and depth (the surface point at the block's centre, to ~(25 µm)² × curvature / 2),
// its top-left pixel's face (for the normal) and label (0 when the labels differ), and the mean
// projector pixel when the whole block is lit; visibility is the block's least. A block across a
// depth step has no point (EvaluateCloud skips it). `truth` must have maps with sizes divisible by
// factor (std::invalid_argument).
FrameTruth BinnedTruth(const FrameTruth& truth, int factor);

// False colour of a single-channel map: values in [lo, hi] through an OpenCV colour map
// (cv::COLORMAP_*), clipped outside; black where the value is NaN. H×W CV_8UC3 (BGR).
cv::Mat FalseColour(const cv::Mat& values, double lo, double hi, int colormap);

// A colour heat map of signed errors (blue −range … green 0 … red +range µm; black where NaN).
cv::Mat ErrorHeatMap(const cv::Mat& error_um, double range_um);

}  // namespace d3d
