#include "calib/features/image_quality.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <vector>

#include "common/core/status.h"

namespace d3d {
namespace {

double Percentile(std::vector<float> v, double q) {
  if (v.empty()) return 0.0;
  const size_t k =
      std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size() - 1) + 0.5));
  std::nth_element(v.begin(), v.begin() + static_cast<long>(k), v.end());
  return v[k];
}

}  // namespace

void ImageQualityOptions::Check() const {
  D3D_CHECK_MSG(max_edge_blur_px > 0 && max_noise_dn > 0 && min_contrast_dn >= 0,
                "image quality thresholds must be positive");
}

ImageQuality AssessImage(const cv::Mat& gray, const ImageQualityOptions& options) {
  options.Check();
  D3D_CHECK_MSG(gray.type() == CV_8U || gray.type() == CV_16U,
                "AssessImage needs a CV_8U or CV_16U grey image");
  D3D_CHECK_MSG(gray.rows >= 16 && gray.cols >= 16, "image too small for a quality estimate");
  cv::Mat f;
  gray.convertTo(f, CV_32F, gray.type() == CV_16U ? 1.0 / 257.0 : 1.0);
  ImageQuality q;
  std::vector<float> values(f.begin<float>(), f.end<float>());
  q.contrast_dn = Percentile(values, 0.98) - Percentile(values, 0.02);

  cv::Mat gx, gy, mag;
  cv::Scharr(f, gx, CV_32F, 1, 0, 1.0 / 32.0);  // Scharr normalised to a unit-slope derivative
  cv::Scharr(f, gy, CV_32F, 0, 1, 1.0 / 32.0);
  cv::magnitude(gx, gy, mag);
  const cv::Rect inner(1, 1, f.cols - 2, f.rows - 2);
  cv::Mat mag_inner = mag(inner).clone();
  std::vector<float> grads(mag_inner.begin<float>(), mag_inner.end<float>());
  const double g_max = Percentile(grads, 0.997);
  q.edge_blur_px = g_max > 0 ? q.contrast_dn / (std::sqrt(2.0 * M_PI) * g_max) : 1e9;

  // Immerkær on low-gradient pixels.
  cv::Mat lap;
  const cv::Mat kernel = (cv::Mat_<float>(3, 3) << 1, -2, 1, -2, 4, -2, 1, -2, 1);
  cv::filter2D(f, lap, CV_32F, kernel, cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
  const double flat_limit = Percentile(grads, 0.6);
  double sum = 0;
  int64_t n = 0;
  for (int r = 1; r < f.rows - 1; ++r) {
    const float* l = lap.ptr<float>(r);
    const float* m = mag.ptr<float>(r);
    for (int c = 1; c < f.cols - 1; ++c) {
      if (m[c] > flat_limit) continue;
      sum += std::abs(l[c]);
      ++n;
    }
  }
  q.noise_dn = n > 0 ? std::sqrt(M_PI / 2.0) * sum / (6.0 * static_cast<double>(n)) : 0.0;

  std::ostringstream why;
  if (q.contrast_dn < options.min_contrast_dn) {
    why << "contrast " << q.contrast_dn << " DN < " << options.min_contrast_dn
        << " DN (under-exposed or no target)";
  } else if (q.edge_blur_px > options.max_edge_blur_px) {
    why << "blurred: edge blur " << q.edge_blur_px << " px > " << options.max_edge_blur_px << " px";
  } else if (q.noise_dn > options.max_noise_dn) {
    why << "noisy: noise " << q.noise_dn << " DN > " << options.max_noise_dn << " DN";
  }
  q.reason = why.str();
  q.accepted = q.reason.empty();
  return q;
}

}  // namespace d3d
