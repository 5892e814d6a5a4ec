#include "calib/features/synthetic_target.h"

#include <cmath>
#include <opencv2/imgproc.hpp>
#include <random>

#include "common/core/status.h"

namespace d3d {

void SyntheticImageOptions::Check() const {
  D3D_CHECK_MSG(supersample >= 1 && supersample <= 16, "supersample must be in [1, 16]");
  D3D_CHECK_MSG(blur_sigma_px >= 0 && noise_dn >= 0, "blur and noise must be ≥ 0");
}

double TargetAlbedo(const CalibrationTarget& t, double x, double y) {
  const double s = t.spacing_mm;
  if (t.kind == TargetKind::kChessboard) {
    const int i = static_cast<int>(std::floor(x / s)), j = static_cast<int>(std::floor(y / s));
    if (i < -1 || j < -1 || i > t.cols - 1 || j > t.rows - 1) return 1.0;
    return ((i + j) % 2 == 0) ? 0.0 : 1.0;
  }
  D3D_CHECK_MSG(t.circle_diameter_mm > 0, "rendering a circle grid needs its diameter");
  const double r2 = 0.25 * t.circle_diameter_mm * t.circle_diameter_mm;
  const int row = static_cast<int>(std::lround(y / s));
  for (int r = row - 1; r <= row + 1; ++r) {
    if (r < 0 || r >= t.rows) continue;
    const double shift = t.kind == TargetKind::kAsymmetricCircleGrid ? (r % 2) : 0.0;
    const double step = t.kind == TargetKind::kAsymmetricCircleGrid ? 2.0 : 1.0;
    const int col = static_cast<int>(std::lround((x / s - shift) / step));
    for (int c = col - 1; c <= col + 1; ++c) {
      if (c < 0 || c >= t.cols) continue;
      const double cx = (step * c + shift) * s, cy = r * s;
      if ((x - cx) * (x - cx) + (y - cy) * (y - cy) <= r2) return 0.0;
    }
  }
  return 1.0;
}

cv::Mat RenderSyntheticTarget(const CalibrationTarget& target, const PinholeBrownConrady& camera,
                              const Rigid3d& cam_from_target,
                              const SyntheticImageOptions& options) {
  target.Check();
  camera.Check();
  options.Check();
  const int n = options.supersample;
  const Rigid3d target_from_cam = cam_from_target.inverse();
  const Eigen::Vector3d o = target_from_cam.translation();
  const Eigen::Matrix3d R = target_from_cam.linear();
  cv::Mat f(camera.height, camera.width, CV_32F);
  for (int r = 0; r < camera.height; ++r)
    for (int c = 0; c < camera.width; ++c) {
      double sum = 0;
      for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
          const Eigen::Vector2d px(c - 0.5 + (j + 0.5) / n, r - 0.5 + (i + 0.5) / n);
          const auto ray = camera.PixelRay(px);
          double level = options.background_dn;
          if (ray) {
            const Eigen::Vector3d d = R * *ray;
            const double lambda = std::abs(d.z()) > 1e-12 ? -o.z() / d.z() : -1.0;
            if (lambda > 0) {
              const Eigen::Vector3d p = o + lambda * d;
              const double a = TargetAlbedo(target, p.x(), p.y());
              level = options.black_dn + a * (options.white_dn - options.black_dn);
            }
          }
          sum += level;
        }
      f.at<float>(r, c) = static_cast<float>(sum / (n * n));
    }
  if (options.blur_sigma_px > 0)
    cv::GaussianBlur(f, f, cv::Size(0, 0), options.blur_sigma_px, options.blur_sigma_px,
                     cv::BORDER_REFLECT);
  std::mt19937_64 rng(options.seed);
  std::normal_distribution<double> noise(0.0, options.noise_dn);
  cv::Mat out(f.size(), CV_8U);
  for (int r = 0; r < f.rows; ++r)
    for (int c = 0; c < f.cols; ++c) {
      const double v = f.at<float>(r, c) + (options.noise_dn > 0 ? noise(rng) : 0.0);
      out.at<uint8_t>(r, c) = static_cast<uint8_t>(std::clamp(std::lround(v), 0L, 255L));
    }
  return out;
}

}  // namespace d3d
