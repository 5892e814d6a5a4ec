#include "sim/render/projector_radiance.h"

#include <cmath>
#include <opencv2/imgproc.hpp>

#include "common/core/status.h"

namespace d3d {

ProjectorRadiance::ProjectorRadiance(const ProjectorFrame& frame, double gamma, int axis_length)
    : axis_(frame.axis),
      pad_(static_cast<int>(std::ceil(3.0 * kSigmaMin * std::pow(2.0, 0.5 * (kLevels - 1)))) *
           kSamplesPerPixel),
      length_(axis_length * kSamplesPerPixel + 2 * pad_) {
  D3D_CHECK_MSG(gamma > 0, "projector gamma must be positive");
  D3D_CHECK_MSG(static_cast<int>(frame.dmd.size()) == axis_length,
                "frame '" << frame.name << "' has " << frame.dmd.size()
                          << " DMD values, projector axis has " << axis_length);
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
    cv::GaussianBlur(base, blurred, cv::Size(2 * half + 1, 1), sigma_samples, 0,
                     cv::BORDER_CONSTANT);
    std::copy(blurred.ptr<float>(0), blurred.ptr<float>(0) + length_,
              levels_.begin() + static_cast<long>(k) * length_);
  }
}

}  // namespace d3d
