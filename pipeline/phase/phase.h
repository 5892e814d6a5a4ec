// Wrapped phase φ, modulation B and offset A from an N-step phase-shift burst, with compensation of
// the projector's non-sinusoidal (gamma) response, and detection of the absolute-phase marker that
// the probe hides in one of the frames (calib/model/probe_calibration.h, FringePatternSpec).
//
// Signal model (per camera pixel, DN):  I_n = A + B · w(Φ − δ_n),  δ_n = 2πn/N,
//   w(x) = cos x + Σ_{k≥2} ρ_k cos kx   (the projector's radiance waveform, normalised so that its
//   fundamental has unit amplitude; ρ_k = 0 for an ideal sinusoidal projector).
// A projector with an uncorrected power-law response r = p^γ displaying p = ½ + ½ cos x has
// ρ_2 = 0.286, ρ_3 = 0.011 at γ = 2.2 and ρ_2 = 0.375, ρ_3 = 0.052 at γ = 2.8. The N-step sums
// alias harmonics k ≡ ±1 (mod N) into the fundamental (phase error ≈ (ρ_{N+1} − ρ_{N−1}) sin NΦ),
// and the 3-frame fit that the marker forces inside its stripes aliases ρ_2 (errors up to 0.5 rad
// at γ = 2.2). Optical blur (defocus, diffraction, sub-surface scattering, camera blur) attenuates
// the harmonics by a factor that varies over the image.
//
// Algorithms (PhaseAlgorithm):
//   kStandard   the textbook N-step estimator φ = atan2(Σ I_n sin δ_n, Σ I_n cos δ_n), B = (2/N)|Σ
//   I_n e^{iδ_n}|
//               (e.g. Malacara, "Optical Shop Testing", 3rd ed., ch. 14); inside marker stripes the
//               plain least-squares fit of the N−1 unmarked frames.
//   kLutGamma   the published phase-error look-up table compensation of Zhang & Yau 2007 ("Generic
//               nonsinusoidal phase error correction for three-dimensional shape measurement using
//               a digital video projector", Appl. Opt. 46(1):36–43): the phase error as a function
//               of the measured wrapped phase is tabulated once and subtracted. Zhang & Yau measure
//               it on a flat board; we build it from the calibrated response (projector_gamma, the
//               DMD's 8-bit levels and pixel size), i.e. for an unblurred power-law waveform — the
//               same table for every pixel.
//   kAdaptiveHarmonic  (ours) "harmonic model with locally measured attenuation": the waveform's
//               harmonic ratios come from the calibrated response, ρ_k = ρ_k^γ · κ^{(k²−1)/3},
//               where κ ∈ [0, 1.5] is the local attenuation of the harmonics by optical blur (κ =
//               1: none; the exponent is that of a Gaussian blur, a_k/a_1 = exp(−(k²−1)σ²/2), κ =
//               a_2/a_1). κ is measured from the burst itself: the N-step set is redundant (N ≥ 4:
//               the consistency residual e = Σ w_n I_n, orthogonal to DC and the fundamental, sees
//               only harmonics, for N = 4 and the marker frame 3: e = I_3 − I_0 − I_2 + I_1 =
//               −4Bρ_2 cos 2Φ), and κ is the least-squares ratio of e to its unattenuated model
//               B·E_1(Φ) over 8×8-pixel tiles summed over 3×3 tiles, robustly: the median of those
//               local fits, then fits over 11×11 tiles and finally 3×3 tiles that each drop the
//               pixels the previous fit cannot explain (marker stripes, glints), falling back to
//               the wider fit where too few remain. Phase, modulation and offset are then read from
//               2-D tables (nearest κ row × measured phase, linear in phase) of the inverse of the
//               model's phase distortion. This builds on the harmonic error model of Hoang, Pan,
//               Nguyen & Wang 2010 and Pan, Kemao, Huang & Asundi 2009 ("Phase error analysis and
//               compensation for nonsinusoidal waveforms in phase-shifting digital fringe
//               projection profilometry", Opt. Lett. 34(4):416–418), who estimate the harmonic
//               ratios globally and iterate; ours takes their shape from the calibration and only
//               their attenuation, per region, from the data, and inverts by table instead of
//               iterating. For N = 3 (no redundancy) κ = options.kappa_prior.
//
// Marker (FringePatternSpec: frame m = marker_frame carries p' = p ± ½ in stripes one period wide;
// dissertation D3DscannerII, 4 images instead of 5): the N−1 unmarked frames give A, B, Φ (through
// the same harmonic model), predict frame m, and the marker is what the prediction misses: the
// normalised residual r = (e − B·E(Φ;κ))/B is matched against the stripe's known signature D(Φ;κ)
// (frame m brighter in the first half of a stripe period, darker in the second, blurred like the
// fringes), α = r·D/(D² + ε) averaged over marker_box_px² (5×5), marker where α > marker_threshold,
// then a marker_close_px² (3×3) closing (fills the blurred jump in the stripe's middle) and opening
// (drops isolated pixels). Inside the detected stripes dilated by marker_guard_px (transition
// pixels), and at pixels within marker_suspect_reach_px (12) of a stripe whose |r| > 0.3 (a partly
// marked or missed fringe), the phase comes from the N−1 unmarked frames. This is the
// dissertation's "modulation from 3 frames vs from 4" test made robust to the projector's 2nd
// harmonic, which alone would make that difference oscillate as cos 2Φ with an amplitude comparable
// to the marker's.
//
// In-burst motion (motion_compensation, N ≥ 4): the frames are taken one frame interval apart while
// the hand moves, so at a pixel Φ drifts by ε per frame (depth changes along the pixel's ray) and
// the fringe amplitude and offset drift by b and a per frame. To first order, frame n (time s_n =
// n − (N−1)/2 intervals from the burst's reference time, the middle of the burst) sees
//   I_n = A + s_n·a + (B + s_n·b)·w(Φ + s_n·ε − δ_n),
// which gives the N-step phase an error at 2Φ (for N = 4: (ε/2)·cos 2Φ + (b/2B)·sin 2Φ) and the
// offset drift one at Φ: about 11 µm RMS of depth at the probe's 12.5 mm/s. The same drift shows in
// the redundant residual e (for N = 4: e ∝ 2Bε(sin Φ + cos Φ) + 2b(sin Φ − cos Φ) + 2a), orthogonal
// to the κ term's cos 2Φ. So after κ, (ε, b/B, a/B) are fitted by least squares to the residual
// left by the κ model over the same tiles and windows as κ (residuals up to drift_exclusion·B:
// marker stripes and glints are left out), and φ, the N−1-frame φ and e (before marker detection)
// are corrected by their first-order error functions, tabulated from the estimators' own weights.
// The motion-compensated phase refers to the burst's reference time (the truth of the virtual
// probe's Burst::reference_truth). This is the first-order error model of motion in phase shifting
// (e.g. Weise, Leibe & Van Gool 2007, CVPR, "Fast 3D scanning with automatic motion compensation";
// Liu, Zhang et al. 2018, Opt. Express 26(10), "Motion-induced error compensation for phase
// shifting profilometry"), with the drift measured from the burst's own redundancy instead of from
// neighbouring bursts.
//
// A marker pixel's absolute phase is Φ = 2π·k + φ with k one of the marker orders
// (MarkerOrders(spec)); which one is decided downstream from the measurement volume (stripes are
// farther apart than the orders a pixel can take). φ near 0 or 2π lies at a stripe edge.
//
// Threads: PhaseEstimator::Compute is not reentrant (it owns scratch buffers); use one estimator
// per thread. ComputePhase() is thread-safe. Everything runs on the calling thread (no
// parallelism).
#pragma once

#include <memory>
#include <opencv2/core.hpp>
#include <vector>

#include "calib/model/probe_calibration.h"
#include "common/core/status.h"

namespace d3d {

enum class PhaseAlgorithm {
  kStandard,          // plain N-step (and plain N−1-frame fit inside marker stripes)
  kLutGamma,          // Zhang & Yau 2007 phase-error LUT from the calibrated gamma
  kAdaptiveHarmonic,  // ours: calibrated harmonic model with locally measured attenuation κ
};
const char* PhaseAlgorithmName(
    PhaseAlgorithm algorithm);  // "standard", "lut-gamma", "adaptive-harmonic"

struct PhaseOptions {
  PhaseAlgorithm algorithm = PhaseAlgorithm::kAdaptiveHarmonic;
  // A pixel is valid when no frame is saturated and its modulation B ≥ min_modulation_dn (DN of the
  // input; 4 DN is ≈ 2.5 σ of the 8-bit sensor's noise in one frame at mid-grey).
  double min_modulation_dn = 4.0;
  // A frame value ≥ saturation_dn counts as saturated. 0 = full scale of the input type (255 for
  // CV_8U, 65535 for CV_16U; set it for 10/12-bit data in CV_16U).
  double saturation_dn = 0.0;
  bool detect_marker = true;      // when the spec has a marker (needs N ≥ 4)
  double marker_threshold = 0.5;  // on α, the matched-filter marker amplitude (1 = a full stripe)
  int marker_guard_px = 2;  // camera px around detected stripes that use the N−1-frame phase
  // Pixel sizes of the marker detector, tuned where a fringe period spans ≈ 23 camera px (640 × 480
  // probe); scale them with the period (ReconstructOptions::scale_to_fringe_period does).
  int marker_box_px = 5;    // odd: α is averaged over a box of this size before the threshold
  int marker_close_px = 3;  // odd: closing (fills the blurred jump in a stripe's middle), opening
  int marker_suspect_reach_px =
      12;                    // |r| > 0.3 pixels this close to a stripe use the N−1-frame phase
  double kappa_prior = 1.0;  // κ where the data cannot tell (N = 3, γ = 1, no valid pixels)
  double kappa_exclusion = 0.25;  // |r| (B units) above which a pixel is left out of the κ fit
  int kappa_tile_px = 8;          // κ tiles (camera px) ...
  int kappa_window_tiles = 3;     // ... and the odd window of tiles each κ is fitted over
  // In-burst motion: fit and remove the phase drift (N ≥ 4, see above). Off by default: it removes
  // the drift of analytic frames (phase_test: 0.046 → 0.020 rad at γ = 2.2, 0.029 → 0.003 at γ =
  // 1), but on the virtual probe's bursts the marker stripes' residual leaks into the fit near the
  // stripes (static renders: 0.006 → 0.015 rad outside the stripes, 0.02 → 0.10 inside) and 50
  // moving bursts gain little (typodont 17.2 → 17.0 µm RMS, real arch 13.9 → 14.3 µm). Fitting the
  // drift after the marker is known is the next step. A hand-held scan turns it on all the same
  // (pipeline/chain HandHeldReconstructOptions): the uncompensated drift is alike in consecutive
  // views and biases their registration, which costs the fused arch more than the single view
  // loses.
  bool motion_compensation = false;
  double max_phase_drift_rad = 0.5;  // |ε| per frame interval is clamped to this (rad)
  double drift_exclusion = 0.5;      // residuals above this many B are left out of the drift fit
  int table_bins = 1024;             // phase bins of the compensation tables
  int table_rows = 121;              // κ rows of the tables over [0, 1.5] (nearest row is used)
  // > 1: the per-pixel passes (sums, compensation, marker score) run on blocks of rows as oneTBB
  // tasks (common/core/parallel_rows.h); the same bits as 1. The tile fits (κ, drift) stay serial.
  int threads = 1;
  void Check() const;  // throws std::invalid_argument
};

// Outputs of ComputePhase; all H×W like the frames.
struct PhaseMaps {
  cv::Mat phi;  // CV_32F wrapped phase φ ∈ [0, 2π) in the spec's convention (φ ≈ AbsolutePhase(c)
                // mod 2π for projector coordinate c), NaN where !valid
  cv::Mat modulation;  // CV_32F B, DN: amplitude of the fringes' fundamental
  cv::Mat offset;   // CV_32F A, DN: mean of the N frames (for marker pixels: of the frames as they
                    // would be without the marker)
  cv::Mat texture;  // offset rounded to the input's type (CV_8U or CV_16U)
  cv::Mat valid;    // CV_8U 255 = φ usable
  cv::Mat saturated;  // CV_8U 255 = some frame ≥ saturation_dn
  cv::Mat marker;     // CV_8U 255 = marker stripe detected (all 0 when the spec has none)
  cv::Mat
      marker_score;  // CV_32F α (matched-filter marker amplitude; empty without marker detection)
  cv::Mat kappa;     // CV_32F harmonic attenuation κ used per pixel (empty when not estimated)
  cv::Mat phase_drift;  // CV_32F ε, rad per frame interval: the in-burst drift of Φ removed per
                        // pixel (motion_compensation; empty when not estimated)
  int num_valid = 0;
  int num_saturated = 0;
  int num_marker = 0;
};

// Marker stripe orders of `spec` whose stripes may fall on the projector (coordinate range
// [0, projector_extent_px)); empty when the spec has no marker.
std::vector<int> MarkerOrders(const FringePatternSpec& spec, double projector_extent_px);

// Prepared tables for one (spec, gamma, options): build once, reuse per burst.
class PhaseEstimator {
 public:
  // Throws std::invalid_argument for an invalid spec/options, gamma ∉ (0.1, 10), or a marker with
  // N < 4 while options.detect_marker (the N−1 unmarked frames cannot determine A, B, Φ and κ).
  PhaseEstimator(const FringePatternSpec& spec, double projector_gamma,
                 const PhaseOptions& options);
  ~PhaseEstimator();
  PhaseEstimator(PhaseEstimator&&) noexcept;
  PhaseEstimator& operator=(PhaseEstimator&&) noexcept;

  // frames: exactly spec.steps images, frame n under pattern n, all H×W of one type, CV_8UC1 or
  // CV_16UC1 (H, W ≥ 1). INVALID_ARGUMENT for an empty list, a wrong count, an empty frame,
  // different sizes or types, or a type other than 8/16-bit single channel. Data problems (all
  // dark, saturated) are not errors: those pixels are invalid. Never writes NaN where valid.
  [[nodiscard]] Status Compute(const std::vector<cv::Mat>& frames, PhaseMaps* out);

  const FringePatternSpec& spec() const;
  const PhaseOptions& options() const;
  double projector_gamma() const;
  // The calibrated harmonic ratios ρ_k^γ (k = 0..; ρ_1 = 1) of the unblurred projector waveform.
  const std::vector<double>& harmonic_ratios() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// One-shot form: builds (and caches, for the last few (spec, gamma, options)) a PhaseEstimator.
[[nodiscard]] Status ComputePhase(const std::vector<cv::Mat>& frames, const FringePatternSpec& spec,
                                  double projector_gamma, const PhaseOptions& options,
                                  PhaseMaps* out);

}  // namespace d3d
