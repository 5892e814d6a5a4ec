#include "firmware/sim/render/projector_radiance.h"

#include <cmath>
#include <opencv2/imgproc.hpp>

#include "common/core/status.h"

namespace d3d {

ProjectorRadiance::ProjectorRadiance(const ProjectorFrame& frame, double gamma, int axis_length)
    : axis_(frame.axis),
      pad_(static_cast<int>(std::ceil(3.0 * kSigmaMin * std::pow(2.0, 0.5 * (kLevels - 1)))) * kSamplesPerPixel),
      length_(axis_length * kSamplesPerPixel + 2 * pad_) {
  D3D_CHECK_MSG(gamma > 0, "projector gamma must be positive");
  D3D_CHECK_MSG(static_cast<int>(frame.dmd.size()) == axis_length,
                "frame '" << frame.name << "' has " << frame.dmd.size() << " DMD values, projector axis has " << axis_length);
  cv::Mat base(1, length_, CV_32F, cv::Scalar(0));
  for (int i = 0; i < axis_length * kSamplesPerPixel; ++i) {
    const double dmd = frame.dmd[static_cast<size_t>(i / kSamplesPerPixel)] / 255.0;
    base.at<float>(0, pad_ + i) = static_cast<float>(std::pow(dmd, gamma));
  }
  levels_.resize(static_cast<size_t>(kLevels) * static_cast<size_t>(length_));
  for (int k = 0; k < kLevels; ++k) {
    const double sigma_samples = kSigmaMin * std::pow(2.0, 0.5 * k) * kSamplesPerPixel;
    cv::Mat blurred;
    const int half = static_cast<int>(std::ceil(4.0 * sigma_samples));
    cv::GaussianBlur(base, blurred, cv::Size(2 * half + 1, 1), sigma_samples, 0, cv::BORDER_CONSTANT);
    std::copy(blurred.ptr<float>(0), blurred.ptr<float>(0) + length_, levels_.begin() + static_cast<long>(k) * length_);
  }
}

float ProjectorRadiance::SampleLevel(int level, float index) const {
  const float* row = levels_.data() + static_cast<size_t>(level) * static_cast<size_t>(length_);
  if (!(index >= 0.0f) || index >= static_cast<float>(length_ - 1)) return 0.0f;  // far outside: dark
  const int i = static_cast<int>(index);
  const float f = index - static_cast<float>(i);
  return row[i] + f * (row[i + 1] - row[i]);
}

float ProjectorRadiance::Sample(float coord_px, float sigma_px) const {
  // Sample j sits at coordinate (j + ½)/s − ½ for s samples per pixel.
  const float index = (coord_px + 0.5f) * kSamplesPerPixel - 0.5f + static_cast<float>(pad_);
  const float s = std::max(sigma_px, kSigmaMin);
  float level = 2.0f * std::log2(s / kSigmaMin);
  level = std::min(level, static_cast<float>(kLevels - 1));
  const int l0 = static_cast<int>(level);
  const int l1 = std::min(l0 + 1, kLevels - 1);
  const float w = level - static_cast<float>(l0);
  const float a = SampleLevel(l0, index);
  return w > 0.0f ? a + w * (SampleLevel(l1, index) - a) : a;
}

}  // namespace d3d
