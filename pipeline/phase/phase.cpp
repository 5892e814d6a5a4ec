#include "pipeline/phase/phase.h"

#include <tbb/enumerable_thread_specific.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <list>
#include <mutex>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string>
#include <utility>

#include "common/core/parallel_rows.h"
#include "pipeline/phase/phase_model.h"

namespace d3d {

using phase_internal::FastAtan2Pos;
using phase_internal::FullEntry;
using phase_internal::PhaseModel;
using phase_internal::SubEntry;

namespace {

constexpr float kTwoPiF = 6.28318530717958647692f;
constexpr float kMarkerEps = 0.01f;  // ε of the matched filter α = r·D/(D² + ε)
constexpr int kKappaStride = 2;      // κ is fitted on every 2nd pixel of every 2nd row
constexpr int kDriftRows = 16;  // κ rows of the motion-compensation tables over [0, kKappaMax]

inline int DriftRow(float kappa) {
  const int j = static_cast<int>(
      kappa * ((kDriftRows - 1) / static_cast<float>(phase_internal::kKappaMax)) + 0.5f);
  return j < 0 ? 0 : (j >= kDriftRows ? kDriftRows - 1 : j);
}
constexpr float kSuspect = 0.3f;  // |r| (B units) above which the N-step result is not trusted

inline float WrapPos(float a) {
  a = a < 0.0f ? a + kTwoPiF : a;
  return a >= kTwoPiF ? a - kTwoPiF : a;
}

// Position of a phase in a table of `bins` bins over [0, 2π): bin index and fraction.
struct BinPos {
  int i;
  float t;
};
inline BinPos PhaseBin(float phi, float bins_per_rad, int bins) {
  const float x = phi * bins_per_rad;
  int i = static_cast<int>(x);
  i = i < 0 ? 0 : (i >= bins ? bins - 1 : i);
  return {i, x - static_cast<float>(i)};
}

// Nearest κ row of the tables (rows are 1.5/(rows−1) apart: 0.0125 by default).
inline int KappaRow(float kappa, float rows_per_kappa, int rows) {
  int j = static_cast<int>(kappa * rows_per_kappa + 0.5f);
  return j < 0 ? 0 : (j >= rows ? rows - 1 : j);
}

// Linear interpolation in φ' within one κ row.
inline FullEntry ReadFullRow(const FullEntry* row, BinPos b) {
  const FullEntry& a = row[b.i];
  const FullEntry& c = row[b.i + 1];
  return {a.corr + b.t * (c.corr - a.corr), a.ginv + b.t * (c.ginv - a.ginv),
          a.e + b.t * (c.e - a.e), a.e1 + b.t * (c.e1 - a.e1)};
}
inline SubEntry ReadSubRow(const SubEntry* row, BinPos b) {
  const SubEntry& a = row[b.i];
  const SubEntry& c = row[b.i + 1];
  return {a.corr + b.t * (c.corr - a.corr), a.ginv + b.t * (c.ginv - a.ginv),
          a.e + b.t * (c.e - a.e), a.d + b.t * (c.d - a.d), a.off + b.t * (c.off - a.off)};
}

std::string ModelKey(const FringePatternSpec& s, double gamma, bool marker, int bins, int rows) {
  std::ostringstream os;
  os.precision(17);
  os << s.steps << '|' << s.fringe_period_px << '|' << (marker ? s.marker_frame : -1) << '|'
     << s.marker_width_periods << '|' << gamma << '|' << bins << '|' << rows;
  return os.str();
}

// Models are immutable once built: share them between estimators (the last few keys).
std::shared_ptr<const PhaseModel> CachedModel(const FringePatternSpec& spec, double gamma,
                                              bool marker, int bins, int rows) {
  static std::mutex mutex;
  static std::list<std::pair<std::string, std::shared_ptr<const PhaseModel>>> cache;
  const std::string key = ModelKey(spec, gamma, marker, bins, rows);
  {
    std::lock_guard<std::mutex> lock(mutex);
    for (auto it = cache.begin(); it != cache.end(); ++it)
      if (it->first == key) {
        cache.splice(cache.begin(), cache, it);
        return cache.front().second;
      }
  }
  auto model = std::make_shared<const PhaseModel>(spec, gamma, marker, bins, rows);
  std::lock_guard<std::mutex> lock(mutex);
  cache.emplace_front(key, model);
  while (cache.size() > 8) cache.pop_back();
  return model;
}

template <typename T>
void ToFloat(const T* src, float* dst, int W) {
  for (int x = 0; x < W; ++x) dst[x] = static_cast<float>(src[x]);
}

void Accumulate(const float* w, const std::vector<std::vector<float>>& f, int W, float* out) {
  std::fill(out, out + W, 0.0f);
  for (size_t n = 0; n < f.size(); ++n) {
    const float c = w[n];
    if (c == 0.0f) continue;
    const float* src = f[n].data();
    for (int x = 0; x < W; ++x) out[x] += c * src[x];
  }
}

}  // namespace

const char* PhaseAlgorithmName(PhaseAlgorithm algorithm) {
  switch (algorithm) {
    case PhaseAlgorithm::kStandard:
      return "standard";
    case PhaseAlgorithm::kLutGamma:
      return "lut-gamma";
    case PhaseAlgorithm::kAdaptiveHarmonic:
      return "adaptive-harmonic";
  }
  return "?";
}

void PhaseOptions::Check() const {
  D3D_CHECK_MSG(algorithm == PhaseAlgorithm::kStandard || algorithm == PhaseAlgorithm::kLutGamma ||
                    algorithm == PhaseAlgorithm::kAdaptiveHarmonic,
                "unknown phase algorithm " << static_cast<int>(algorithm));
  D3D_CHECK_MSG(std::isfinite(min_modulation_dn) && min_modulation_dn >= 0.0,
                "min_modulation_dn must be ≥ 0, got " << min_modulation_dn);
  D3D_CHECK_MSG(std::isfinite(saturation_dn) && saturation_dn >= 0.0,
                "saturation_dn must be ≥ 0, got " << saturation_dn);
  D3D_CHECK_MSG(marker_threshold > 0.0 && marker_threshold < 2.0,
                "marker_threshold must be in (0, 2), got " << marker_threshold);
  D3D_CHECK_MSG(marker_guard_px >= 0 && marker_guard_px <= 32,
                "marker_guard_px must be in [0, 32], got " << marker_guard_px);
  D3D_CHECK_MSG(marker_box_px >= 1 && marker_box_px <= 63 && marker_box_px % 2 == 1,
                "marker_box_px must be odd in [1, 63], got " << marker_box_px);
  D3D_CHECK_MSG(marker_close_px >= 1 && marker_close_px <= 31 && marker_close_px % 2 == 1,
                "marker_close_px must be odd in [1, 31], got " << marker_close_px);
  D3D_CHECK_MSG(marker_suspect_reach_px >= 0 && marker_suspect_reach_px <= 128,
                "marker_suspect_reach_px must be in [0, 128], got " << marker_suspect_reach_px);
  D3D_CHECK_MSG(
      kappa_prior >= 0.0 && kappa_prior <= phase_internal::kKappaMax,
      "kappa_prior must be in [0, " << phase_internal::kKappaMax << "], got " << kappa_prior);
  D3D_CHECK_MSG(kappa_exclusion > 0.0, "kappa_exclusion must be > 0, got " << kappa_exclusion);
  D3D_CHECK_MSG(kappa_tile_px >= 2 && kappa_tile_px <= 256,
                "kappa_tile_px must be in [2, 256], got " << kappa_tile_px);
  D3D_CHECK_MSG(kappa_window_tiles >= 1 && kappa_window_tiles % 2 == 1 && kappa_window_tiles <= 63,
                "kappa_window_tiles must be odd in [1, 63], got " << kappa_window_tiles);
  D3D_CHECK_MSG(std::isfinite(max_phase_drift_rad) && max_phase_drift_rad >= 0.0 &&
                    max_phase_drift_rad <= 1.5,
                "max_phase_drift_rad must be in [0, 1.5], got " << max_phase_drift_rad);
  D3D_CHECK_MSG(std::isfinite(drift_exclusion) && drift_exclusion > 0.0,
                "drift_exclusion must be > 0, got " << drift_exclusion);
  D3D_CHECK_MSG(table_bins >= 64 && table_bins <= 65536,
                "table_bins must be in [64, 65536], got " << table_bins);
  D3D_CHECK_MSG(table_rows >= 2 && table_rows <= 4096,
                "table_rows must be in [2, 4096], got " << table_rows);
  D3D_CHECK_MSG(threads >= 1, "threads must be >= 1, got " << threads);
}

std::vector<int> MarkerOrders(const FringePatternSpec& spec, double projector_extent_px) {
  std::vector<int> orders;
  if (!spec.HasMarker()) return orders;
  const double last_order =
      std::floor((projector_extent_px - spec.phase_origin_px) / spec.fringe_period_px);
  for (int k = spec.marker_first_order; k <= last_order; k += spec.marker_spacing_orders) {
    orders.push_back(k);
    if (spec.marker_spacing_orders == 0) break;
  }
  return orders;
}

struct PhaseEstimator::Impl {
  FringePatternSpec spec;
  PhaseOptions options;
  double gamma = 1.0;
  bool marker = false;  // detect the marker
  std::shared_ptr<const PhaseModel> model;
  // Scratch (reused between calls). Pass 1's row buffers, one set per thread that runs its blocks
  // (ForRowBlocks): the frames' rows as float, the cos / sin sums and the running maximum.
  struct RowScratch {
    std::vector<std::vector<float>> frame_rows;
    std::vector<float> acc_c, acc_s, acc_max;
  };
  tbb::enumerable_thread_specific<RowScratch> row_scratch;
  cv::Mat residual, phi_sub, mod_sub, dc_sub, marker_raw, guard, near, invalid;
  std::vector<double> num, den, cnt;
  cv::Mat kappa_tiles;
  // Motion compensation (phase.h): per phase bin, the first-order effect of a unit drift
  // (0: ε of Φ, 1: b/B of the amplitude, 2: a/B of the offset, per frame interval) on the
  // residual e per unit B (drift_g), on the N-step phase (drift_h) and on the N−1-frame phase
  // (drift_hs, with a marker). Empty when the residual cannot see the drift.
  std::vector<float> drift_g[3], drift_h[3], drift_hs[3];
  std::vector<double> drift_sums[10];  // tile sums of the 3×3 normal equations, right side, count
  cv::Mat drift_tiles[3], drift_maps[3];

  void BuildDriftTables();
  void EstimateDrift(const PhaseMaps& out, int H, int W);

  Status Validate(const std::vector<cv::Mat>& frames, PhaseMaps* out) const;
  void EstimateKappa(const PhaseMaps& out, int H, int W, cv::Mat* kappa);
  void TileSums(const PhaseMaps& out, const cv::Mat* exclude_with, int H, int W);
  cv::Mat SolveTiles(int TH, int TW, int window, const cv::Mat* fallback,
                     double fallback_value) const;

  // Compute's per-call values, shared by its passes (below, in Compute's order).
  struct Call {
    int H = 0, W = 0;
    bool wide = false;                           // CV_16U frames
    bool need_kappa = false;                     // κ is estimated (pass 2)
    bool drift = false;                          // in-burst motion is compensated (pass 2b)
    float bins_per_rad = 0, rows_per_kappa = 0;  // table indexing
    int bins = 0, rows = 0;
    const FullEntry* lut_full = nullptr;  // the tables' row at κ = 1 (kLutGamma)
    const SubEntry* lut_sub = nullptr;    // with a marker
  };
  void CreateMaps(const Call& c, PhaseMaps* out);
  void LinearSums(const std::vector<cv::Mat>& frames, const Call& c, PhaseMaps* out);
  void Kappa(const Call& c, PhaseMaps* out);
  void Drift(const Call& c, PhaseMaps* out);
  void Compensate(const Call& c, PhaseMaps* out);
  void MarkerScores(const Call& c, PhaseMaps* out);
  void MarkerMasks(PhaseMaps* out);
  void UnmarkedPhaseInStripes(const Call& c, PhaseMaps* out);
  void Finish(const Call& c, PhaseMaps* out);
};

PhaseEstimator::PhaseEstimator(const FringePatternSpec& spec, double projector_gamma,
                               const PhaseOptions& options)
    : impl_(std::make_unique<Impl>()) {
  spec.Check();
  options.Check();
  D3D_CHECK_MSG(projector_gamma > 0.1 && projector_gamma < 10.0,
                "projector gamma " << projector_gamma << " is implausible");
  D3D_CHECK_MSG(!(spec.HasMarker() && options.detect_marker) || spec.steps >= 4,
                "marker detection needs N ≥ 4 phase steps, the spec has "
                    << spec.steps << " (set detect_marker = false or marker_frame = -1)");
  impl_->spec = spec;
  impl_->options = options;
  impl_->gamma = projector_gamma;
  impl_->marker = spec.HasMarker() && options.detect_marker;
  impl_->model =
      CachedModel(spec, projector_gamma, impl_->marker, options.table_bins, options.table_rows);
  if (options.motion_compensation && impl_->model->has_residual() && spec.steps >= 4)
    impl_->BuildDriftTables();
}

// First-order drift tables (phase.h, "In-burst motion"), per κ row (kDriftRows over [0, kKappaMax])
// and phase bin: frame n is s_n = n − (N−1)/2 frame intervals from the reference time, with the
// model's waveform w_n(Φ; κ) per unit B (harmonics included: their drift aliases into the N-step
// phase as much as the fundamental's). A unit drift perturbs the frames by s_n·∂w_n/∂Φ (ε), s_n·w_n
// (b/B) or s_n (a/B); the tables hold the resulting change of the residual left by the κ model,
// r = e − B_c·E(φ; κ) (drift_g), and of the
// estimators' final phases (drift_h: N-step + table correction; drift_hs: N−1-frame fit + its
// table), by central differences through the same weights and tables as Compute().
void PhaseEstimator::Impl::BuildDriftTables() {
  const PhaseModel& m = *model;
  const int N = m.steps(), bins = m.bins();
  const float bins_per_rad = static_cast<float>(bins / (2.0 * M_PI));
  const size_t size = static_cast<size_t>(kDriftRows) * bins;
  for (int k = 0; k < 3; ++k) {
    drift_g[k].assign(size, 0.0f);
    drift_h[k].assign(size, 0.0f);
    if (marker) drift_hs[k].assign(size, 0.0f);
  }
  struct Estimate {
    double phi, e, phi_sub;
  };
  std::vector<double> I(static_cast<size_t>(N));
  auto estimate = [&](int model_row) {
    double C = 0, S = 0, e = 0, Cs = 0, Ss = 0;
    for (int n = 0; n < N; ++n) {
      C += m.cos_w()[n] * I[n];
      S += m.sin_w()[n] * I[n];
      e += m.res_w()[n] * I[n];
      if (marker) Cs += m.sub_cos_w()[n] * I[n], Ss += m.sub_sin_w()[n] * I[n];
    }
    const float p = WrapPos(static_cast<float>(std::atan2(S, C)));
    const FullEntry f = ReadFullRow(m.full_row(model_row), PhaseBin(p, bins_per_rad, bins));
    // The residual as EstimateDrift sees it: e minus the κ model read at the measured phase (which
    // the drift moves too).
    Estimate r{p + f.corr, e - std::sqrt(C * C + S * S) * f.ginv * f.e, 0.0};
    if (marker) {
      const float q = WrapPos(static_cast<float>(std::atan2(Ss, Cs)));
      r.phi_sub = q + ReadSubRow(m.sub_row(model_row), PhaseBin(q, bins_per_rad, bins)).corr;
    }
    return r;
  };
  double g_rms = 0;
  constexpr double h = 1e-3;
  for (int j = 0; j < kDriftRows; ++j) {
    const double kappa = phase_internal::kKappaMax * j / (kDriftRows - 1);
    const int model_row = m.RowOf(kappa);
    for (int i = 0; i < bins; ++i) {
      const double Phi = 2.0 * M_PI * (i + 0.5) / bins;
      for (int k = 0; k < 3; ++k) {
        Estimate pm[2];
        for (int side = 0; side < 2; ++side) {
          const double x = side == 0 ? -h : h;
          for (int n = 0; n < N; ++n) {
            const double s_n = n - (N - 1) / 2.0;
            I[n] = k == 0   ? m.Waveform(n, Phi + s_n * x, kappa)
                   : k == 1 ? (1.0 + s_n * x) * m.Waveform(n, Phi, kappa)
                            : m.Waveform(n, Phi, kappa) + s_n * x;
          }
          pm[side] = estimate(model_row);
        }
        const size_t at = static_cast<size_t>(j) * bins + i;
        drift_g[k][at] = static_cast<float>((pm[1].e - pm[0].e) / (2 * h));
        drift_h[k][at] =
            static_cast<float>(std::remainder(pm[1].phi - pm[0].phi, 2 * M_PI) / (2 * h));
        if (marker)
          drift_hs[k][at] =
              static_cast<float>(std::remainder(pm[1].phi_sub - pm[0].phi_sub, 2 * M_PI) / (2 * h));
        if (k == 0 && j == kDriftRows - 1) g_rms += drift_g[0][at] * drift_g[0][at];
      }
    }
  }
  // A residual blind to ε (e.g. some N > 4 channels) cannot measure the drift: no compensation.
  if (std::sqrt(g_rms / bins) < 1e-3)
    for (int k = 0; k < 3; ++k) drift_g[k].clear(), drift_h[k].clear(), drift_hs[k].clear();
}

// Least-squares fit of r = e − B_c·E(φ_c; κ) ≈ B_c·Σ_k x_k·g_k(φ_c) per window of tiles (the κ
// tiles and window), over every kKappaStride-th valid pixel with |r| ≤ drift_exclusion·B_c (wider
// than the κ fit's exclusion: the drift's own residual reaches 2√2·ε·B),
// with a small ridge; tiles without support get x = 0. Leaves per-pixel maps in drift_maps.
void PhaseEstimator::Impl::EstimateDrift(const PhaseMaps& out, int H, int W) {
  const PhaseModel& m = *model;
  const int t = options.kappa_tile_px;
  const int TW = (W + t - 1) / t, TH = (H + t - 1) / t;
  for (auto& v : drift_sums) v.assign(static_cast<size_t>(TW) * TH, 0.0);
  const float bins_per_rad = static_cast<float>(m.bins() / (2.0 * M_PI));
  const float rows_per_kappa = static_cast<float>(1.0 / m.KappaStep());
  const float min_mod = static_cast<float>(options.min_modulation_dn);
  const float excl = static_cast<float>(options.drift_exclusion);
  const int bins = m.bins();
  for (int y = kKappaStride / 2; y < H; y += kKappaStride) {
    const float* phi = out.phi.ptr<float>(y);
    const float* mod = out.modulation.ptr<float>(y);
    const float* e = residual.ptr<float>(y);
    const float* kap = out.kappa.empty() ? nullptr : out.kappa.ptr<float>(y);
    const uint8_t* sat = out.saturated.ptr<uint8_t>(y);
    const size_t row0 = static_cast<size_t>(y / t) * TW;
    for (int x = kKappaStride / 2; x < W; x += kKappaStride) {
      if (sat[x] || !(mod[x] >= min_mod)) continue;
      const int row = KappaRow(kap ? kap[x] : static_cast<float>(options.kappa_prior),
                               rows_per_kappa, m.rows());
      const FullEntry f = ReadFullRow(m.full_row(row), PhaseBin(phi[x], bins_per_rad, bins));
      const float Bc = mod[x] * f.ginv;
      const float r = e[x] - Bc * f.e;
      if (std::abs(r) > excl * Bc) continue;
      const size_t i =
          static_cast<size_t>(DriftRow(kap ? kap[x] : static_cast<float>(options.kappa_prior))) *
              bins +
          PhaseBin(WrapPos(phi[x] + f.corr), bins_per_rad, bins).i;
      const double g[3] = {Bc * drift_g[0][i], Bc * drift_g[1][i], Bc * drift_g[2][i]};
      const size_t ti = row0 + static_cast<size_t>(x / t);
      int q = 0;
      for (int a = 0; a < 3; ++a)
        for (int b = a; b < 3; ++b) drift_sums[q++][ti] += g[a] * g[b];
      for (int a = 0; a < 3; ++a) drift_sums[6 + a][ti] += g[a] * r;
      drift_sums[9][ti] += 1.0;
    }
  }
  const int window = options.kappa_window_tiles;
  cv::Mat sums[10];
  for (int q = 0; q < 10; ++q)
    cv::boxFilter(cv::Mat(TH, TW, CV_64F, drift_sums[q].data()), sums[q], CV_64F,
                  cv::Size(window, window), cv::Point(-1, -1), false, cv::BORDER_CONSTANT);
  const double min_count =
      std::max(8.0, window * window * t * t / (kKappaStride * kKappaStride) / 8.0);
  const double max_eps = options.max_phase_drift_rad;
  for (auto& d : drift_tiles) d.create(TH, TW, CV_32F);
  for (int ty = 0; ty < TH; ++ty)
    for (int tx = 0; tx < TW; ++tx) {
      double v[10];
      for (int q = 0; q < 10; ++q) v[q] = sums[q].at<double>(ty, tx);
      Eigen::Vector3d x = Eigen::Vector3d::Zero();
      if (v[9] >= min_count) {
        Eigen::Matrix3d A;
        A << v[0], v[1], v[2], v[1], v[3], v[4], v[2], v[4], v[5];
        A.diagonal() += Eigen::Vector3d::Constant(1e-3 * A.trace() / 3.0 + 1e-12);
        x = A.ldlt().solve(Eigen::Vector3d(v[6], v[7], v[8]));
        if (!x.allFinite()) x.setZero();
        x = x.cwiseMax(-max_eps).cwiseMin(max_eps);
      }
      for (int k = 0; k < 3; ++k) drift_tiles[k].at<float>(ty, tx) = static_cast<float>(x[k]);
    }
  for (int k = 0; k < 3; ++k)
    cv::resize(drift_tiles[k], drift_maps[k], cv::Size(W, H), 0, 0, cv::INTER_LINEAR);
}

PhaseEstimator::~PhaseEstimator() = default;
PhaseEstimator::PhaseEstimator(PhaseEstimator&&) noexcept = default;
PhaseEstimator& PhaseEstimator::operator=(PhaseEstimator&&) noexcept = default;

const FringePatternSpec& PhaseEstimator::spec() const { return impl_->spec; }
const PhaseOptions& PhaseEstimator::options() const { return impl_->options; }
double PhaseEstimator::projector_gamma() const { return impl_->gamma; }
const std::vector<double>& PhaseEstimator::harmonic_ratios() const {
  return impl_->model->harmonic_ratios();
}

Status PhaseEstimator::Impl::Validate(const std::vector<cv::Mat>& frames, PhaseMaps* out) const {
  if (out == nullptr) return InvalidArgument("phase: no output PhaseMaps given");
  if (frames.empty()) return InvalidArgument("phase: no frames given");
  if (static_cast<int>(frames.size()) != spec.steps)
    return InvalidArgument("phase: got " + std::to_string(frames.size()) +
                           " frames, the pattern '" + spec.name + "' has " +
                           std::to_string(spec.steps) + " steps");
  for (size_t n = 0; n < frames.size(); ++n) {
    const cv::Mat& f = frames[n];
    if (f.empty()) return InvalidArgument("phase: frame " + std::to_string(n) + " is empty");
    if (f.type() != CV_8UC1 && f.type() != CV_16UC1)
      return InvalidArgument("phase: frame " + std::to_string(n) + " has type " +
                             cv::typeToString(f.type()) + ", expected CV_8UC1 or CV_16UC1");
    if (f.size() != frames[0].size())
      return InvalidArgument("phase: frame " + std::to_string(n) + " is " + std::to_string(f.cols) +
                             "x" + std::to_string(f.rows) + ", frame 0 is " +
                             std::to_string(frames[0].cols) + "x" + std::to_string(frames[0].rows));
    if (f.type() != frames[0].type())
      return InvalidArgument("phase: frame " + std::to_string(n) + " has type " +
                             cv::typeToString(f.type()) + ", frame 0 has " +
                             cv::typeToString(frames[0].type()));
  }
  return Status::Ok();
}

// Tile sums of the κ fit e ≈ κ·b, b = B'·E_1(φ') (B', φ' the raw N-step estimates), over valid
// pixels (every kKappaStride-th), leaving out pixels with |e − κ_tile·b| > kappa_exclusion·B' when
// `exclude_with` (tile κ) is given.
void PhaseEstimator::Impl::TileSums(const PhaseMaps& out, const cv::Mat* exclude_with, int H,
                                    int W) {
  const int t = options.kappa_tile_px;
  const int TW = (W + t - 1) / t, TH = (H + t - 1) / t;
  num.assign(static_cast<size_t>(TW) * TH, 0.0);
  den.assign(num.size(), 0.0);
  cnt.assign(num.size(), 0.0);
  const PhaseModel& m = *model;
  const float bins_per_rad = static_cast<float>(m.bins() / (2.0 * M_PI));
  const float rows_per_kappa = static_cast<float>(1.0 / m.KappaStep());
  const int prior_row = KappaRow(static_cast<float>(options.kappa_prior), rows_per_kappa, m.rows());
  const float min_mod = static_cast<float>(options.min_modulation_dn);
  const float excl = static_cast<float>(options.kappa_exclusion);
  for (int y = kKappaStride / 2; y < H; y += kKappaStride) {
    const float* phi = out.phi.ptr<float>(y);
    const float* mod = out.modulation.ptr<float>(y);
    const float* e = residual.ptr<float>(y);
    const uint8_t* sat = out.saturated.ptr<uint8_t>(y);
    const float* kt = exclude_with ? exclude_with->ptr<float>(y / t) : nullptr;
    double* tn = &num[static_cast<size_t>(y / t) * TW];
    double* td = &den[static_cast<size_t>(y / t) * TW];
    double* tc = &cnt[static_cast<size_t>(y / t) * TW];
    for (int x = kKappaStride / 2; x < W; x += kKappaStride) {
      if (sat[x] || !(mod[x] >= min_mod)) continue;
      // Φ and B through the current κ (the N-step distortion depends on it), basis E(Φ; 1).
      const FullEntry f =
          ReadFullRow(m.full_row(kt ? KappaRow(kt[x / t], rows_per_kappa, m.rows()) : prior_row),
                      PhaseBin(phi[x], bins_per_rad, m.bins()));
      const float b = mod[x] * f.ginv * f.e1;
      if (kt && std::abs(e[x] - mod[x] * f.ginv * f.e) > excl * mod[x] * f.ginv) continue;
      tn[x / t] += static_cast<double>(e[x]) * b;
      td[x / t] += static_cast<double>(b) * b;
      tc[x / t] += 1.0;
    }
  }
}

// κ per tile from the sums over a window of tiles; tiles without enough support get the fallback
// tile map's value (or fallback_value).
cv::Mat PhaseEstimator::Impl::SolveTiles(int TH, int TW, int window, const cv::Mat* fallback,
                                         double fallback_value) const {
  const int half = window / 2;  // window = 2·half + 1
  const int t = options.kappa_tile_px;
  const double min_count = std::max(
      8.0, (2.0 * half + 1) * (2.0 * half + 1) * t * t / (kKappaStride * kKappaStride) / 8.0);
  // Window sums by separable box filters over the tile grids (zero outside).
  cv::Mat sums[3];
  const std::vector<double>* grids[3] = {&num, &den, &cnt};
  for (int g = 0; g < 3; ++g)
    cv::boxFilter(cv::Mat(TH, TW, CV_64F, const_cast<double*>(grids[g]->data())), sums[g], CV_64F,
                  cv::Size(window, window), cv::Point(-1, -1), false, cv::BORDER_CONSTANT);
  cv::Mat k(TH, TW, CV_32F);
  for (int ty = 0; ty < TH; ++ty)
    for (int tx = 0; tx < TW; ++tx) {
      const double n = sums[0].at<double>(ty, tx), d = sums[1].at<double>(ty, tx),
                   c = sums[2].at<double>(ty, tx);
      // Only fitted values are clamped: EstimateKappa's first pass marks tiles without support by
      // fallback_value −1, and its median must not count them (clamped, they read as κ = 0, and
      // an image more than half dark then seeded the robust fit with κ = 0).
      const double kappa = c >= min_count && d > 0.0
                               ? std::clamp(n / d, 0.0, phase_internal::kKappaMax)
                           : fallback ? fallback->at<float>(ty, tx)
                                      : fallback_value;
      k.at<float>(ty, tx) = static_cast<float>(kappa);
    }
  return k;
}

void PhaseEstimator::Impl::EstimateKappa(const PhaseMaps& out, int H, int W, cv::Mat* kappa) {
  constexpr int kWideWindow = 11;
  const int t = options.kappa_tile_px;
  const int TW = (W + t - 1) / t, TH = (H + t - 1) / t;
  const int local = options.kappa_window_tiles;
  TileSums(out, nullptr, H, W);
  const cv::Mat first = SolveTiles(TH, TW, local, nullptr, -1.0);
  std::vector<float> supported;
  for (int i = 0; i < first.rows * first.cols; ++i)
    if (first.ptr<float>()[i] >= 0.0f && first.ptr<float>()[i] < phase_internal::kKappaMax)
      supported.push_back(first.ptr<float>()[i]);
  double kappa0 = options.kappa_prior;
  if (!supported.empty()) {
    std::nth_element(supported.begin(), supported.begin() + supported.size() / 2, supported.end());
    kappa0 = supported[supported.size() / 2];
  }
  const cv::Mat flat(TH, TW, CV_32F, cv::Scalar(kappa0));
  TileSums(out, &flat, H, W);
  const cv::Mat wide = SolveTiles(TH, TW, kWideWindow, &flat, kappa0);
  TileSums(out, &wide, H, W);
  kappa_tiles = SolveTiles(TH, TW, local, &wide, kappa0);
  // Tile centres → pixels (bilinear); exact when W, H are multiples of the tile size.
  cv::resize(kappa_tiles, *kappa, cv::Size(W, H), 0, 0, cv::INTER_LINEAR);
}

Status PhaseEstimator::Compute(const std::vector<cv::Mat>& frames, PhaseMaps* out) {
  Impl& I = *impl_;
  D3D_RETURN_IF_ERROR(I.Validate(frames, out));
  const PhaseModel& m = *I.model;
  Impl::Call c;
  c.H = frames[0].rows;
  c.W = frames[0].cols;
  c.wide = frames[0].depth() == CV_16U;
  const PhaseAlgorithm alg = I.options.algorithm;
  c.need_kappa = m.has_residual() && m.residual_informative() &&
                 (alg == PhaseAlgorithm::kAdaptiveHarmonic || I.marker);
  c.drift = alg == PhaseAlgorithm::kAdaptiveHarmonic && !I.drift_g[0].empty();
  c.bins_per_rad = static_cast<float>(m.bins() / (2.0 * M_PI));
  c.rows_per_kappa = static_cast<float>(1.0 / m.KappaStep());
  c.bins = m.bins();
  c.rows = m.rows();
  c.lut_full = m.full_row(m.RowOf(1.0));
  c.lut_sub = I.marker ? m.sub_row(m.RowOf(1.0)) : nullptr;

  I.CreateMaps(c, out);
  I.LinearSums(frames, c, out);                                // pass 1
  I.Kappa(c, out);                                             // pass 2
  I.Drift(c, out);                                             // pass 2b
  if (alg != PhaseAlgorithm::kStandard) I.Compensate(c, out);  // pass 3
  if (I.marker) {                                              // pass 4
    I.MarkerScores(c, out);
    I.MarkerMasks(out);
    I.UnmarkedPhaseInStripes(c, out);
  } else {
    out->marker_score.release();
  }
  I.Finish(c, out);  // pass 5
  return Status::Ok();
}

void PhaseEstimator::Impl::CreateMaps(const Call& c, PhaseMaps* out) {
  const PhaseModel& m = *model;
  const int H = c.H, W = c.W;
  out->phi.create(H, W, CV_32F);
  out->modulation.create(H, W, CV_32F);
  out->offset.create(H, W, CV_32F);
  out->texture.create(H, W, c.wide ? CV_16U : CV_8U);
  out->valid.create(H, W, CV_8U);
  out->saturated.create(H, W, CV_8U);
  out->marker.create(H, W, CV_8U);
  out->marker.setTo(0);
  if (c.need_kappa || m.has_residual()) residual.create(H, W, CV_32F);
  if (marker) {
    phi_sub.create(H, W, CV_32F);
    mod_sub.create(H, W, CV_32F);
    dc_sub.create(H, W, CV_32F);
  }
}

// Pass 1: linear sums per pixel (vectorised row loops): raw N-step φ', B', mean, saturation,
// residual e, and the N−1-frame fit.
void PhaseEstimator::Impl::LinearSums(const std::vector<cv::Mat>& frames, const Call& c,
                                      PhaseMaps* out) {
  const PhaseModel& m = *model;
  const int N = spec.steps, H = c.H, W = c.W;
  const bool wide = c.wide;
  const float sat_dn = static_cast<float>(options.saturation_dn > 0 ? options.saturation_dn
                                                                    : (wide ? 65535.0 : 255.0));
  const std::vector<float> ones(N, 1.0f / N);
  const int threads = options.threads;
  ForRowBlocks(H, threads, [&](int y0, int y1) {
    RowScratch& rs = row_scratch.local();  // this thread's; sized once
    rs.frame_rows.resize(N);
    for (auto& r : rs.frame_rows) r.resize(W);
    rs.acc_c.resize(W);
    rs.acc_s.resize(W);
    rs.acc_max.resize(W);
    for (int y = y0; y < y1; ++y) {
      for (int n = 0; n < N; ++n) {
        if (wide)
          ToFloat(frames[n].ptr<uint16_t>(y), rs.frame_rows[n].data(), W);
        else
          ToFloat(frames[n].ptr<uint8_t>(y), rs.frame_rows[n].data(), W);
      }
      float* C = rs.acc_c.data();
      float* S = rs.acc_s.data();
      float* mean = out->offset.ptr<float>(y);
      float* mx = rs.acc_max.data();
      Accumulate(m.cos_w().data(), rs.frame_rows, W, C);
      Accumulate(m.sin_w().data(), rs.frame_rows, W, S);
      Accumulate(ones.data(), rs.frame_rows, W, mean);
      std::copy(rs.frame_rows[0].begin(), rs.frame_rows[0].end(), mx);
      for (int n = 1; n < N; ++n) {
        const float* f = rs.frame_rows[n].data();
        for (int x = 0; x < W; ++x) mx[x] = f[x] > mx[x] ? f[x] : mx[x];
      }
      float* phi = out->phi.ptr<float>(y);
      float* mod = out->modulation.ptr<float>(y);
      uint8_t* sat = out->saturated.ptr<uint8_t>(y);
      for (int x = 0; x < W; ++x) {
        phi[x] = FastAtan2Pos(S[x], C[x]);
        mod[x] = std::sqrt(C[x] * C[x] + S[x] * S[x]);
      }
      for (int x = 0; x < W; ++x) sat[x] = static_cast<uint8_t>(-static_cast<int>(mx[x] >= sat_dn));
      if (!residual.empty()) Accumulate(m.res_w().data(), rs.frame_rows, W, residual.ptr<float>(y));
      if (marker) {
        Accumulate(m.sub_cos_w().data(), rs.frame_rows, W, C);
        Accumulate(m.sub_sin_w().data(), rs.frame_rows, W, S);
        Accumulate(m.sub_dc_w().data(), rs.frame_rows, W, dc_sub.ptr<float>(y));
        float* p3 = phi_sub.ptr<float>(y);
        float* m3 = mod_sub.ptr<float>(y);
        for (int x = 0; x < W; ++x) {
          p3[x] = FastAtan2Pos(S[x], C[x]);
          m3[x] = std::sqrt(C[x] * C[x] + S[x] * S[x]);
        }
      }
    }
  });
}

// Pass 2: harmonic attenuation κ.
void PhaseEstimator::Impl::Kappa(const Call& c, PhaseMaps* out) {
  const int H = c.H, W = c.W;
  if (c.need_kappa) {
    EstimateKappa(*out, H, W, &out->kappa);
  } else if (options.algorithm == PhaseAlgorithm::kAdaptiveHarmonic) {
    out->kappa.create(H, W, CV_32F);
    out->kappa.setTo(static_cast<float>(options.kappa_prior));
  } else {
    out->kappa.release();
  }
}

// Pass 2b: in-burst motion (ours only; the textbook and LUT baselines stay as published).
void PhaseEstimator::Impl::Drift(const Call& c, PhaseMaps* out) {
  if (c.drift) {
    EstimateDrift(*out, c.H, c.W);
    drift_maps[0].copyTo(out->phase_drift);
  } else {
    out->phase_drift.release();
  }
}

// Pass 3: compensated N-step phase and modulation; with drift, also the N−1-frame phase and the
// residual (what the marker detector sees) lose their motion terms.
void PhaseEstimator::Impl::Compensate(const Call& c, PhaseMaps* out) {
  const PhaseModel& m = *model;
  const int H = c.H, W = c.W;
  const PhaseAlgorithm alg = options.algorithm;
  const bool drift = c.drift;
  const float bins_per_rad = c.bins_per_rad, rows_per_kappa = c.rows_per_kappa;
  const int bins = c.bins, rows = c.rows;
  const FullEntry* lut_full = c.lut_full;
  const int threads = options.threads;
  ForRowBlocks(H, threads, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      float* phi = out->phi.ptr<float>(y);
      float* mod = out->modulation.ptr<float>(y);
      const float* kap =
          alg == PhaseAlgorithm::kAdaptiveHarmonic ? out->kappa.ptr<float>(y) : nullptr;
      for (int x = 0; x < W; ++x) {
        const BinPos b = PhaseBin(phi[x], bins_per_rad, bins);
        const FullEntry e =
            ReadFullRow(kap ? m.full_row(KappaRow(kap[x], rows_per_kappa, rows)) : lut_full, b);
        phi[x] = WrapPos(phi[x] + e.corr);
        mod[x] *= e.ginv;
      }
      if (!drift) continue;
      const float* d0 = drift_maps[0].ptr<float>(y);
      const float* d1 = drift_maps[1].ptr<float>(y);
      const float* d2 = drift_maps[2].ptr<float>(y);
      float* res = residual.ptr<float>(y);
      float* p3 = marker ? phi_sub.ptr<float>(y) : nullptr;
      for (int x = 0; x < W; ++x) {
        const size_t row0 = static_cast<size_t>(DriftRow(kap[x])) * bins;
        const size_t i = row0 + PhaseBin(phi[x], bins_per_rad, bins).i;
        res[x] -= mod[x] * (d0[x] * drift_g[0][i] + d1[x] * drift_g[1][i] + d2[x] * drift_g[2][i]);
        phi[x] = WrapPos(phi[x] -
                         (d0[x] * drift_h[0][i] + d1[x] * drift_h[1][i] + d2[x] * drift_h[2][i]));
        if (p3) {
          const size_t j = row0 + PhaseBin(p3[x], bins_per_rad, bins).i;
          p3[x] = WrapPos(
              p3[x] - (d0[x] * drift_hs[0][j] + d1[x] * drift_hs[1][j] + d2[x] * drift_hs[2][j]));
        }
      }
    }
  });
}

// Pass 4a: marker detection against the adaptive model (whatever the phase algorithm): the
// matched-filter amplitude α per pixel (out->marker_score), and in marker_raw the pixels whose
// N frames contradict the non-marker model.
void PhaseEstimator::Impl::MarkerScores(const Call& c, PhaseMaps* out) {
  const PhaseModel& m = *model;
  const int H = c.H, W = c.W;
  const bool need_kappa = c.need_kappa;
  const float min_mod = static_cast<float>(options.min_modulation_dn);
  const float bins_per_rad = c.bins_per_rad, rows_per_kappa = c.rows_per_kappa;
  const int bins = c.bins, rows = c.rows;
  const int threads = options.threads;
  out->marker_score.create(H, W, CV_32F);
  marker_raw.create(H, W, CV_8U);
  ForRowBlocks(H, threads, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      const float* p3 = phi_sub.ptr<float>(y);
      const float* m3 = mod_sub.ptr<float>(y);
      const float* e = residual.ptr<float>(y);
      const float* kap = need_kappa ? out->kappa.ptr<float>(y) : nullptr;
      const uint8_t* sat = out->saturated.ptr<uint8_t>(y);
      float* score = out->marker_score.ptr<float>(y);
      uint8_t* raw = marker_raw.ptr<uint8_t>(y);
      const float kappa_const = static_cast<float>(options.kappa_prior);
      for (int x = 0; x < W; ++x) {
        const SubEntry s =
            ReadSubRow(m.sub_row(KappaRow(kap ? kap[x] : kappa_const, rows_per_kappa, rows)),
                       PhaseBin(p3[x], bins_per_rad, bins));
        const float B = m3[x] * s.ginv;
        float alpha = 0.0f;
        bool suspect = false;
        if (!sat[x] && B >= min_mod) {
          const float r = (e[x] - B * s.e) / B;
          alpha = r * s.d / (s.d * s.d + kMarkerEps);
          suspect = std::abs(r) > kSuspect;
        }
        score[x] = alpha;
        raw[x] = suspect ? 255 : 0;
      }
    }
  });
}

// Pass 4b: the marker stripes (out->marker) and the pixels that take the N−1-frame phase (guard).
void PhaseEstimator::Impl::MarkerMasks(PhaseMaps* out) {
  const float thr = static_cast<float>(options.marker_threshold);
  // α averaged over a box (noise of low-modulation pixels, the blurred jump in a stripe's middle),
  // thresholded, then a closing and an opening.
  const int box = options.marker_box_px, close = options.marker_close_px;
  const int reach = options.marker_suspect_reach_px;
  cv::blur(out->marker_score, out->marker_score, cv::Size(box, box), cv::Point(-1, -1),
           cv::BORDER_REPLICATE);
  cv::compare(out->marker_score, thr, out->marker, cv::CMP_GT);
  const cv::Mat k3 = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(close, close));
  cv::morphologyEx(out->marker, out->marker, cv::MORPH_CLOSE, k3);
  cv::morphologyEx(out->marker, out->marker, cv::MORPH_OPEN, k3);
  // The N−1-frame phase is used in the stripes dilated by the guard (transition pixels) and
  // wherever the N frames contradict the non-marker model (|r| > kSuspect: a stripe's fringe
  // missed by the detector, a partly marked pixel, a glint's edge).
  // Only near detected stripes (marker_suspect_reach_px): elsewhere |r| > kSuspect is mostly noise
  // of low-modulation pixels, for which the N-step phase is the better one.
  const int g = options.marker_guard_px;
  if (g > 0)
    cv::dilate(out->marker, guard,
               cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * g + 1, 2 * g + 1)));
  else
    out->marker.copyTo(guard);
  cv::dilate(out->marker, near,
             cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * reach + 1, 2 * reach + 1)));
  cv::bitwise_and(marker_raw, near, marker_raw);
  cv::bitwise_or(guard, marker_raw, guard);
}

// Pass 4c: inside the guarded stripes, phase, modulation and offset from the N−1 unmarked frames.
void PhaseEstimator::Impl::UnmarkedPhaseInStripes(const Call& c, PhaseMaps* out) {
  const PhaseModel& m = *model;
  const int H = c.H, W = c.W;
  const PhaseAlgorithm alg = options.algorithm;
  const bool need_kappa = c.need_kappa;
  const float bins_per_rad = c.bins_per_rad, rows_per_kappa = c.rows_per_kappa;
  const int bins = c.bins, rows = c.rows;
  const SubEntry* lut_sub = c.lut_sub;
  const int threads = options.threads;
  ForRowBlocks(H, threads, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      const uint8_t* gd = guard.ptr<uint8_t>(y);
      const float* p3 = phi_sub.ptr<float>(y);
      const float* m3 = mod_sub.ptr<float>(y);
      const float* dc = dc_sub.ptr<float>(y);
      const float* kap = need_kappa ? out->kappa.ptr<float>(y) : nullptr;
      float* phi = out->phi.ptr<float>(y);
      float* mod = out->modulation.ptr<float>(y);
      float* off = out->offset.ptr<float>(y);
      for (int x = 0; x < W; ++x) {
        if (!gd[x]) continue;
        const BinPos b = PhaseBin(p3[x], bins_per_rad, bins);
        SubEntry s{0.0f, 1.0f, 0.0f, 0.0f, 0.0f};
        if (alg == PhaseAlgorithm::kLutGamma) {
          s = ReadSubRow(lut_sub, b);
        } else if (alg == PhaseAlgorithm::kAdaptiveHarmonic) {
          s = ReadSubRow(m.sub_row(KappaRow(kap ? kap[x] : static_cast<float>(options.kappa_prior),
                                            rows_per_kappa, rows)),
                         b);
        }
        phi[x] = WrapPos(p3[x] + s.corr);
        mod[x] = m3[x] * s.ginv;
        off[x] = dc[x] - mod[x] * s.off;
      }
    }
  });
}

// Pass 5: validity, NaN where invalid, texture, counts (OpenCV's vectorised array operations).
void PhaseEstimator::Impl::Finish(const Call& c, PhaseMaps* out) {
  const float min_mod = static_cast<float>(options.min_modulation_dn);
  cv::compare(out->modulation, min_mod, out->valid, cv::CMP_GE);
  cv::bitwise_and(out->valid, out->saturated == 0, out->valid);
  cv::bitwise_not(out->valid, invalid);
  out->phi.setTo(std::numeric_limits<float>::quiet_NaN(), invalid);
  out->marker.setTo(0, invalid);
  out->num_valid = cv::countNonZero(out->valid);
  out->num_saturated = cv::countNonZero(out->saturated);
  out->offset.convertTo(out->texture, c.wide ? CV_16U : CV_8U);
  out->num_marker = marker ? cv::countNonZero(out->marker) : 0;
}

Status ComputePhase(const std::vector<cv::Mat>& frames, const FringePatternSpec& spec,
                    double projector_gamma, const PhaseOptions& options, PhaseMaps* out) {
  PhaseEstimator estimator(spec, projector_gamma, options);
  return estimator.Compute(frames, out);
}

}  // namespace d3d
