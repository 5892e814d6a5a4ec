#include "pipeline/register/pairwise.h"

#include <chrono>
#include <cmath>
#include <limits>

#include "common/core/status.h"

namespace d3d {

void PairwiseOptions::Check() const {
  features.Check();
  icp.Check();
  D3D_CHECK_MSG(max_gap_mm > 0 && source_stride >= 1, "PairwiseOptions: invalid value");
}

PairwiseResult RegisterPair(const cv::Mat& sp, const cv::Mat& st, const cv::Mat& tp, const cv::Mat& tt, const PairwiseOptions& o) {
  o.Check();
  PairwiseResult r;
  const auto t0 = std::chrono::steady_clock::now();
  const ViewFeatures fs = ExtractViewFeatures(sp, st, o.features), ft = ExtractViewFeatures(tp, tt, o.features);
  r.initial = AlignByFeatures(fs, ft, o.features);
  const auto t1 = std::chrono::steady_clock::now();
  r.ms_features = std::chrono::duration<double, std::milli>(t1 - t0).count();
  if (!r.initial.ok) {
    r.reason = r.initial.reason;
    return r;
  }
  const SurfacePoints source = SampleOrganised(sp, GridNormals(sp, o.max_gap_mm), cv::Mat(), o.source_stride);
  const KdTreeTarget target(SampleOrganised(tp, GridNormals(tp, o.max_gap_mm), cv::Mat(), 1));
  const auto t2 = std::chrono::steady_clock::now();
  r.refined = RegisterIcp(source, target, r.initial.target_from_source, o.icp);
  r.ms_icp = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t2).count();
  if (!r.refined.ok) {
    r.reason = "icp: " + r.refined.reason;
    return r;
  }
  r.ok = true;
  r.target_from_source = r.refined.target_from_source;
  return r;
}

}  // namespace d3d
