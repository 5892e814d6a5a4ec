// The projector waveform model behind the phase compensation (phase.h) and its look-up tables.
// Internal to d3d_phase; exposed for tests.
//
// Waveform of frame n at absolute phase Φ, normalised to a unit fundamental (DC dropped):
//   w(Φ − δ_n; κ) = Σ_{k≥1} ρ_k^γ · κ^{(k²−1)/3} · cos k(Φ − δ_n)
// ρ_k^γ: Fourier ratios c_k/c_1 of the DMD's radiance (round(255·(½ + ½ cos x))/255)^γ, times the
// relative attenuation sinc(k/T)/sinc(1/T) of the DMD pixel (box of 1 projector px, T = period).
// κ: attenuation of the harmonics by optical blur (Gaussian blur σ rad: κ = exp(−3σ²/2)).
//
// Tables, per κ row j (κ_j = kKappaMax·j/(rows−1)) and measured phase bin i (φ'_i = 2πi/bins, one
// extra bin for interpolation across 2π):
//   full[j][i]  : the N-step estimator (C + iS = Σ I_n e^{iδ_n}·2/N):
//                 corr = Φ − φ' (true minus measured phase), ginv = 1/|C + iS| per unit B,
//                 e = E(Φ; κ_j), the consistency residual per unit B at that Φ, e1 = E(Φ; 1).
//   sub[j][i]   : the least-squares fit of the N−1 frames other than the marker frame (only with a
//                 marker): corr, ginv, e = E(Φ; κ_j), d = D(Φ; κ_j) the marker's signature (change
//                 of frame m inside a stripe per unit B, blurred with the κ's σ), off = DC of the
//                 fit minus the mean of the N unmarked frames, per unit B.
#pragma once

#include <vector>

#include "calib/model/probe_calibration.h"

namespace d3d::phase_internal {

constexpr double kKappaMax = 1.5;

struct FullEntry {
  float corr, ginv, e, e1;  // e1 = E(Φ; κ = 1), the basis of the κ fit, at this row's Φ
};
struct SubEntry {
  float corr, ginv, e, d, off;
};

class PhaseModel {
 public:
  PhaseModel(const FringePatternSpec& spec, double gamma, bool with_marker, int bins, int rows);

  int steps() const { return steps_; }
  int bins() const { return bins_; }
  int rows() const { return rows_; }
  bool has_residual() const { return has_residual_; }  // N ≥ 4 or a marker
  bool has_marker() const { return marker_frame_ >= 0; }
  bool residual_informative() const { return residual_rms_ > 1e-4; }  // κ can be measured
  int marker_frame() const { return marker_frame_; }
  const std::vector<double>& harmonic_ratios() const { return rho_; }
  double KappaStep() const { return kKappaMax / (rows_ - 1); }
  int RowOf(double kappa) const;  // nearest row

  // Per-frame linear weights (size N): C = Σ c_n I_n, S = Σ s_n I_n (|C + iS| = B for a sinusoid),
  // mean = Σ I_n / N, residual e = Σ r_n I_n; sub-fit (marker frame weight 0): dc, a (cos), b
  // (sin).
  const std::vector<float>& cos_w() const { return cw_; }
  const std::vector<float>& sin_w() const { return sw_; }
  const std::vector<float>& res_w() const { return rw_; }
  const std::vector<float>& sub_dc_w() const { return dw_; }
  const std::vector<float>& sub_cos_w() const { return aw_; }
  const std::vector<float>& sub_sin_w() const { return bw_; }

  const FullEntry* full_row(int j) const { return &full_[static_cast<size_t>(j) * (bins_ + 1)]; }
  const SubEntry* sub_row(int j) const { return &sub_[static_cast<size_t>(j) * (bins_ + 1)]; }

  // Model waveform of frame n (without marker) at Φ for attenuation κ, per unit B (no DC).
  double Waveform(int frame, double Phi, double kappa) const;

 private:
  void BuildRow(int j);
  // The marker's change of frame m per unit B over one stripe period (Φ mod 2π = position in the
  // stripe), blurred for attenuation κ; kMarkerGrid samples.
  std::vector<double> BlurredMarkerSignature(double kappa) const;
  int steps_;
  int marker_frame_;
  int bins_, rows_;
  bool has_residual_ = false;
  double gamma_;
  double period_px_;
  double residual_rms_ = 0.0;
  double c1_ = 0.5;  // fundamental amplitude of the unblurred radiance waveform
  std::vector<double> rho_;
  std::vector<double> marker_delta_;
  std::vector<double> e1_at_;  // E(Φ; κ = 1) on the fine grid of BuildRow  // Δr(x) over one stripe
                               // period (kMarkerGrid samples), per c1
  std::vector<float> cw_, sw_, rw_, dw_, aw_, bw_;
  std::vector<FullEntry> full_;
  std::vector<SubEntry> sub_;
};

// atan2 in [0, 2π), branch-free (vectorisable), |error| < 1e-6 rad.
inline float FastAtan2Pos(float y, float x) {
  constexpr float kPi = 3.14159265358979f, kHalfPi = 1.57079632679490f, kTwoPi = 6.28318530717959f;
  const float ax = x < 0 ? -x : x, ay = y < 0 ? -y : y;
  const float mn = ax < ay ? ax : ay, mx = ax < ay ? ay : ax;
  const float a = mn / (mx + 1e-30f);
  const float s = a * a;
  float r = -0.004073924739f;  // least-squares fit of atan(a)/a in a², |error| < 5e-8 on [0, 1]
  r = r * s + 0.021948928994f;
  r = r * s - 0.056066670518f;
  r = r * s + 0.096565246178f;
  r = r * s - 0.139159123644f;
  r = r * s + 0.199485321137f;
  r = r * s - 0.333301087963f;
  r = r * s + 0.999999437381f;
  r *= a;
  r = ay > ax ? kHalfPi - r : r;
  r = x < 0 ? kPi - r : r;
  r = y < 0 ? kTwoPi - r : r;
  return r >= kTwoPi ? 0.0f : r;
}

}  // namespace d3d::phase_internal
