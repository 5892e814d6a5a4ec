// Real-image validation of pipeline/phase and pipeline/unwrap (see real_fringe.h).
#include "pipeline/recon/real_fringe.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/structured_light.hpp>
#include <string>
#include <vector>

#include "calib/model/probe_calibration.h"
#include "common/core/status.h"
#include "pipeline/phase/phase.h"
#include "pipeline/recon/evaluate.h"
#include "pipeline/unwrap/quality_map.h"
#include "pipeline/unwrap/unwrap.h"

namespace d3d::real_fringe {

constexpr double kPi = 3.14159265358979323846;
constexpr double kTwoPi = 2.0 * kPi;
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

inline double WrapPi(double d) { return d - kTwoPi * std::floor(d / kTwoPi + 0.5); }

inline Status ReadGrey(const std::string& path, cv::Mat* out) {
  *out = cv::imread(path, cv::IMREAD_GRAYSCALE);
  if (out->empty()) return NotFound("cannot read " + path);
  return Status::Ok();
}

inline std::string Pat(const std::string& dir, int i) {
  char name[32];
  std::snprintf(name, sizeof(name), "/pat%02d.png", i);
  return dir + name;
}

// ---------------------------------------------------------------------------------------------
// kamino410/object2
// ---------------------------------------------------------------------------------------------
// Gray decoding with OpenCV's GrayCodePattern: cell (x, y) per camera pixel, −1 where undecoded.
inline Status DecodeGray(const KaminoOptions& o, cv::Mat* cell_x, cv::Mat* cell_y) {
  std::vector<cv::Mat> pats(18);
  for (int i = 0; i < 18; ++i) D3D_RETURN_IF_ERROR(ReadGrey(Pat(o.dir, 12 + i), &pats[i]));
  cv::Mat white, black;
  D3D_RETURN_IF_ERROR(ReadGrey(Pat(o.dir, 30), &white));
  D3D_RETURN_IF_ERROR(ReadGrey(Pat(o.dir, 31), &black));
  cv::Ptr<cv::structured_light::GrayCodePattern> gray =
      cv::structured_light::GrayCodePattern::create(20, 11);
  if (gray->getNumberOfPatternImages() != 18)
    return InvalidArgument("GrayCodePattern(20, 11): not 18 images");
  gray->setBlackThreshold(static_cast<size_t>(o.black_threshold));
  gray->setWhiteThreshold(static_cast<size_t>(o.white_threshold));
  cell_x->create(white.size(), CV_32S);
  cell_y->create(white.size(), CV_32S);
  cell_x->setTo(-1);
  cell_y->setTo(-1);
  for (int y = 0; y < white.rows; ++y) {
    const uint8_t* w = white.ptr<uint8_t>(y);
    const uint8_t* b = black.ptr<uint8_t>(y);
    int* cx = cell_x->ptr<int>(y);
    int* cy = cell_y->ptr<int>(y);
    for (int x = 0; x < white.cols; ++x) {
      // Shadow mask as in GrayCodePattern::decode (computeShadowMasks): |white − black| > black
      // thr.
      if (std::abs(static_cast<int>(w[x]) - static_cast<int>(b[x])) <= o.black_threshold) continue;
      cv::Point p;
      if (gray->getProjPixel(pats, x, y, p)) continue;  // true = error
      cx[x] = p.x;
      cy[x] = p.y;
    }
  }
  return Status::Ok();
}

inline double Median(std::vector<float>* v) {
  if (v->empty()) return std::numeric_limits<double>::quiet_NaN();
  auto mid = v->begin() + static_cast<std::ptrdiff_t>(v->size() / 2);
  std::nth_element(v->begin(), mid, v->end());
  return *mid;
}

// Circular distance on [0, 256) from value v to the interval [a, b] (b − a < 256).
inline double CircDistToInterval(double v, double a, double b) {
  double t = std::fmod(v - a, 256.0);
  if (t < 0) t += 256.0;
  if (t <= b - a) return 0.0;
  return std::min(t - (b - a), 256.0 - t);
}

// Wrapped phase of the 3-step set pat(first), pat(first + 1), pat(first + 2) (period_px along x).
// Frame n of our spec shows ½ + ½cos(Φ − 2πn/3); pat(first + phs − 1) shows ½ + ½cos(ωx + 2π(phs −
// 2)/3): n = 0 ↔ pat(first + 1), n = 1 (−2π/3) ↔ pat(first), n = 2 (−4π/3 ≡ +2π/3) ↔ pat(first +
// 2).
inline Status KaminoPhase(const KaminoOptions& o, int first, double period_px,
                          PhaseAlgorithm algorithm, PhaseMaps* pm) {
  cv::Mat I1, I2, I3;
  D3D_RETURN_IF_ERROR(ReadGrey(Pat(o.dir, first), &I1));
  D3D_RETURN_IF_ERROR(ReadGrey(Pat(o.dir, first + 1), &I2));
  D3D_RETURN_IF_ERROR(ReadGrey(Pat(o.dir, first + 2), &I3));
  FringePatternSpec spec;
  spec.name = "kamino410-3step";
  spec.axis = 'x';
  spec.steps = 3;
  spec.fringe_period_px = period_px;
  spec.phase_origin_px = 0.0;
  spec.marker_frame = -1;
  PhaseOptions popt;
  popt.algorithm = algorithm;
  popt.detect_marker = false;
  return ComputePhase({I2, I1, I3}, spec, o.gamma, popt, pm);
}

// Quality map and region-growing unwrap, each region anchored by the Gray-code bounds.
inline Status KaminoUnwrap(const KaminoOptions& o, const PhaseMaps& pm, double period_px,
                           const cv::Mat& cell_x, UnwrapResult* ur) {
  cv::Mat phase_min(cell_x.size(), CV_32F, cv::Scalar(kNaN)),
      phase_max(cell_x.size(), CV_32F, cv::Scalar(kNaN));
  const double k = kTwoPi / period_px;
  for (int y = 0; y < cell_x.rows; ++y) {
    const int* cx = cell_x.ptr<int>(y);
    float* lo = phase_min.ptr<float>(y);
    float* hi = phase_max.ptr<float>(y);
    for (int x = 0; x < cell_x.cols; ++x) {
      if (cx[x] < 0) continue;
      lo[x] = static_cast<float>(k * (o.cell_px * cx[x] - o.bound_margin_px));
      hi[x] = static_cast<float>(k * (o.cell_px * (cx[x] + 1) + o.bound_margin_px));
    }
  }
  QualityOptions qopt;
  qopt.modulation_edge_ratio = o.modulation_edge_ratio;
  cv::Mat quality;
  D3D_RETURN_IF_ERROR(ComputeQualityMap(pm.phi, pm.modulation, pm.valid, qopt, &quality));
  UnwrapOptions uopt;
  uopt.min_region_pixels = o.min_region_pixels;
  uopt.monotonic_x = o.monotonic_x;
  uopt.depth_fraction = o.depth_fraction;
  uopt.drop_outside_volume = false;  // keep pixels outside their cell: they are what we measure
  return UnwrapPhase(pm.phi, quality, cv::Mat(), phase_min, phase_max, uopt, ur);
}

// Median and RMS of |c_a − c_b| (projector columns from two unwrapped Φ maps of periods ta, tb).
inline void CompareColumns(const cv::Mat& Phi_a, double ta, const cv::Mat& Phi_b, double tb,
                           double* median, double* rms, int64_t* count,
                           double* signed_median = nullptr) {
  std::vector<float> d, sd;
  double sum2 = 0.0;
  for (int y = 0; y < Phi_a.rows; ++y) {
    const float* a = Phi_a.ptr<float>(y);
    const float* b = Phi_b.ptr<float>(y);
    for (int x = 0; x < Phi_a.cols; ++x) {
      if (!std::isfinite(a[x]) || !std::isfinite(b[x])) continue;
      const double e = a[x] * ta / kTwoPi - b[x] * tb / kTwoPi;
      d.push_back(static_cast<float>(std::abs(e)));
      sd.push_back(static_cast<float>(e));
      sum2 += e * e;
    }
  }
  *count = static_cast<int64_t>(d.size());
  *rms = d.empty() ? 0.0 : std::sqrt(sum2 / static_cast<double>(d.size()));
  *median = Median(&d);
  if (signed_median) *signed_median = Median(&sd);
}

Status RunKamino(const KaminoOptions& o, KaminoReport* rep) {
  const auto t0 = std::chrono::steady_clock::now();
  *rep = KaminoReport{};
  PhaseMaps pm;
  D3D_RETURN_IF_ERROR(KaminoPhase(o, 0, o.period_px, o.algorithm, &pm));
  const int W = pm.phi.cols, H = pm.phi.rows;
  rep->width = W;
  rep->height = H;
  rep->phase_valid = pm.num_valid;

  // Verify the frame order against the author's formula with the plain estimator (and show that the
  // naive order pat00, pat01, pat02 is wrong).
  {
    cv::Mat I1, I2, I3;
    D3D_RETURN_IF_ERROR(ReadGrey(Pat(o.dir, 0), &I1));
    D3D_RETURN_IF_ERROR(ReadGrey(Pat(o.dir, 1), &I2));
    D3D_RETURN_IF_ERROR(ReadGrey(Pat(o.dir, 2), &I3));
    FringePatternSpec spec;
    spec.steps = 3;
    spec.fringe_period_px = o.period_px;
    spec.marker_frame = -1;
    PhaseOptions sopt;
    sopt.algorithm = PhaseAlgorithm::kStandard;
    sopt.detect_marker = false;
    PhaseMaps ours, naive;
    D3D_RETURN_IF_ERROR(ComputePhase({I2, I1, I3}, spec, 1.0, sopt, &ours));
    D3D_RETURN_IF_ERROR(ComputePhase({I1, I2, I3}, spec, 1.0, sopt, &naive));
    double sum = 0.0, sum_naive = 0.0;
    int64_t n = 0, n_naive = 0;
    for (int y = 0; y < H; ++y) {
      const uint8_t* a = I1.ptr<uint8_t>(y);
      const uint8_t* b = I2.ptr<uint8_t>(y);
      const uint8_t* c = I3.ptr<uint8_t>(y);
      const float* phi = ours.phi.ptr<float>(y);
      const float* phin = naive.phi.ptr<float>(y);
      for (int x = 0; x < W; ++x) {
        const double ref = std::atan2(std::sqrt(3.0) * (a[x] - c[x]), 2.0 * b[x] - a[x] - c[x]);
        if (std::isfinite(phi[x])) {
          sum += std::abs(WrapPi(phi[x] - ref));
          ++n;
        }
        if (std::isfinite(phin[x])) {
          sum_naive += std::abs(WrapPi(phin[x] - ref));
          ++n_naive;
        }
      }
    }
    rep->order_check_rad = n ? sum / static_cast<double>(n) : 0.0;
    rep->order_check_swapped_rad = n_naive ? sum_naive / static_cast<double>(n_naive) : 0.0;
  }

  cv::Mat cell_x, cell_y;
  D3D_RETURN_IF_ERROR(DecodeGray(o, &cell_x, &cell_y));
  int64_t steps = 0, up = 0;
  for (int y = 0; y < H; ++y) {
    const int* cx = cell_x.ptr<int>(y);
    for (int x = 0; x < W; ++x) {
      if (cx[x] < 0) continue;
      ++rep->gray_valid;
      if (x + 1 < W && cx[x + 1] >= 0 && cx[x + 1] != cx[x]) {
        ++steps;
        up += cx[x + 1] > cx[x];
      }
    }
  }
  rep->monotonic_corr = steps ? static_cast<double>(up) / static_cast<double>(steps) : 0.0;

  UnwrapResult ur;
  D3D_RETURN_IF_ERROR(KaminoUnwrap(o, pm, o.period_px, cell_x, &ur));
  rep->stats = ur.stats;
  for (const RegionInfo& r : ur.regions) {
    rep->regions_anchored += r.anchor == RegionAnchor::kDepth || r.anchor == RegionAnchor::kMarker;
  }
  rep->Phi = ur.Phi;
  if (std::getenv("D3D_REAL_FRINGE_DEBUG")) {
    for (const RegionInfo& r : ur.regions) {
      if (r.pixels < o.min_region_pixels) continue;
      std::fprintf(stderr, "  region %d px: %s K=%d bounded %d admitting %d cand %d viol %d\n",
                   r.pixels, RegionAnchorName(r.anchor), r.offset, r.bounded_pixels,
                   r.admitting_pixels, r.candidates, r.violations);
    }
  }

  // Independent check of the phase (and of the gamma compensation): the 100-px set pat03–05 has its
  // harmonic error at another spatial period, so |c(66.67) − c(100)| measures the phase error.
  if (o.cross_check) {
    PhaseMaps pm100;
    UnwrapResult ur100;
    D3D_RETURN_IF_ERROR(KaminoPhase(o, 3, o.cell_px, o.algorithm, &pm100));
    D3D_RETURN_IF_ERROR(KaminoUnwrap(o, pm100, o.cell_px, cell_x, &ur100));
    CompareColumns(ur.Phi, o.period_px, ur100.Phi, o.cell_px, &rep->cross_median_px,
                   &rep->cross_rms_px, &rep->cross_count, &rep->cross_signed_median_px);
  }

  cv::Mat viz = cv::imread(o.dir + "/vizualized.png", cv::IMREAD_COLOR);
  if (viz.empty() || viz.size() != pm.phi.size())
    return InvalidArgument("cannot read vizualized.png of " + o.dir);

  rep->disagreement.create(H, W, CV_8UC3);
  rep->viz_diff.create(H, W, CV_8UC3);
  const cv::Vec3b green(0, 200, 0), red(0, 0, 255), grey(128, 128, 128), blackc(0, 0, 0);
  std::vector<float> outside, cviz, cviz_signed;
  int64_t within2 = 0;
  const double tol = o.agree_tol_px;
  for (int y = 0; y < H; ++y) {
    const int* cx = cell_x.ptr<int>(y);
    const int* cy = cell_y.ptr<int>(y);
    const float* Phi = ur.Phi.ptr<float>(y);
    const cv::Vec3b* v = viz.ptr<cv::Vec3b>(y);
    cv::Vec3b* dis = rep->disagreement.ptr<cv::Vec3b>(y);
    cv::Vec3b* vd = rep->viz_diff.ptr<cv::Vec3b>(y);
    for (int x = 0; x < W; ++x) {
      const bool g = cx[x] >= 0;
      const bool u = std::isfinite(Phi[x]);
      const bool vv = v[x][2] == 128;
      rep->unwrapped_valid += u;
      rep->viz_valid += vv;
      const double c = u ? Phi[x] * o.period_px / kTwoPi : 0.0;
      if (g && u) {
        ++rep->both_valid;
        const double a = o.cell_px * cx[x], b = o.cell_px * (cx[x] + 1);
        const double err = c < a ? a - c : (c > b ? c - b : 0.0);
        outside.push_back(static_cast<float>(err));
        const bool ok = err <= tol;
        rep->agree += ok;
        dis[x] = ok ? green : red;
      } else {
        dis[x] = (g || u) ? grey : blackc;
      }
      if (g && vv) {
        ++rep->gray_viz_both;
        const double dx =
            CircDistToInterval(v[x][0], o.cell_px * cx[x] - tol, o.cell_px * (cx[x] + 1) + tol);
        const double dy =
            CircDistToInterval(v[x][1], o.cell_px * cy[x] - tol, o.cell_px * (cy[x] + 1) + tol);
        rep->gray_viz_agree += dx == 0.0 && dy == 0.0;
      }
      if (u && vv) {
        ++rep->c_viz_both;
        double d = std::fmod(c - v[x][0], 256.0);
        if (d < 0) d += 256.0;
        if (d >= 128.0) d -= 256.0;  // signed, in [−128, 128)
        cviz_signed.push_back(static_cast<float>(d));
        d = std::abs(d);
        cviz.push_back(static_cast<float>(d));
        within2 += d <= 2.0;
        vd[x] = d <= 2.0 ? green : red;
      } else {
        vd[x] = (u || vv) ? grey : blackc;
      }
    }
  }
  rep->agree_share = rep->both_valid
                         ? static_cast<double>(rep->agree) / static_cast<double>(rep->both_valid)
                         : 0.0;
  rep->median_abs_err_px = Median(&outside);
  rep->gray_viz_share = rep->gray_viz_both ? static_cast<double>(rep->gray_viz_agree) /
                                                 static_cast<double>(rep->gray_viz_both)
                                           : 0.0;
  rep->c_viz_median_px = Median(&cviz);
  rep->c_viz_signed_median_px = Median(&cviz_signed);
  rep->c_viz_within2_share =
      rep->c_viz_both ? static_cast<double>(within2) / static_cast<double>(rep->c_viz_both) : 0.0;
  rep->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return Status::Ok();
}

// ---------------------------------------------------------------------------------------------
// kylemcdonald 3-step captures: relative unwrapping
// ---------------------------------------------------------------------------------------------
// The Unwrapper anchors a region only if exactly one offset K is admitted. Without any absolute
// reference we make that so, with depth_fraction = 1 (K must be admitted by every bounded pixel of
// the region, so the admitted K form exactly the interval [−W − r_min, W − 1 − r_max] for relative
// orders r ∈ [r_min, r_max]): pass 1 gives every usable pixel the window [−2πW, 2πW] and reports
// per region how many K it admits (RegionInfo::candidates); pass 2 (same φ and quality, so the same
// regions) lowers phase_max by candidates − 1 orders for that region's pixels, which removes
// exactly the top candidates − 1 offsets. (With depth_fraction < 1 the two tails of the order
// distribution interact once the window is tight, and the count is not exact.) The resulting Φ is
// relative: any constant multiple of 2π per region is as good.
inline Status UnwrapRelative(const cv::Mat& phi, const cv::Mat& quality, UnwrapOptions uopt,
                             int window_orders, UnwrapResult* out) {
  uopt.drop_outside_volume = false;
  uopt.depth_fraction =
      1.0;  // the admitted set is then exactly an interval that pass 2 can cut to one K
  const float lo = static_cast<float>(-kTwoPi * window_orders);
  const float hi = static_cast<float>(kTwoPi * window_orders);
  cv::Mat pmin(phi.size(), CV_32F, cv::Scalar(lo)), pmax(phi.size(), CV_32F, cv::Scalar(hi));
  UnwrapResult first;
  D3D_RETURN_IF_ERROR(UnwrapPhase(phi, quality, cv::Mat(), pmin, pmax, uopt, &first));
  for (int y = 0; y < phi.rows; ++y) {
    const int* reg = first.region.ptr<int>(y);
    float* mx = pmax.ptr<float>(y);
    for (int x = 0; x < phi.cols; ++x) {
      if (reg[x] < 0) continue;
      const int cand = first.regions[static_cast<size_t>(reg[x])].candidates;
      if (cand > 1) mx[x] = static_cast<float>(kTwoPi * (window_orders - (cand - 1)));
    }
  }
  return UnwrapPhase(phi, quality, cv::Mat(), pmin, pmax, uopt, out);
}

Status RunRelative(const RelativeOptions& o, RelativeReport* rep) {
  const auto t0 = std::chrono::steady_clock::now();
  *rep = RelativeReport{};
  cv::Mat P1, P2, P3;
  D3D_RETURN_IF_ERROR(ReadGrey(o.dir + "/phase1.png", &P1));
  D3D_RETURN_IF_ERROR(ReadGrey(o.dir + "/phase2.png", &P2));
  D3D_RETURN_IF_ERROR(ReadGrey(o.dir + "/phase3.png", &P3));
  rep->width = P1.cols;
  rep->height = P1.rows;
  FringePatternSpec spec;
  spec.name = "kylemcdonald-3step";
  spec.steps = 3;
  spec.fringe_period_px = 64.0;  // unknown; only the relative phase is used
  spec.marker_frame = -1;
  PhaseOptions popt;
  popt.algorithm = o.algorithm;
  popt.detect_marker = false;
  PhaseMaps pm;
  // ThreePhase's decoder: φ = atan2(√3(I1 − I3), 2 I2 − I1 − I3), i.e. shifts −2π/3, 0, +2π/3 as
  // in kamino410: frames n = 0, 1, 2 are phase2, phase1, phase3.
  D3D_RETURN_IF_ERROR(ComputePhase({P2, P1, P3}, spec, o.gamma, popt, &pm));
  rep->phase_valid = pm.num_valid;
  QualityOptions qopt;
  qopt.modulation_edge_ratio = o.modulation_edge_ratio;
  cv::Mat quality;
  D3D_RETURN_IF_ERROR(ComputeQualityMap(pm.phi, pm.modulation, pm.valid, qopt, &quality));
  UnwrapOptions uopt;
  uopt.monotonic_x = 0;  // unknown camera/projector layout
  uopt.min_region_pixels = o.min_region_pixels;
  UnwrapResult ur;
  D3D_RETURN_IF_ERROR(UnwrapRelative(pm.phi, quality, uopt, o.window_orders, &ur));
  rep->regions_total = ur.stats.regions_total;
  for (const RegionInfo& r : ur.regions) rep->regions_anchored += r.anchor == RegionAnchor::kDepth;
  rep->Phi = ur.Phi;
  if (std::getenv("D3D_REAL_FRINGE_DEBUG")) {
    std::fprintf(stderr, "  usable %lld dropped: conflict %lld small %lld rejected %lld\n",
                 static_cast<long long>(ur.stats.pixels_usable),
                 static_cast<long long>(ur.stats.pixels_conflict),
                 static_cast<long long>(ur.stats.pixels_small),
                 static_cast<long long>(ur.stats.pixels_rejected));
    for (const RegionInfo& r : ur.regions) {
      if (r.pixels < o.min_region_pixels) continue;
      std::fprintf(stderr, "  region %d px: %s K=%d bounded %d admitting %d cand %d\n", r.pixels,
                   RegionAnchorName(r.anchor), r.offset, r.bounded_pixels, r.admitting_pixels,
                   r.candidates);
    }
  }
  for (int y = 0; y < P1.rows; ++y) {
    const float* row = ur.Phi.ptr<float>(y);
    const int* reg = ur.region.ptr<int>(y);
    const float* below = y + 1 < P1.rows ? ur.Phi.ptr<float>(y + 1) : nullptr;
    const int* regb = y + 1 < P1.rows ? ur.region.ptr<int>(y + 1) : nullptr;
    for (int x = 0; x < P1.cols; ++x) {
      if (!std::isfinite(row[x])) continue;
      ++rep->unwrapped_valid;
      if (x + 1 < P1.cols && std::isfinite(row[x + 1]) && reg[x + 1] == reg[x]) {
        ++rep->pairs;
        rep->continuous += std::abs(row[x + 1] - row[x]) < kPi;
      }
      if (below && std::isfinite(below[x]) && regb[x] == reg[x]) {
        ++rep->pairs;
        rep->continuous += std::abs(below[x] - row[x]) < kPi;
      }
    }
  }
  rep->continuity_share =
      rep->pairs ? static_cast<double>(rep->continuous) / static_cast<double>(rep->pairs) : 0.0;
  rep->coverage = rep->phase_valid ? static_cast<double>(rep->unwrapped_valid) /
                                         static_cast<double>(rep->phase_valid)
                                   : 0.0;
  rep->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return Status::Ok();
}

// Colour image of an unwrapped phase map (jet over its finite range, black where NaN).
cv::Mat PhaseImage(const cv::Mat& Phi) {
  double lo = 0.0, hi = 0.0;
  cv::minMaxLoc(Phi, &lo, &hi, nullptr, nullptr, Phi == Phi);  // over the finite values
  return FalseColour(Phi, lo, hi, cv::COLORMAP_JET);
}

}  // namespace d3d::real_fringe
