// d3d-bench-unwrap: speed and fringe-order errors of our quality map + unwrapping (pipeline/unwrap)
// against OpenCV's HistogramPhaseUnwrapping (opencv_contrib phase_unwrapping) and scikit-image's
// unwrap_phase (Herráez 2002, via /usr/bin/python3 tools/bench/skimage_unwrap.py), on the same
// wrapped maps, on one core.
//
//   d3d-bench-unwrap [--burst DIR]... [--npy DIR]... [--reps N] [--python EXE] [--script PY]
//                    [--no-skimage] [--no-compare] [--dump DIR] [--max-laplace R] [--laplace-ref R]
//                    [--min-quality Q] [--max-jump R] [--max-reverse R] [--levels L]
//                    [Google Benchmark flags]
// (the tuning flags apply to the comparison runs, not to the Google Benchmark timings)
//
// Maps: synthetic "teeth" at 640×480 and 1280×1024 (pipeline/unwrap/synthetic_fringes.h, known
// truth); --burst takes a d3d-sim burst folder (calibration.json two levels up, truth_0/ needed)
// and builds the wrapped map with a stand-in phase (4-step, 3-step inside the marker stripes; the
// marker mask from the truth: an idealised detection) until pipeline/phase lands; --npy takes a
// folder with phi.npy, modulation.npy (float32), optional valid.npy, marker.npy (uint8),
// phase_min.npy, phase_max.npy (float32) and order_true.npy (int32, −1 unknown).
// Wrong orders: ours absolutely (and relatively, up to one offset per region); OpenCV and
// scikit-image unwrap relatively, so they are compared up to the best single offset per connected
// component of the unwrapped mask. All methods get the same mask: pixels with quality > 0.
#include <benchmark/benchmark.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/phase_unwrapping.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "calib/model/probe_calibration.h"
#include "common/core/npy_io.h"
#include "pipeline/triangulate/triangulate.h"
#include "pipeline/unwrap/quality_map.h"
#include "pipeline/unwrap/synthetic_fringes.h"
#include "pipeline/unwrap/unwrap.h"

#ifndef D3D_SKIMAGE_SCRIPT
#define D3D_SKIMAGE_SCRIPT "tools/bench/skimage_unwrap.py"
#endif

namespace d3d {
namespace {

namespace fs = std::filesystem;
constexpr double kTwoPi = 2.0 * M_PI;
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

struct Maps {
  std::string name;
  cv::Mat phi, modulation, valid, peak, marker, phase_min, phase_max;
  cv::Mat order_true;  // CV_32S, −1 unknown
  cv::Mat tooth;       // CV_8U, optional: pixels whose valid share is reported
  UnwrapOptions unwrap;
};

Maps FromSynthetic(int w, int h, uint64_t seed) {
  const SyntheticProbe probe = SyntheticProbe::ForSize(w, h);
  SyntheticNoise noise;
  noise.seed = seed;
  noise.intensity_sigma = 3.0;
  cv::Mat holes = cv::Mat::zeros(h, w, CV_8UC1);
  cv::RNG rng(seed);
  for (int i = 0; i < 12; ++i) {
    cv::circle(holes, {rng.uniform(0, w), rng.uniform(0, h)}, rng.uniform(2, 8) * w / 640, 255,
               cv::FILLED);
  }
  const SyntheticScene s =
      MakeFringeScene(TeethDepth(probe, 5, 12.0 * w / 640, seed), probe, noise, holes);
  Maps m;
  m.name = "synthetic teeth " + std::to_string(w) + "x" + std::to_string(h);
  m.phi = s.phi;
  m.modulation = s.modulation;
  m.valid = s.valid;
  m.marker = s.marker;
  m.phase_min = s.phase_min;
  m.phase_max = s.phase_max;
  m.order_true = s.order_true;
  m.tooth = s.valid.clone();
  return m;
}

cv::Mat MatFromNpy(const NpyArray& a) {
  if (a.shape.size() < 2) return {};
  const int h = static_cast<int>(a.shape[0]), w = static_cast<int>(a.shape[1]);
  const int ch = a.shape.size() > 2 ? static_cast<int>(a.shape[2]) : 1;
  int depth = -1;
  switch (a.type) {
    case NpyType::kFloat32:
      depth = CV_32F;
      break;
    case NpyType::kFloat64:
      depth = CV_64F;
      break;
    case NpyType::kUint8:
      depth = CV_8U;
      break;
    case NpyType::kUint16:
      depth = CV_16U;
      break;
    case NpyType::kInt32:
      depth = CV_32S;
      break;
  }
  cv::Mat m(h, w, CV_MAKETYPE(depth, ch));
  std::memcpy(m.data, a.bytes.data(), std::min(a.bytes.size(), m.total() * m.elemSize()));
  return m;
}

bool LoadNpy(const std::string& path, int type, cv::Mat* out, bool required) {
  NpyArray a;
  const Status st = ReadNpy(path, &a);
  if (!st.ok()) {
    if (required) std::fprintf(stderr, "%s: %s\n", path.c_str(), st.ToString().c_str());
    return false;
  }
  cv::Mat m = MatFromNpy(a);
  if (m.empty()) return false;
  m.convertTo(*out, type);
  return true;
}

bool FromNpyDir(const std::string& dir, Maps* m) {
  m->name = "npy " + dir;
  if (!LoadNpy(dir + "/phi.npy", CV_32F, &m->phi, true)) return false;
  if (!LoadNpy(dir + "/modulation.npy", CV_32F, &m->modulation, true)) return false;
  LoadNpy(dir + "/valid.npy", CV_8U, &m->valid, false);
  LoadNpy(dir + "/marker.npy", CV_8U, &m->marker, false);
  LoadNpy(dir + "/phase_min.npy", CV_32F, &m->phase_min, false);
  LoadNpy(dir + "/phase_max.npy", CV_32F, &m->phase_max, false);
  LoadNpy(dir + "/order_true.npy", CV_32S, &m->order_true, false);
  return true;
}

// A d3d-sim burst with its truth: stand-in phase, truth marker mask, bounds from calibration.json.
bool FromBurst(const std::string& dir, Maps* m) {
  ProbeCalibration calib;
  const std::string calib_path = (fs::path(dir) / ".." / ".." / "calibration.json").string();
  if (Status st = ProbeCalibration::Load(calib_path, &calib); !st.ok()) {
    std::fprintf(stderr, "%s: %s\n", calib_path.c_str(), st.ToString().c_str());
    return false;
  }
  const FringePatternSpec& pat = calib.pattern;
  if (pat.steps != 4 || pat.axis != 'x') {
    std::fprintf(stderr, "%s: the stand-in phase needs the 4-step x pattern\n", dir.c_str());
    return false;
  }
  cv::Mat I[4];
  for (int k = 0; k < 4; ++k) {
    cv::Mat img = cv::imread(dir + "/frame_" + std::to_string(k) + ".png", cv::IMREAD_GRAYSCALE);
    if (img.empty()) {
      std::fprintf(stderr, "%s: cannot read frame_%d.png\n", dir.c_str(), k);
      return false;
    }
    img.convertTo(I[k], CV_32F);
  }
  cv::Mat uv, vis, label;
  if (!LoadNpy(dir + "/truth_0/projector_uv.npy", CV_32FC2, &uv, true)) return false;
  vis = cv::imread(dir + "/truth_0/visibility.png", cv::IMREAD_GRAYSCALE);
  label = cv::imread(dir + "/truth_0/label.png", cv::IMREAD_GRAYSCALE);
  const int h = I[0].rows, w = I[0].cols;
  if (vis.size() != I[0].size() || label.size() != I[0].size() || uv.size() != I[0].size())
    return false;

  m->name = "render " + dir;
  m->phi.create(h, w, CV_32F);
  m->modulation.create(h, w, CV_32F);
  m->valid.create(h, w, CV_8U);
  m->peak.create(h, w, CV_32F);
  m->marker = cv::Mat::zeros(h, w, CV_8U);
  m->phase_min.create(h, w, CV_32F);
  m->phase_max.create(h, w, CV_32F);
  m->order_true.create(h, w, CV_32S);
  m->tooth.create(h, w, CV_8U);
  m->unwrap.marker_first_order = pat.marker_first_order;
  m->unwrap.marker_spacing_orders = pat.marker_spacing_orders;
  m->unwrap.marker_width_periods = pat.marker_width_periods;
  cv::Mat true_marker = cv::Mat::zeros(h, w, CV_8U);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const float i0 = I[0].at<float>(y, x), i1 = I[1].at<float>(y, x), i2 = I[2].at<float>(y, x),
                  i3 = I[3].at<float>(y, x);
      const cv::Vec2f t = uv.at<cv::Vec2f>(y, x);
      const bool lit = vis.at<uint8_t>(y, x) == 2 && std::isfinite(t[0]);
      const double Phi_true =
          lit ? kTwoPi * (t[0] - pat.phase_origin_px) / pat.fringe_period_px : NAN;
      const bool in_stripe = lit && pat.InMarker(t[0]);
      float phi, b;
      if (in_stripe) {  // frames 0–2: a 3-step set with π/2 shifts
        const float a = 0.5f * (i0 + i2);
        phi = std::atan2(i1 - a, 0.5f * (i0 - i2));
        b = std::hypot(i1 - a, 0.5f * (i0 - i2));
      } else {
        phi = std::atan2(i1 - i3, i0 - i2);
        b = 0.5f * std::hypot(i1 - i3, i0 - i2);
      }
      if (phi < 0) phi += static_cast<float>(kTwoPi);
      if (phi >= static_cast<float>(kTwoPi)) phi = 0.0f;
      m->phi.at<float>(y, x) = phi;
      m->modulation.at<float>(y, x) = b;
      m->valid.at<uint8_t>(y, x) = 255;
      m->peak.at<float>(y, x) = std::max(std::max(i0, i1), std::max(i2, i3));
      true_marker.at<uint8_t>(y, x) = in_stripe && b >= 4.0f ? 255 : 0;
      // Truth order of the measured phase: the k that brings φ + 2πk closest to the true Φ, if the
      // phase error is below 1 rad (else the phase itself is wrong: not counted as an order error).
      int32_t k = -1;
      if (lit) {
        const double kk = std::round((Phi_true - phi) / kTwoPi);
        if (std::fabs(Phi_true - phi - kTwoPi * kk) < 1.0) k = static_cast<int32_t>(kk);
      }
      m->order_true.at<int32_t>(y, x) = k;
      m->tooth.at<uint8_t>(y, x) = lit && label.at<uint8_t>(y, x) == 2 ? 255 : 0;
    }
  }
  // Admissible phase: each pixel's ray at depth_min and depth_max projected into the projector.
  PhaseTriangulator(calib).PhaseRange(&m->phase_min, &m->phase_max);
  // An imperfect detection: the stripe bleeds 1 px sideways.
  cv::dilate(true_marker, m->marker, cv::getStructuringElement(cv::MORPH_RECT, {3, 1}));
  return true;
}

template <typename F>
double MedianMs(int reps, F&& f) {
  std::vector<double> t;
  for (int i = 0; i < reps; ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    f();
    t.push_back(
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  }
  std::sort(t.begin(), t.end());
  return t[t.size() / 2];
}

struct OrderErrors {
  int64_t evaluated = 0;  // output pixels with a known truth order
  int64_t wrong = 0;
  double Share() const { return evaluated > 0 ? static_cast<double>(wrong) / evaluated : 0.0; }
};

// Relative comparison: per label (connected component / region), the best single offset.
OrderErrors RelativeErrors(const cv::Mat& order, const cv::Mat& labels, const cv::Mat& truth) {
  std::map<std::pair<int, int>, int64_t> count;  // (label, offset) → pixels
  std::map<int, int64_t> total;
  OrderErrors e;
  for (int y = 0; y < order.rows; ++y) {
    for (int x = 0; x < order.cols; ++x) {
      const int k = order.at<int32_t>(y, x), t = truth.at<int32_t>(y, x),
                l = labels.at<int32_t>(y, x);
      if (k == INT32_MIN || t < 0 || l < 0) continue;
      ++count[{l, t - k}];
      ++total[l];
      ++e.evaluated;
    }
  }
  std::map<int, int64_t> best;
  for (const auto& [key, n] : count) best[key.first] = std::max(best[key.first], n);
  for (const auto& [l, n] : total) e.wrong += n - best[l];
  return e;
}

// OpenCV's HistogramPhaseUnwrapping for a map of φ ∈ [0, 2π): its input in [−π, π) (0 outside the
// mask) and an unwrapper sized for it. Relative unwrapping (no absolute orders).
struct OpenCvUnwrap {
  cv::Mat wrapped;
  cv::Ptr<cv::phase_unwrapping::HistogramPhaseUnwrapping> unwrapper;
};
OpenCvUnwrap MakeOpenCvUnwrap(const cv::Mat& phi, const cv::Mat& mask) {
  OpenCvUnwrap u;
  u.wrapped = phi - static_cast<float>(M_PI);
  u.wrapped.setTo(0.0f, ~mask);
  cv::phase_unwrapping::HistogramPhaseUnwrapping::Params params;
  params.width = phi.cols;
  params.height = phi.rows;
  u.unwrapper = cv::phase_unwrapping::HistogramPhaseUnwrapping::create(params);
  return u;
}

// Orders of an unwrapped phase map Ψ (any offset): k = round((Ψ + shift − φ)/2π); INT32_MIN where
// the method gave nothing or outside the mask.
cv::Mat OrdersOf(const cv::Mat& unwrapped, const cv::Mat& phi, const cv::Mat& mask, double shift) {
  cv::Mat k(phi.size(), CV_32S, cv::Scalar(INT32_MIN));
  for (int y = 0; y < phi.rows; ++y) {
    for (int x = 0; x < phi.cols; ++x) {
      const float u = unwrapped.at<float>(y, x);
      if (mask.at<uint8_t>(y, x) == 0 || !std::isfinite(u)) continue;
      k.at<int32_t>(y, x) =
          static_cast<int32_t>(std::lround((u + shift - phi.at<float>(y, x)) / kTwoPi));
    }
  }
  return k;
}

struct Options {
  std::vector<std::string> bursts, npys;
  int reps = 15;
  std::string python = "/usr/bin/python3";
  std::string script = D3D_SKIMAGE_SCRIPT;
  bool skimage = true;
  bool compare = true;
  std::string dump;  // write each map (the --npy format) and our orders to DUMP/mapN/
  QualityOptions quality;
  UnwrapOptions unwrap;  // marker fields are taken from the map
};

void Dump(const Maps& m, const UnwrapResult& res, const std::string& dir) {
  fs::create_directories(dir);
  const std::vector<int64_t> shape = {m.phi.rows, m.phi.cols};
  auto put = [&](const char* name, const cv::Mat& mat, NpyType type) {
    if (mat.empty()) return;
    const cv::Mat c = mat.clone();
    if (!WriteNpy(dir + "/" + name, type, shape, c.data).ok())
      std::fprintf(stderr, "cannot write %s\n", name);
  };
  put("phi.npy", m.phi, NpyType::kFloat32);
  put("modulation.npy", m.modulation, NpyType::kFloat32);
  put("valid.npy", m.valid, NpyType::kUint8);
  put("marker.npy", m.marker, NpyType::kUint8);
  put("phase_min.npy", m.phase_min, NpyType::kFloat32);
  put("phase_max.npy", m.phase_max, NpyType::kFloat32);
  put("order_true.npy", m.order_true, NpyType::kInt32);
  put("ours_order.npy", res.order, NpyType::kInt32);
  put("ours_region.npy", res.region, NpyType::kInt32);
}

void Compare(const Maps& m, const Options& opt, int index) {
  std::printf("\n== %s (%dx%d)\n", m.name.c_str(), m.phi.cols, m.phi.rows);
  cv::setNumThreads(1);
  const QualityOptions qopt = opt.quality;
  UnwrapOptions uopt = opt.unwrap;
  uopt.marker_first_order = m.unwrap.marker_first_order;
  uopt.marker_spacing_orders = m.unwrap.marker_spacing_orders;
  uopt.marker_width_periods = m.unwrap.marker_width_periods;
  cv::Mat quality;
  Unwrapper unwrapper(uopt);
  UnwrapResult res;
  auto run_quality = [&] {
    if (!ComputeQualityMap(m.phi, m.modulation, m.valid, m.peak, qopt, &quality).ok()) std::abort();
  };
  auto run_unwrap = [&] {
    if (!unwrapper.Run(m.phi, quality, m.marker, m.phase_min, m.phase_max, &res).ok()) std::abort();
  };
  run_quality();
  run_unwrap();
  const double ms_quality = MedianMs(opt.reps, run_quality);
  const double ms_unwrap = MedianMs(opt.reps, run_unwrap);
  const double ms_ours = ms_quality + ms_unwrap;
  const cv::Mat mask = quality > 0;
  const int64_t usable = cv::countNonZero(mask);
  if (!opt.dump.empty()) Dump(m, res, opt.dump + "/map" + std::to_string(index));

  // Ours: absolute orders.
  cv::Mat ours_k(m.phi.size(), CV_32S, cv::Scalar(INT32_MIN));
  OrderErrors ours_abs;
  int64_t tooth_lit = 0, tooth_kept = 0;
  for (int y = 0; y < m.phi.rows; ++y) {
    for (int x = 0; x < m.phi.cols; ++x) {
      const int k = res.order.at<int32_t>(y, x);
      const bool kept = std::isfinite(res.Phi.at<float>(y, x));
      if (!m.tooth.empty() && m.tooth.at<uint8_t>(y, x) != 0) {
        ++tooth_lit;
        tooth_kept += kept;
      }
      if (!kept) continue;
      ours_k.at<int32_t>(y, x) = k;
      if (m.order_true.empty()) continue;
      const int t = m.order_true.at<int32_t>(y, x);
      if (t < 0) continue;
      ++ours_abs.evaluated;
      ours_abs.wrong += k != t;
    }
  }
  std::printf(
      "ours   quality %.3f ms + unwrap %.3f ms = %.3f ms | usable %lld px, valid %lld (%.1f%%), "
      "regions %d: marker %d, depth %d, rejected %d, small %d; conflicts %lld, outside %lld\n",
      ms_quality, ms_unwrap, ms_ours, static_cast<long long>(usable),
      static_cast<long long>(res.stats.pixels_valid),
      usable > 0 ? 100.0 * res.stats.pixels_valid / usable : 0.0, res.stats.regions_total,
      res.stats.regions_marker, res.stats.regions_depth, res.stats.regions_rejected,
      res.stats.regions_small, static_cast<long long>(res.stats.pixels_conflict),
      static_cast<long long>(res.stats.pixels_outside));
  for (size_t i = 0; i < res.regions.size(); ++i) {
    const RegionInfo& g = res.regions[i];
    if (g.pixels < 2000) continue;
    std::printf(
        "       region %zu: %d px %s K=%d marker hits %d/%d rival %d, bounded %d admitting %d, "
        "depth candidates %d, violations %d\n",
        i, g.pixels, RegionAnchorName(g.anchor), g.offset, g.marker_hits, g.marker_predicted,
        g.marker_rival_hits, g.bounded_pixels, g.admitting_pixels, g.candidates, g.violations);
  }
  if (tooth_lit > 0) {
    std::printf("       valid share of the %s: %.2f%% of %lld px\n",
                m.name.rfind("render", 0) == 0 ? "lit tooth pixels" : "object pixels",
                100.0 * tooth_kept / tooth_lit, static_cast<long long>(tooth_lit));
  }

  // OpenCV HistogramPhaseUnwrapping: input in [−π, π), relative.
  OpenCvUnwrap ocv = MakeOpenCvUnwrap(m.phi, mask);
  cv::Mat cv_out;
  const double ms_cv = MedianMs(std::max(3, opt.reps / 3),
                                [&] { ocv.unwrapper->unwrapPhaseMap(ocv.wrapped, cv_out, mask); });
  cv::Mat cv_k = OrdersOf(cv_out, m.phi, mask, M_PI);
  cv::Mat cc;
  cv::connectedComponents(mask, cc, 4, CV_32S);
  cc.setTo(-1, ~mask);

  // scikit-image through python.
  double ms_sk = -1.0;
  cv::Mat sk_k;
  std::string sk_version;
  if (opt.skimage) {
    const fs::path tmp =
        fs::temp_directory_path() / ("d3d-bench-unwrap-" + std::to_string(::getpid()));
    fs::create_directories(tmp);
    cv::Mat wp = m.phi - static_cast<float>(M_PI);
    wp.setTo(0.0f, ~mask);
    const std::vector<int64_t> shape = {m.phi.rows, m.phi.cols};
    cv::Mat wpc = wp.clone(), maskc = mask.clone();
    if (WriteNpy((tmp / "wrapped.npy").string(), NpyType::kFloat32, shape, wpc.data).ok() &&
        WriteNpy((tmp / "mask.npy").string(), NpyType::kUint8, shape, maskc.data).ok()) {
      const std::string cmd = opt.python + " " + opt.script + " " + tmp.string() + " " +
                              std::to_string(std::max(3, opt.reps / 5)) + " 2>&1";
      std::string out;
      if (FILE* p = ::popen(cmd.c_str(), "r")) {
        char buf[512];
        while (std::fgets(buf, sizeof buf, p)) out += buf;
        const int rc = ::pclose(p);
        const size_t at = out.find("\"ms\": ");
        if (rc == 0 && at != std::string::npos) {
          ms_sk = std::atof(out.c_str() + at + 6);
          const size_t v = out.find("\"version\": \"");
          if (v != std::string::npos)
            sk_version = out.substr(v + 12, out.find('"', v + 12) - v - 12);
          cv::Mat sk;
          if (LoadNpy((tmp / "unwrapped.npy").string(), CV_32F, &sk, true))
            sk_k = OrdersOf(sk, m.phi, mask, M_PI);
        } else {
          std::printf("scikit-image: failed (%s): %s\n", cmd.c_str(), out.c_str());
        }
      }
    }
    fs::remove_all(tmp);
  }

  std::printf("OpenCV HistogramPhaseUnwrapping %.3f ms (%.1fx ours)\n", ms_cv, ms_cv / ms_ours);
  if (ms_sk >= 0) {
    std::printf("scikit-image %s unwrap_phase %.3f ms (%.1fx ours)\n", sk_version.c_str(), ms_sk,
                ms_sk / ms_ours);
  } else if (opt.skimage) {
    std::printf("scikit-image: not run (install python3-skimage)\n");
  }
  if (m.order_true.empty()) return;
  const OrderErrors ours_rel = RelativeErrors(ours_k, res.region, m.order_true);
  const OrderErrors cv_rel = RelativeErrors(cv_k, cc, m.order_true);
  std::printf("wrong orders: ours %lld of %lld kept (%.4f%%; relative per region %.4f%%)\n",
              static_cast<long long>(ours_abs.wrong), static_cast<long long>(ours_abs.evaluated),
              100 * ours_abs.Share(), 100 * ours_rel.Share());
  std::printf("              OpenCV %lld of %lld (%.4f%%, relative per connected component)\n",
              static_cast<long long>(cv_rel.wrong), static_cast<long long>(cv_rel.evaluated),
              100 * cv_rel.Share());
  if (!sk_k.empty()) {
    const OrderErrors sk_rel = RelativeErrors(sk_k, cc, m.order_true);
    std::printf(
        "              scikit-image %lld of %lld (%.4f%%, relative per connected component)\n",
        static_cast<long long>(sk_rel.wrong), static_cast<long long>(sk_rel.evaluated),
        100 * sk_rel.Share());
  }
}

std::vector<std::unique_ptr<Maps>>& Registry() {
  static std::vector<std::unique_ptr<Maps>> maps;
  return maps;
}

void RegisterBenchmarks(const Maps& m, const std::string& tag) {
  benchmark::RegisterBenchmark(("quality/" + tag).c_str(), [&m](benchmark::State& state) {
    cv::Mat q;
    for (auto _ : state) {
      if (!ComputeQualityMap(m.phi, m.modulation, m.valid, m.peak, {}, &q).ok())
        state.SkipWithError("quality");
      benchmark::DoNotOptimize(q.data);
    }
  })->Unit(benchmark::kMillisecond);
  benchmark::RegisterBenchmark(("unwrap/" + tag).c_str(), [&m](benchmark::State& state) {
    cv::Mat q;
    if (!ComputeQualityMap(m.phi, m.modulation, m.valid, m.peak, {}, &q).ok())
      state.SkipWithError("quality");
    Unwrapper u(m.unwrap);
    UnwrapResult r;
    for (auto _ : state) {
      if (!u.Run(m.phi, q, m.marker, m.phase_min, m.phase_max, &r).ok())
        state.SkipWithError("unwrap");
      benchmark::DoNotOptimize(r.Phi.data);
    }
  })->Unit(benchmark::kMillisecond);
  benchmark::RegisterBenchmark(("opencv_histogram/" + tag).c_str(), [&m](benchmark::State& state) {
    cv::setNumThreads(1);
    cv::Mat q;
    if (!ComputeQualityMap(m.phi, m.modulation, m.valid, m.peak, {}, &q).ok())
      state.SkipWithError("quality");
    const cv::Mat mask = q > 0;
    OpenCvUnwrap ocv = MakeOpenCvUnwrap(m.phi, mask);
    cv::Mat out;
    for (auto _ : state) ocv.unwrapper->unwrapPhaseMap(ocv.wrapped, out, mask);
  })->Unit(benchmark::kMillisecond);
}

}  // namespace
}  // namespace d3d

int main(int argc, char** argv) {
  using namespace d3d;
  Options opt;
  std::vector<char*> rest = {argv[0]};
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "%s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--burst")
      opt.bursts.push_back(next());
    else if (a == "--npy")
      opt.npys.push_back(next());
    else if (a == "--reps")
      opt.reps = std::max(1, std::atoi(next().c_str()));
    else if (a == "--python")
      opt.python = next();
    else if (a == "--script")
      opt.script = next();
    else if (a == "--no-skimage")
      opt.skimage = false;
    else if (a == "--no-compare")
      opt.compare = false;
    else if (a == "--dump")
      opt.dump = next();
    else if (a == "--max-laplace")
      opt.quality.max_laplace = std::atof(next().c_str());
    else if (a == "--laplace-ref")
      opt.quality.laplace_ref = std::atof(next().c_str());
    else if (a == "--min-quality")
      opt.unwrap.min_quality = static_cast<float>(std::atof(next().c_str()));
    else if (a == "--max-jump")
      opt.unwrap.max_jump = std::atof(next().c_str());
    else if (a == "--max-reverse")
      opt.unwrap.max_reverse = std::atof(next().c_str());
    else if (a == "--levels")
      opt.unwrap.quality_levels = std::atoi(next().c_str());
    else if (a == "--help" || a == "-h") {
      std::printf(
          "d3d-bench-unwrap [--burst DIR]... [--npy DIR]... [--reps N] [--python EXE] [--script "
          "PY]\n"
          "                 [--no-skimage] [--no-compare] [--dump DIR] [--max-laplace R] "
          "[--laplace-ref R]\n"
          "                 [--min-quality Q] [--max-jump R] [--max-reverse R] [--levels L]\n"
          "                 [Google Benchmark flags]\n");
      return 0;
    } else
      rest.push_back(argv[i]);
  }
  auto& maps = Registry();
  maps.push_back(std::make_unique<Maps>(FromSynthetic(640, 480, 7)));
  maps.push_back(std::make_unique<Maps>(FromSynthetic(1280, 1024, 7)));
  RegisterBenchmarks(*maps[0], "synthetic640x480");
  RegisterBenchmarks(*maps[1], "synthetic1280x1024");
  for (const std::string& d : opt.npys) {
    auto m = std::make_unique<Maps>();
    if (FromNpyDir(d, m.get())) maps.push_back(std::move(m));
  }
  for (const std::string& d : opt.bursts) {
    auto m = std::make_unique<Maps>();
    if (FromBurst(d, m.get())) maps.push_back(std::move(m));
  }
  for (size_t i = 2; i < maps.size(); ++i) RegisterBenchmarks(*maps[i], "map" + std::to_string(i));

  int bargc = static_cast<int>(rest.size());
  benchmark::Initialize(&bargc, rest.data());
  if (benchmark::ReportUnrecognizedArguments(bargc, rest.data())) return 1;
  cv::setNumThreads(1);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  if (opt.compare) {
    for (size_t i = 0; i < maps.size(); ++i) Compare(*maps[i], opt, static_cast<int>(i));
  }
  return 0;
}
