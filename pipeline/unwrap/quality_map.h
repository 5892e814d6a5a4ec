// Per-pixel reliability of a wrapped phase map: the modulation–Laplace quality map, with the masks
// for shadow, low modulation, saturation and phase noise / discontinuities.
//
// Definition (all per pixel p, units in brackets):
//   W(d)   = d − 2π·round(d / 2π)                    wrap to (−π, π]
//   H(p)   = W(φ(x+1,y) − φ(x,y)) − W(φ(x,y) − φ(x−1,y))   wrapped second difference along x [rad]
//   V(p)   = the same along y [rad] The wrapped Laplacian is H + V; we use the energy of its two
//   components, D² = H² + V², so that the axes cannot cancel (Herráez et al. 2002, Appl. Opt.
//   41(35):7437, eq. 2, without the diagonal terms). On a smooth surface the unwrapped phase is
//   locally linear and D ≈ 0; phase noise of σ rad gives E[D²] = 12σ², and a fringe-order jump
//   hidden in a depth step of s fringes gives D ≈ 2π·|s − round(s)| at the pixels beside it. Masked
//   pixels (any reason below) do not enter their neighbours' differences. Where the centred
//   difference along an axis is unavailable, the one-sided one (pixels x, x+1, x+2, else x−2, x−1,
//   x) is used; an axis with neither is left out (D² = 2·(the other)²); with neither axis the pixel
//   is `kIsolated`. Q_B(p) = min(1, B(p) / full_modulation)           modulation term: the phase
//   noise of an N-step
//            shift is σ_φ = σ_I·√(2/N) / B (Zhang, Li & Yau 2007, Appl. Opt. 46(1):50, use B as the
//            quality of the multilevel quality-guided unwrapping), so more B = less noise
//   Q_L(p) = 1 / (1 + D² / laplace_ref²)               Laplace term: 1 on smooth phase, → 0 at
//   noise
//            and discontinuities
//   Q(p)   = Q_B · Q_L ∈ (0, 1], or 0 where a mask applies (see QualityReason).
//   Albedo-edge mask: where B(p+1)/B(p−1) along x or y leaves [1/r, r] (r = modulation_edge_ratio),
//   optionally with one-pixel gaps bridged (modulation_edge_close), Q = 0 (kModulationEdge). A
//   tooth/gingiva border (albedo ≈ 0.70 vs 0.35) often hides a depth step of nearly one fringe that
//   the optics blur into a smooth-looking phase ramp (−0.3…−0.6 rad over a few pixels) which
//   neither the Laplace term nor the unwrapper's jump tests catch; the modulation changes sharply
//   there, so the cut keeps the unwrapper's regions from crossing it.
// The dissertation's modulation–Laplace quality combines the same two measures (modulation for the
// signal-to-noise ratio, the Laplacian of the wrapped phase for noise and discontinuities); the
// product form and the constants here are ours and are documented in QualityOptions.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>

#include "common/core/status.h"

namespace d3d {

// Why a pixel got quality 0 (the `reason` output of ComputeQualityMap).
enum class QualityReason : uint8_t {
  kUsable = 0,         // quality > 0
  kInvalid = 1,        // valid == 0, or φ / B not finite
  kShadow = 2,         // B < shadow_modulation: no projector light (projector shadow, background)
  kLowModulation = 3,  // B < min_modulation: too dark / too defocused to trust the phase
  kSaturated = 4,      // peak intensity ≥ saturation_level (only when `peak` is given)
  kPhaseNoise = 5,     // D > max_laplace: noise or a discontinuity
  kIsolated = 6,       // no second difference along either axis (too few usable neighbours)
  kModulationEdge =
      7,  // B changes by more than modulation_edge_ratio across the pixel: an albedo
          // edge (tooth/gingiva) that may hide a depth step, see modulation_edge_ratio
};

struct QualityOptions {
  double shadow_modulation = 2.0;   // DN; B below: shadow (reason kShadow)
  double min_modulation = 4.0;      // DN; B below: low modulation (reason kLowModulation)
  double full_modulation = 24.0;    // DN; B at and above which Q_B = 1
  double laplace_ref = 0.6;         // rad; D at which Q_L = ½
  double max_laplace = 1.5;         // rad; D above: quality 0 (reason kPhaseNoise)
  double saturation_level = 254.5;  // DN; peak ≥ this: saturated (only with a `peak` image)
  // Albedo edges: where B(p+1)/B(p−1) along x or y (centred, both neighbours with B ≥
  // min_modulation) lies outside [1/ratio, ratio], the pixel gets quality 0 (kModulationEdge). A
  // tooth/gingiva border (albedo ≈ 0.70 vs 0.35) often carries a depth step of nearly a whole
  // fringe that the optics blur into a smooth-looking phase ramp; the modulation step is sharp
  // there, so the unwrapper's regions must not cross it. On a smooth surface B varies slowly (n_z,
  // defocus). 0 = off.
  double modulation_edge_ratio = 1.2;
  // ... and only where the two neighbours' B also differ by at least this [DN] (B noise on dark
  // gingiva would otherwise mark scattered pixels).
  double modulation_edge_min_dn = 0.0;
  // Gap bridging (0 = off, 1 = on): a pixel between two edge pixels on opposite sides (left and
  // right, above and below, or diagonally) becomes an edge pixel too, so a one-pixel gap in a cut
  // (noise, a corner where two borders meet) does not let a region leak around it. The minimal
  // closing: it widens nothing else. Off by default: on the teeth it gains a few % of the tooth
  // pixels, but on strongly textured scenes (tests/real_fringe_test, Kamino) it cuts too much.
  int modulation_edge_close = 0;

  // Throws std::invalid_argument unless 0 ≤ shadow ≤ min, 0 < min < full, 0 < laplace_ref,
  // 0 < max_laplace, saturation_level > 0, modulation_edge_ratio 0 or > 1, modulation_edge_min_dn ≥
  // 0 and modulation_edge_close 0 or 1 (all finite).
  void Check() const;
};

// Computes the quality map of a wrapped phase map.
//   phi         H×W CV_32F wrapped phase φ [rad]; any finite value is taken modulo 2π (the
//               contract of pipeline/phase is [0, 2π)); NaN = invalid
//   modulation  H×W CV_32F fringe modulation B [DN] (I_n = A + B cos(Φ − δ_n))
//   valid       H×W CV_8U, nonzero = usable; an empty Mat means every pixel
//   quality     out: H×W CV_32F Q ∈ [0, 1], 0 = unusable (reused if already allocated)
//   reason      optional out: H×W CV_8U QualityReason per pixel
// INVALID_ARGUMENT for empty input, mismatched sizes or types, or invalid options; nothing is
// written then. Never writes NaN.
[[nodiscard]] Status ComputeQualityMap(const cv::Mat& phi, const cv::Mat& modulation,
                                       const cv::Mat& valid, const QualityOptions& options,
                                       cv::Mat* quality, cv::Mat* reason = nullptr);

// The same with the saturation mask: `peak` is H×W CV_8U or CV_32F, the brightest value of the
// pixel over the burst's frames [DN]; pixels with peak ≥ saturation_level get quality 0
// (a clipped sinusoid biases φ). An empty `peak` skips the saturation test.
[[nodiscard]] Status ComputeQualityMap(const cv::Mat& phi, const cv::Mat& modulation,
                                       const cv::Mat& valid, const cv::Mat& peak,
                                       const QualityOptions& options, cv::Mat* quality,
                                       cv::Mat* reason = nullptr);

}  // namespace d3d
