#include "pipeline/phase/phase_model.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

#include "common/core/status.h"

namespace d3d::phase_internal {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kTwoPi = 2.0 * kPi;
constexpr int kHarmonics = 16;  // waveform harmonics kept (ρ_k for k > 8 are < 1e-5 for γ ≤ 3)
constexpr int kMarkerGrid = 512;      // samples of the marker signature over one stripe period
constexpr double kMaxSigmaRad = 1.2;  // blur cap for the marker signature (κ < 0.115)

double Sinc(double z) { return z == 0.0 ? 1.0 : std::sin(kPi * z) / (kPi * z); }

// DMD level of a pattern value, as the virtual probe and the probe's firmware quantise it.
double Dmd(double p) { return std::round(std::clamp(p, 0.0, 1.0) * 255.0) / 255.0; }

double WrapSigned(double a) { return a - kTwoPi * std::floor((a + kPi) / kTwoPi); }

// Σ_n weights[n] · values[n].
double Dot(const std::vector<float>& w, const std::vector<double>& v) {
  double s = 0;
  for (size_t n = 0; n < w.size(); ++n) s += w[n] * v[n];
  return s;
}

// For a phase map u(Φ_i) (i = 0..F−1, Φ_i = 2πi/F) that increases by 2π over a period, the fine
// index f (fractional, in [0, F)) at which u ≡ target (mod 2π), first crossing if not monotone.
class Inverter {
 public:
  explicit Inverter(const std::vector<double>& wrapped) {
    const size_t F = wrapped.size();
    u_.resize(2 * F + 1);
    u_[0] = wrapped[0];
    for (size_t i = 1; i < F; ++i) u_[i] = u_[i - 1] + WrapSigned(wrapped[i] - wrapped[i - 1]);
    // One period of Φ advances the measured phase by one turn: close the loop exactly.
    for (size_t i = 0; i <= F; ++i) u_[F + i] = (i < F ? u_[i] : u_[0] + kTwoPi) + kTwoPi;
    for (size_t i = 1; i < u_.size(); ++i) u_[i] = std::max(u_[i], u_[i - 1]);  // first crossing
    F_ = static_cast<double>(F);
  }
  double Find(double target) const {
    const double t = target + kTwoPi * std::ceil((u_[0] - target) / kTwoPi);
    const auto it = std::upper_bound(u_.begin(), u_.end(), t);
    const size_t k = static_cast<size_t>(
        std::clamp<std::ptrdiff_t>(it - u_.begin(), 1, static_cast<std::ptrdiff_t>(u_.size()) - 1));
    const double lo = u_[k - 1], hi = u_[k];
    const double frac = hi > lo ? std::clamp((t - lo) / (hi - lo), 0.0, 1.0) : 0.0;
    return std::fmod(static_cast<double>(k - 1) + frac, F_);
  }

 private:
  std::vector<double> u_;
  double F_ = 1;
};

// Linear interpolation of a periodic array at fractional index f.
double Lerp(const std::vector<double>& a, double f) {
  const size_t F = a.size();
  const double fl = std::floor(f);
  const size_t i0 = static_cast<size_t>(fl) % F, i1 = (i0 + 1) % F;
  const double t = f - fl;
  return a[i0] + t * (a[i1] - a[i0]);
}

}  // namespace

PhaseModel::PhaseModel(const FringePatternSpec& spec, double gamma, bool with_marker, int bins,
                       int rows)
    : steps_(spec.steps),
      marker_frame_(with_marker && spec.HasMarker() ? spec.marker_frame : -1),
      bins_(bins),
      rows_(rows),
      gamma_(gamma),
      period_px_(spec.fringe_period_px) {
  spec.Check();
  D3D_CHECK_MSG(gamma > 0.1 && gamma < 10.0, "projector gamma " << gamma << " is implausible");
  D3D_CHECK_MSG(bins >= 64 && rows >= 2, "tables need ≥ 64 bins and ≥ 2 rows");
  D3D_CHECK_MSG(marker_frame_ < 0 || steps_ >= 4,
                "a marker frame needs N ≥ 4 steps, got " << steps_);
  const int N = steps_;

  // Harmonic ratios of the DMD's radiance waveform (8-bit levels, power law, 1-px box).
  constexpr int kQ = 8192;
  std::vector<double> c(kHarmonics + 1, 0.0);
  for (int i = 0; i < kQ; ++i) {
    const double x = kTwoPi * i / kQ;
    const double r = std::pow(Dmd(0.5 + 0.5 * std::cos(x)), gamma);
    for (int k = 0; k <= kHarmonics; ++k) c[k] += r * std::cos(k * x);
  }
  for (int k = 0; k <= kHarmonics; ++k) c[k] *= (k == 0 ? 1.0 : 2.0) / kQ;
  c1_ = c[1];
  rho_.assign(kHarmonics + 1, 0.0);
  for (int k = 0; k <= kHarmonics; ++k) {
    const double box = k == 0 ? 1.0 : Sinc(k / period_px_) / Sinc(1.0 / period_px_);
    rho_[k] = c[k] / c[1] * box;
  }

  // Linear weights of the estimators.
  cw_.resize(N);
  sw_.resize(N);
  rw_.assign(N, 0.0f);
  dw_.assign(N, 0.0f);
  aw_.assign(N, 0.0f);
  bw_.assign(N, 0.0f);
  for (int n = 0; n < N; ++n) {
    const double d = kTwoPi * n / N;
    cw_[n] = static_cast<float>(2.0 / N * std::cos(d));
    sw_[n] = static_cast<float>(2.0 / N * std::sin(d));
  }
  if (marker_frame_ >= 0) {
    // Least-squares fit of A + a cos δ + b sin δ to the N−1 frames n ≠ m, and the residual of frame
    // m.
    Eigen::MatrixXd X(N - 1, 3);
    for (int n = 0, r = 0; n < N; ++n) {
      if (n == marker_frame_) continue;
      const double d = kTwoPi * n / N;
      X.row(r++) << 1.0, std::cos(d), std::sin(d);
    }
    const Eigen::MatrixXd pinv = (X.transpose() * X).inverse() * X.transpose();  // 3 × (N−1)
    const double dm = kTwoPi * marker_frame_ / N;
    const Eigen::RowVector3d xm(1.0, std::cos(dm), std::sin(dm));
    const Eigen::RowVectorXd predict = xm * pinv;
    for (int n = 0, r = 0; n < N; ++n) {
      if (n == marker_frame_) {
        rw_[n] = 1.0f;
        continue;
      }
      dw_[n] = static_cast<float>(pinv(0, r));
      aw_[n] = static_cast<float>(pinv(1, r));
      bw_[n] = static_cast<float>(pinv(2, r));
      rw_[n] = static_cast<float>(-predict(r));
      ++r;
    }
    has_residual_ = true;

    // Marker change of frame m over one stripe period, per unit c1 (before blur).
    marker_delta_.assign(kMarkerGrid, 0.0);
    const double w = spec.marker_width_periods;
    for (int i = 0; i < kMarkerGrid; ++i) {
      const double x = kTwoPi * (i + 0.5) / kMarkerGrid;
      if (w < 1.0 && std::abs(x - kPi) >= kPi * w) continue;
      const double p = 0.5 + 0.5 * std::cos(x - dm);
      const double pm = p < 0.5 ? p + 0.5 : p - 0.5;
      marker_delta_[i] = (std::pow(Dmd(pm), gamma) - std::pow(Dmd(p), gamma)) / c1_;
    }
  } else if (N >= 4) {
    for (int n = 0; n < N; ++n)
      rw_[n] = static_cast<float>(2.0 / N * std::cos(2.0 * kTwoPi * n / N));
    has_residual_ = true;
  }

  full_.resize(static_cast<size_t>(rows_) * (bins_ + 1));
  if (marker_frame_ >= 0) sub_.resize(static_cast<size_t>(rows_) * (bins_ + 1));
  // Build the κ = 1 row first: its residual is the basis e1 of every row.
  const int j1 = RowOf(1.0);
  BuildRow(j1);
  for (int j = 0; j < rows_; ++j)
    if (j != j1) BuildRow(j);
}

int PhaseModel::RowOf(double kappa) const {
  return std::clamp(static_cast<int>(std::lround(kappa / KappaStep())), 0, rows_ - 1);
}

double PhaseModel::Waveform(int frame, double Phi, double kappa) const {
  const double x = Phi - kTwoPi * frame / steps_;
  double w = 0;
  for (int k = 1; k <= kHarmonics; ++k)
    w += rho_[k] * std::pow(kappa, (k * k - 1) / 3.0) * std::cos(k * x);
  return w;
}

std::vector<double> PhaseModel::BlurredMarkerSignature(double kappa) const {
  // Gaussian blur σ (rad) that attenuates harmonic k relative to the fundamental by κ^{(k²−1)/3},
  // plus the DMD pixel's box (variance (2π/T)²/12), whose harmonic attenuation is already in ρ_k.
  const double sigma_k2 = kappa >= 1.0 ? 0.0
                          : kappa <= 0.0
                              ? kMaxSigmaRad * kMaxSigmaRad
                              : std::min(-2.0 * std::log(kappa) / 3.0, kMaxSigmaRad * kMaxSigmaRad);
  const double box = kTwoPi / period_px_;
  const double sigma2 = sigma_k2 + box * box / 12.0;
  const double sigma = std::sqrt(sigma2);
  const double step = kTwoPi / kMarkerGrid;
  const int half = static_cast<int>(std::ceil(4.0 * sigma / step));
  std::vector<double> kernel(2 * half + 1);
  double ksum = 0;
  for (int i = -half; i <= half; ++i)
    ksum += kernel[i + half] = std::exp(-0.5 * (i * step) * (i * step) / sigma2);
  const double norm = 1.0 / (ksum * std::exp(-0.5 * sigma2));  // per unit blurred fundamental
  std::vector<double> out(kMarkerGrid, 0.0);
  for (int i = 0; i < kMarkerGrid; ++i) {
    double s = 0;
    for (int k = -half; k <= half; ++k) {
      const int src = i - k;  // outside [0, grid) the neighbouring periods carry no marker
      if (src >= 0 && src < kMarkerGrid) s += kernel[k + half] * marker_delta_[src];
    }
    out[i] = s * norm;
  }
  return out;
}

void PhaseModel::BuildRow(int j) {
  const int N = steps_;
  const double kappa = KappaStep() * j;
  const int F = 4 * bins_;
  std::vector<double> amp(kHarmonics + 1, 0.0);
  for (int k = 1; k <= kHarmonics; ++k)
    amp[k] = rho_[k] * (k == 1 ? 1.0 : std::pow(kappa, (k * k - 1) / 3.0));
  // Waveform on the fine grid.
  std::vector<double> cos_table(F), wave(F, 0.0);
  for (int i = 0; i < F; ++i) cos_table[i] = std::cos(kTwoPi * i / F);
  for (int i = 0; i < F; ++i) {
    double w = 0;
    for (int k = 1; k <= kHarmonics; ++k)
      if (amp[k] != 0.0) w += amp[k] * cos_table[(static_cast<size_t>(k) * i) % F];
    wave[i] = w;
  }
  std::vector<double> signature;
  if (marker_frame_ >= 0) signature = BlurredMarkerSignature(kappa);

  std::vector<double> phi_full(F), g_full(F), e_at(F), mean_at(F), phi_sub, g_sub, off_at, d_at;
  if (marker_frame_ >= 0) {
    phi_sub.resize(F);
    g_sub.resize(F);
    off_at.resize(F);
    d_at.resize(F);
  }
  std::vector<double> I(N);
  for (int i = 0; i < F; ++i) {
    for (int n = 0; n < N; ++n)
      I[n] = Lerp(wave, std::fmod(i - static_cast<double>(F) * n / N + F, F));
    const double C = Dot(cw_, I), S = Dot(sw_, I);
    phi_full[i] = std::atan2(S, C);
    g_full[i] = std::hypot(C, S);
    e_at[i] = has_residual_ ? Dot(rw_, I) : 0.0;
    double mean = 0;
    for (double v : I) mean += v;
    mean_at[i] = mean / N;
    if (marker_frame_ >= 0) {
      const double a = Dot(aw_, I), b = Dot(bw_, I);
      phi_sub[i] = std::atan2(b, a);
      g_sub[i] = std::hypot(a, b);
      off_at[i] = Dot(dw_, I) - mean_at[i];
      const double pos =
          static_cast<double>(i) / F * kMarkerGrid - 0.5;  // signature sample centres
      d_at[i] = pos <= 0                 ? signature.front()
                : pos >= kMarkerGrid - 1 ? signature.back()
                                         : Lerp(signature, pos);
    }
  }
  if (j == RowOf(1.0)) {
    double s2 = 0;
    for (double v : e_at) s2 += v * v;
    residual_rms_ = std::sqrt(s2 / F);
    e1_at_ = e_at;
  }

  FullEntry* full = &full_[static_cast<size_t>(j) * (bins_ + 1)];
  const Inverter inv_full(phi_full);
  for (int b = 0; b < bins_; ++b) {
    const double target = kTwoPi * b / bins_;
    const double f = inv_full.Find(target);
    const double Phi = kTwoPi * f / F;
    full[b].corr = static_cast<float>(WrapSigned(Phi - target));
    full[b].ginv = static_cast<float>(1.0 / std::max(Lerp(g_full, f), 1e-3));
    full[b].e = static_cast<float>(Lerp(e_at, f));
    full[b].e1 = static_cast<float>(Lerp(e1_at_, f));
  }
  full[bins_] = full[0];
  if (marker_frame_ < 0) return;
  SubEntry* sub = &sub_[static_cast<size_t>(j) * (bins_ + 1)];
  const Inverter inv_sub(phi_sub);
  for (int b = 0; b < bins_; ++b) {
    const double target = kTwoPi * b / bins_;
    const double f = inv_sub.Find(target);
    const double Phi = kTwoPi * f / F;
    sub[b].corr = static_cast<float>(WrapSigned(Phi - target));
    sub[b].ginv = static_cast<float>(1.0 / std::max(Lerp(g_sub, f), 1e-3));
    sub[b].e = static_cast<float>(Lerp(e_at, f));
    sub[b].d = static_cast<float>(Lerp(d_at, f));
    sub[b].off = static_cast<float>(Lerp(off_at, f));
  }
  sub[bins_] = sub[0];
}

}  // namespace d3d::phase_internal
