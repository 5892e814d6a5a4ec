#include "pipeline/unwrap/quality_map.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "pipeline/unwrap/wrap_util.h"

namespace d3d {

void QualityOptions::Check() const {
  const double all[] = {shadow_modulation,     min_modulation,        full_modulation,
                        laplace_ref,           max_laplace,           saturation_level,
                        modulation_edge_ratio, modulation_edge_min_dn};
  for (double v : all) D3D_CHECK_MSG(std::isfinite(v), "QualityOptions: non-finite value");
  D3D_CHECK_MSG(shadow_modulation >= 0 && shadow_modulation <= min_modulation,
                "QualityOptions: need 0 <= shadow_modulation <= min_modulation, got "
                    << shadow_modulation << ", " << min_modulation);
  D3D_CHECK_MSG(min_modulation > 0,
                "QualityOptions: min_modulation must be > 0, got " << min_modulation);
  D3D_CHECK_MSG(min_modulation < full_modulation,
                "QualityOptions: need min_modulation < full_modulation, got "
                    << min_modulation << ", " << full_modulation);
  D3D_CHECK_MSG(laplace_ref > 0, "QualityOptions: laplace_ref must be > 0, got " << laplace_ref);
  D3D_CHECK_MSG(max_laplace > 0, "QualityOptions: max_laplace must be > 0, got " << max_laplace);
  D3D_CHECK_MSG(saturation_level > 0,
                "QualityOptions: saturation_level must be > 0, got " << saturation_level);
  D3D_CHECK_MSG(
      modulation_edge_min_dn >= 0,
      "QualityOptions: modulation_edge_min_dn must be >= 0, got " << modulation_edge_min_dn);
  D3D_CHECK_MSG(
      modulation_edge_close == 0 || modulation_edge_close == 1,
      "QualityOptions: modulation_edge_close must be 0 or 1, got " << modulation_edge_close);
  D3D_CHECK_MSG(modulation_edge_ratio == 0 || modulation_edge_ratio > 1,
                "QualityOptions: modulation_edge_ratio must be 0 (off) or > 1, got "
                    << modulation_edge_ratio);
}

namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// Cleaned phase row: φ in [0, 2π), NaN where the pixel is masked (invalid, shadow, low modulation,
// saturated), so that masked pixels do not enter their neighbours' second differences.
void CleanRow(const float* phi, const float* mod, const uint8_t* valid, const uint8_t* peak8,
              const float* peak32, float min_mod, float sat, int w, float* out) {
  for (int x = 0; x < w; ++x) {
    const float p = phi[x];
    const float b = mod[x];
    bool ok =
        std::isfinite(p) && b >= min_mod && std::isfinite(b) && (valid == nullptr || valid[x] != 0);
    if (peak8 != nullptr && static_cast<float>(peak8[x]) >= sat) ok = false;
    if (peak32 != nullptr && peak32[x] >= sat) ok = false;
    out[x] = ok ? internal::WrapTo2Pi(p) : kNaN;
  }
}

}  // namespace

Status ComputeQualityMap(const cv::Mat& phi, const cv::Mat& modulation, const cv::Mat& valid,
                         const QualityOptions& options, cv::Mat* quality, cv::Mat* reason) {
  return ComputeQualityMap(phi, modulation, valid, cv::Mat(), options, quality, reason);
}

Status ComputeQualityMap(const cv::Mat& phi, const cv::Mat& modulation, const cv::Mat& valid,
                         const cv::Mat& peak, const QualityOptions& options, cv::Mat* quality,
                         cv::Mat* reason) {
  if (quality == nullptr) return InvalidArgument("ComputeQualityMap: quality output is null");
  try {
    options.Check();
  } catch (const std::invalid_argument& e) {
    return InvalidArgument(std::string("ComputeQualityMap: ") + e.what());
  }
  if (phi.empty()) return InvalidArgument("ComputeQualityMap: phi is empty");
  if (phi.type() != CV_32FC1) return InvalidArgument("ComputeQualityMap: phi must be CV_32FC1");
  if (modulation.type() != CV_32FC1 || modulation.size() != phi.size()) {
    std::ostringstream os;
    os << "ComputeQualityMap: modulation must be CV_32FC1 of phi's size " << phi.cols << "x"
       << phi.rows << ", got type " << modulation.type() << " size " << modulation.cols << "x"
       << modulation.rows;
    return InvalidArgument(os.str());
  }
  if (!valid.empty() && (valid.type() != CV_8UC1 || valid.size() != phi.size())) {
    return InvalidArgument("ComputeQualityMap: valid must be empty or CV_8UC1 of phi's size");
  }
  if (!peak.empty() &&
      ((peak.type() != CV_8UC1 && peak.type() != CV_32FC1) || peak.size() != phi.size())) {
    return InvalidArgument(
        "ComputeQualityMap: peak must be empty or CV_8UC1/CV_32FC1 of phi's size");
  }
  if (quality->data == phi.data || quality->data == modulation.data) {
    return InvalidArgument("ComputeQualityMap: quality must not alias an input");
  }

  const int h = phi.rows;
  const int w = phi.cols;
  quality->create(h, w, CV_32FC1);
  if (reason != nullptr) reason->create(h, w, CV_8UC1);

  const float shadow = static_cast<float>(options.shadow_modulation);
  const float min_mod = static_cast<float>(options.min_modulation);
  const float inv_full = static_cast<float>(1.0 / options.full_modulation);
  const float inv_ref2 = static_cast<float>(1.0 / (options.laplace_ref * options.laplace_ref));
  const float max_d2 = static_cast<float>(options.max_laplace * options.max_laplace);
  const float sat = static_cast<float>(options.saturation_level);
  const bool edge_test = options.modulation_edge_ratio > 1;
  const float edge_hi = static_cast<float>(options.modulation_edge_ratio);
  // Modulation edges: along x and y, the two neighbours' B (both finite and ≥ min_modulation)
  // differ by more than the factor `ratio` (and by ≥ min_dn); bit 0 of medge. No division: both are
  // > 0, so max(t, 1/t) > r with t = b/a is b > r·a or a > r·b.
  std::vector<uint8_t> medge;
  if (edge_test) {
    const float edge_dn = static_cast<float>(options.modulation_edge_min_dn);
    const float lo = min_mod;
    auto step = [edge_hi, edge_dn, lo](float a, float b2) -> uint8_t {
      // NaN fails every comparison: no edge.
      return (a >= lo && b2 >= lo && (b2 > edge_hi * a || a > edge_hi * b2) &&
              std::fabs(b2 - a) >= edge_dn)
                 ? 1
                 : 0;
    };
    medge.assign(static_cast<size_t>(w) * h, 0);
    for (int y = 0; y < h; ++y) {
      const float* bc = modulation.ptr<float>(y);
      const float* bu = y > 0 ? modulation.ptr<float>(y - 1) : nullptr;
      const float* bd = y + 1 < h ? modulation.ptr<float>(y + 1) : nullptr;
      uint8_t* m = medge.data() + static_cast<size_t>(y) * w;
      for (int x = 1; x + 1 < w; ++x) m[x] = step(bc[x - 1], bc[x + 1]);
      if (bu != nullptr && bd != nullptr) {
        for (int x = 0; x < w; ++x) m[x] |= step(bu[x], bd[x]);
      }
    }
    if (options.modulation_edge_close != 0) {
      // Bridge one-pixel gaps: decided on the unbridged mask (bit 0), marked in bit 1.
      auto e = [&](int yy, int xx) {
        return yy >= 0 && yy < h && xx >= 0 && xx < w &&
               (medge[static_cast<size_t>(yy) * w + xx] & 1u) != 0;
      };
      for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) {
          uint8_t& m = medge[static_cast<size_t>(y) * w + x];
          if (m != 0) continue;
          if ((e(y, x - 1) && e(y, x + 1)) || (e(y - 1, x) && e(y + 1, x)) ||
              (e(y - 1, x - 1) && e(y + 1, x + 1)) || (e(y - 1, x + 1) && e(y + 1, x - 1))) {
            m = 2;
          }
        }
      }
    }
  }

  // Five cleaned rows (y−2 .. y+2), each with two NaN border columns on both sides.
  const int rw = w + 4;
  std::vector<float> rows(5 * static_cast<size_t>(rw), kNaN);
  std::vector<float> dxbuf(static_cast<size_t>(w + 3), kNaN);
  float* dx = dxbuf.data() + 1;  // dx[x] = W(φ(x) − φ(x−1)), x = −1 .. w+1
  float* r[5];
  for (int k = 0; k < 5; ++k) r[k] = rows.data() + static_cast<size_t>(k) * rw;
  const bool p8 = !peak.empty() && peak.type() == CV_8UC1;
  const bool p32 = !peak.empty() && peak.type() == CV_32FC1;
  auto clean = [&](int y, float* dst) {
    if (y < 0 || y >= h) {
      std::fill(dst, dst + rw, kNaN);
      return;
    }
    CleanRow(phi.ptr<float>(y), modulation.ptr<float>(y),
             valid.empty() ? nullptr : valid.ptr<uint8_t>(y), p8 ? peak.ptr<uint8_t>(y) : nullptr,
             p32 ? peak.ptr<float>(y) : nullptr, min_mod, sat, w, dst + 2);
  };
  for (int k = 0; k < 4; ++k) clean(k - 2, r[k + 1]);  // r[1..4] = rows −2 .. 1
  for (int y = 0; y < h; ++y) {
    std::rotate(r, r + 1, r + 5);  // r[0..3] = rows y−2 .. y+1
    clean(y + 2, r[4]);
    const float* u2 = r[0] + 2;
    const float* u1 = r[1] + 2;
    const float* c = r[2] + 2;
    const float* d1 = r[3] + 2;
    const float* d2 = r[4] + 2;
    for (int x = -1; x <= w + 1; ++x) dx[x] = internal::WrapPi(c[x] - c[x - 1]);
    const float* b = modulation.ptr<float>(y);
    const float* ph = phi.ptr<float>(y);
    const uint8_t* vd = valid.empty() ? nullptr : valid.ptr<uint8_t>(y);
    float* q = quality->ptr<float>(y);
    uint8_t* why = reason != nullptr ? reason->ptr<uint8_t>(y) : nullptr;
    for (int x = 0; x < w; ++x) {
      QualityReason rs = QualityReason::kUsable;
      float value = 0.0f;
      if (!std::isnan(c[x])) {
        // Second differences: centred, else one-sided (forward, then backward) along each axis.
        float hx = dx[x + 1] - dx[x];
        if (std::isnan(hx)) hx = dx[x + 2] - dx[x + 1];
        if (std::isnan(hx)) hx = dx[x] - dx[x - 1];
        const float dyu = internal::WrapPi(c[x] - u1[x]);
        const float dyd = internal::WrapPi(d1[x] - c[x]);
        float vy = dyd - dyu;
        if (std::isnan(vy)) vy = internal::WrapPi(d2[x] - d1[x]) - dyd;
        if (std::isnan(vy)) vy = dyu - internal::WrapPi(u1[x] - u2[x]);
        const bool has_h = !std::isnan(hx);
        const bool has_v = !std::isnan(vy);
        float dd;
        if (has_h && has_v) {
          dd = hx * hx + vy * vy;
        } else if (has_h) {
          dd = 2.0f * hx * hx;
        } else if (has_v) {
          dd = 2.0f * vy * vy;
        } else {
          dd = -1.0f;
        }
        if (dd < 0.0f) {
          rs = QualityReason::kIsolated;
        } else if (dd > max_d2) {
          rs = QualityReason::kPhaseNoise;
        } else if (edge_test && medge[static_cast<size_t>(y) * w + x] != 0) {
          rs = QualityReason::kModulationEdge;
        } else {
          // B ≥ min_modulation > 0 and dd ≤ max_d2 keep the value > 0.
          value = std::min(1.0f, b[x] * inv_full) / (1.0f + dd * inv_ref2);
        }
      } else if (!std::isfinite(b[x]) || !std::isfinite(ph[x]) || (vd != nullptr && vd[x] == 0)) {
        rs = QualityReason::kInvalid;
      } else if (!(b[x] >= shadow)) {
        rs = QualityReason::kShadow;
      } else if (b[x] < min_mod) {
        rs = QualityReason::kLowModulation;
      } else {
        rs = QualityReason::kSaturated;  // the only other reason CleanRow masks a pixel
      }
      q[x] = value;
      if (why != nullptr) why[x] = static_cast<uint8_t>(rs);
    }
  }
  return Status::Ok();
}

}  // namespace d3d
