#include "pipeline/unwrap/synthetic_fringes.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

namespace d3d {

namespace {
constexpr float kNoValue = std::numeric_limits<float>::quiet_NaN();  // no surface, no phase
constexpr double kTwoPi = 2.0 * M_PI;
}  // namespace

SyntheticProbe SyntheticProbe::ForSize(int width, int height) {
  SyntheticProbe p;
  p.fc *= static_cast<double>(width) / p.width;
  p.width = width;
  p.height = height;
  return p;
}

double SyntheticProbe::ColumnAt(double x, double z_mm) const {
  const double cx = 0.5 * (width - 1);
  return fp * (x - cx) / fc - fp * baseline_mm / z_mm + proj_cx;
}

double SyntheticProbe::PhaseAt(double x, double z_mm) const {
  return kTwoPi * (ColumnAt(x, z_mm) - phase_origin_px) / period_px;
}

SyntheticScene MakeFringeScene(const cv::Mat& depth, const SyntheticProbe& probe,
                               const SyntheticNoise& noise, const cv::Mat& holes) {
  CV_Assert(depth.type() == CV_32FC1 && depth.rows == probe.height && depth.cols == probe.width);
  CV_Assert(holes.empty() || (holes.type() == CV_8UC1 && holes.size() == depth.size()));
  const int h = depth.rows, w = depth.cols;
  SyntheticScene s;
  s.depth = depth.clone();
  s.Phi_true.create(h, w, CV_32FC1);
  s.order_true.create(h, w, CV_32SC1);
  s.phi.create(h, w, CV_32FC1);
  s.modulation.create(h, w, CV_32FC1);
  s.valid.create(h, w, CV_8UC1);
  s.marker.create(h, w, CV_8UC1);
  s.phase_min.create(h, w, CV_32FC1);
  s.phase_max.create(h, w, CV_32FC1);
  cv::RNG rng(noise.seed);
  auto z_at = [&](int x, int y) -> float {
    if (x < 0 || y < 0 || x >= w || y >= h) return kNoValue;
    return depth.at<float>(y, x);
  };
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      s.phase_min.at<float>(y, x) = static_cast<float>(probe.PhaseAt(x, probe.z_min));
      s.phase_max.at<float>(y, x) = static_cast<float>(probe.PhaseAt(x, probe.z_max));
      const float z = depth.at<float>(y, x);
      float Phi = kNoValue, phi = kNoValue, b = 0.0f;
      int32_t k = -1;
      uint8_t lit = 0, mk = 0;
      if (std::isfinite(z) && z > 0) {
        const double u = probe.ColumnAt(x, z);
        if (u >= 0 && u < probe.proj_width) {
          // Surface slope from central differences (one-sided at the silhouette) → n_z.
          auto slope = [&](float za, float zb, float zc) {
            if (std::isfinite(za) && std::isfinite(zb)) return 0.5 * (zb - za);
            if (std::isfinite(zb)) return static_cast<double>(zb - zc);
            if (std::isfinite(za)) return static_cast<double>(zc - za);
            return 0.0;
          };
          const double mm_per_px = z / probe.fc;
          const double gx = slope(z_at(x - 1, y), z_at(x + 1, y), z) / mm_per_px;
          const double gy = slope(z_at(x, y - 1), z_at(x, y + 1), z) / mm_per_px;
          const double nz = 1.0 / std::sqrt(1.0 + gx * gx + gy * gy);
          b = static_cast<float>(noise.modulation * nz);
          if (!holes.empty() && holes.at<uint8_t>(y, x) != 0) b = 0.5f;
          const double Phi_d = probe.PhaseAt(x, z);
          const double sigma = noise.intensity_sigma * std::sqrt(0.5) / std::max(0.5f, b);
          const double noisy = Phi_d + rng.gaussian(sigma);
          Phi = static_cast<float>(Phi_d);
          k = static_cast<int32_t>(std::floor(noisy / kTwoPi));
          phi = static_cast<float>(noisy - kTwoPi * k);
          if (phi >= static_cast<float>(kTwoPi) || phi < 0.0f) phi = 0.0f;
          lit = 255;
          const int k_true = static_cast<int>(std::floor(Phi_d / kTwoPi));
          const int d = k_true - probe.marker_first_order;
          const bool in_stripe = probe.marker_spacing_orders > 0
                                     ? (d >= 0 && d % probe.marker_spacing_orders == 0)
                                     : d == 0;
          if (in_stripe && b > 4.0f) {
            mk = rng.uniform(0.0, 1.0) >= noise.marker_miss_rate ? 255 : 0;
          } else {
            mk = rng.uniform(0.0, 1.0) < noise.marker_false_rate ? 255 : 0;
          }
        }
      }
      s.Phi_true.at<float>(y, x) = Phi;
      s.order_true.at<int32_t>(y, x) = k;
      s.phi.at<float>(y, x) = phi;
      s.modulation.at<float>(y, x) = b;
      s.valid.at<uint8_t>(y, x) = lit;
      s.marker.at<uint8_t>(y, x) = mk;
    }
  }
  return s;
}

cv::Mat PlaneDepth(const SyntheticProbe& probe, double z0, double gx, double gy) {
  cv::Mat d(probe.height, probe.width, CV_32FC1);
  const double cx = 0.5 * (probe.width - 1), cy = 0.5 * (probe.height - 1);
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) {
      d.at<float>(y, x) = static_cast<float>(z0 + gx * (x - cx) + gy * (y - cy));
    }
  }
  return d;
}

cv::Mat SphereDepth(const SyntheticProbe& probe, double px, double py, double r_mm, double z_apex) {
  cv::Mat d(probe.height, probe.width, CV_32FC1, cv::Scalar(kNoValue));
  const double mm_per_px = z_apex / probe.fc;
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) {
      const double dx = (x - px) * mm_per_px, dy = (y - py) * mm_per_px;
      const double rr = dx * dx + dy * dy;
      if (rr < r_mm * r_mm)
        d.at<float>(y, x) = static_cast<float>(z_apex + r_mm - std::sqrt(r_mm * r_mm - rr));
    }
  }
  return d;
}

cv::Mat TeethDepth(const SyntheticProbe& probe, int count, double gap_px, uint64_t seed) {
  CV_Assert(count >= 1);
  const int w = probe.width, h = probe.height;
  cv::Mat d(h, w, CV_32FC1, cv::Scalar(kNoValue));
  cv::RNG rng(seed);
  const double pitch = (w - gap_px) / count;
  const double base[] = {49.0, 52.5, 47.5, 51.0, 53.5, 48.5};
  for (int t = 0; t < count; ++t) {
    double cx = gap_px + pitch * (t + 0.5) - 0.5 * gap_px;
    double rx = 0.5 * (pitch - gap_px);
    const double cy = 0.5 * h + rng.uniform(-0.08, 0.08) * h;
    const double ry = 0.35 * h * rng.uniform(0.9, 1.1);
    double z0 = base[t % 6] + rng.uniform(-0.5, 0.5);
    double height = rng.uniform(2.0, 3.5);
    if (count >= 3 && t == count - 1) {
      // Overlaps its left neighbour and stands in front of it: an occlusion step, no gap.
      cx -= 0.25 * pitch;
      rx *= 1.1;
      z0 = base[(t - 1) % 6] - 1.9;
      height = std::min(height, z0 - 43.0);  // stays inside the 42–58 mm volume
    }
    // A fissure: a shallow groove across the crown.
    const double groove = rng.uniform(0.2, 0.5);
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const double u = (x - cx) / rx, v = (y - cy) / ry;
        const double rho2 = u * u + v * v;
        if (rho2 >= 1.0) continue;
        const double z =
            z0 - height * (1.0 - rho2) + groove * std::exp(-u * u * 40.0) * (1.0 - v * v);
        float& cur = d.at<float>(y, x);
        if (!std::isfinite(cur) || z < cur) cur = static_cast<float>(z);
      }
    }
  }
  return d;
}

}  // namespace d3d
