// Test helpers for packed frames: seeded random frames and a bit-for-bit comparison.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

namespace d3d::pack_testing {

// n random frames of rows × cols and `type` (CV_8UC1: 0..255, else 0..65535), from cv::RNG(seed).
inline std::vector<cv::Mat> RandomFrames(int n, int rows, int cols, int type, uint32_t seed) {
  cv::RNG rng(seed);
  std::vector<cv::Mat> frames(static_cast<size_t>(n));
  for (cv::Mat& f : frames) {
    f.create(rows, cols, type);
    rng.fill(f, cv::RNG::UNIFORM, 0, type == CV_8UC1 ? 256 : 65536);
  }
  return frames;
}

// Same count, sizes, types and pixels.
inline bool Same(const std::vector<cv::Mat>& a, const std::vector<cv::Mat>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    if (a[i].size() != b[i].size() || a[i].type() != b[i].type() ||
        cv::norm(a[i], b[i], cv::NORM_INF) != 0)
      return false;
  return true;
}

}  // namespace d3d::pack_testing
