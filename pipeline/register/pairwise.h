// Pairwise registration of two organised views from an unknown relative pose: features (SIFT on
// texture and range images → RANSAC rigid, features.h) for the initial alignment, then ICP
// (icp.h, k-d tree association) for the refinement. Used for range scans (Stanford bunny) and by
// the benchmark.
#pragma once

#include <opencv2/core.hpp>
#include <string>

#include "pipeline/register/features.h"
#include "pipeline/register/icp.h"

namespace d3d {

struct PairwiseOptions {
  FeatureOptions features;
  IcpOptions icp;
  double max_gap_mm = 2.0;   // GridNormals
  int source_stride = 1;     // ICP source: every k-th grid sample
  void Check() const;
};

struct PairwiseResult {
  bool ok = false;
  std::string reason;
  Rigid3d target_from_source = Rigid3d::Identity();
  FeatureAlignResult initial;
  IcpResult refined;
  double ms_features = 0, ms_icp = 0;
};

PairwiseResult RegisterPair(const cv::Mat& source_points, const cv::Mat& source_texture, const cv::Mat& target_points,
                            const cv::Mat& target_texture, const PairwiseOptions& options);

}  // namespace d3d
