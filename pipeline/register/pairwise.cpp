#include "pipeline/register/pairwise.h"

#include <chrono>
#include <cmath>
#include <limits>
#include <memory>

#include "common/core/status.h"

namespace d3d {

const char* ToString(InitialAlignment a) {
  switch (a) {
    case InitialAlignment::kSift:
      return "sift";
    case InitialAlignment::kFpfh:
      return "fpfh";
    case InitialAlignment::kSiftThenFpfh:
      return "sift-then-fpfh";
  }
  return "?";
}

void PairwiseOptions::Check() const {
  features.Check();
  fpfh.Check();
  icp.Check();
  D3D_CHECK_MSG(max_gap_mm > 0 && source_stride >= 1, "PairwiseOptions: invalid value");
}

PairwiseOptions RangeScanPairwiseOptions(InitialAlignment initial) {
  PairwiseOptions o;
  o.initial = initial;
  o.features.ransac.inlier_threshold_mm = 1.5;
  o.features.max_gap_mm = 2.0;  // grid spacing 0.5 mm
  o.features.max_features = 4000;
  o.features.contrast_threshold = 0.01;
  o.features.ratio = 0.85;
  o.features.mutual = false;
  o.features.ransac.min_inliers = 8;
  o.features.ransac.min_sample_spread_mm = 5;
  o.features.ransac.max_iterations = 20000;
  o.icp.levels = {{4, 30, 5.0, 0.7}, {2, 30, 2.0, 0.9}, {1, 30, 1.0, 1.0}};
  // bun180 (the back) sees a quarter of bun090 / bun270 within the 1 mm gate: 0.26 associated.
  o.icp.min_overlap = 0.2;
  o.icp.max_rmse_mm = 0.5;
  o.icp.min_sigma_mm = 0.05;
  return o;
}

namespace {
double MsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}
}  // namespace

PairwiseResult RegisterPair(const cv::Mat& sp, const cv::Mat& st, const cv::Mat& tp,
                            const cv::Mat& tt, const PairwiseOptions& o) {
  o.Check();
  PairwiseResult r;
  const SurfacePoints source =
      SampleOrganised(sp, GridNormals(sp, o.max_gap_mm), cv::Mat(), o.source_stride);
  SurfacePoints target_samples = SampleOrganised(tp, GridNormals(tp, o.max_gap_mm), cv::Mat(), 1);
  // Initial alignment by `method`, then ICP from its pose; false (and r.reason) when either fails.
  std::unique_ptr<KdTreeTarget> target;
  const auto attempt = [&](InitialAlignment method) {
    r.initial_method = method;
    auto t0 = std::chrono::steady_clock::now();
    if (method == InitialAlignment::kFpfh) {
      r.fpfh =
          AlignByFpfh(ComputeFpfh(source, o.fpfh), ComputeFpfh(target_samples, o.fpfh), o.fpfh);
      r.initial = r.fpfh;
    } else {
      const ViewFeatures fs = ExtractViewFeatures(sp, st, o.features),
                         ft = ExtractViewFeatures(tp, tt, o.features);
      r.initial = AlignByFeatures(fs, ft, o.features);
    }
    r.ms_features += MsSince(t0);
    if (!r.initial.ok) {
      r.reason = r.initial.reason;
      return false;
    }
    t0 = std::chrono::steady_clock::now();
    if (!target) target = std::make_unique<KdTreeTarget>(target_samples);
    r.refined = RegisterIcp(source, *target, r.initial.target_from_source, o.icp);
    r.ms_icp += MsSince(t0);
    if (!r.refined.ok) {
      r.reason = "icp: " + r.refined.reason;
      return false;
    }
    return true;
  };
  bool ok = false;
  switch (o.initial) {
    case InitialAlignment::kSift:
      ok = attempt(InitialAlignment::kSift);
      break;
    case InitialAlignment::kFpfh:
      ok = attempt(InitialAlignment::kFpfh);
      break;
    case InitialAlignment::kSiftThenFpfh:
      ok = attempt(InitialAlignment::kSift);
      if (!ok) {
        r.sift_reason = r.reason;
        ok = attempt(InitialAlignment::kFpfh);
      }
      break;
  }
  if (!ok) return r;
  r.reason.clear();
  r.ok = true;
  r.target_from_source = r.refined.target_from_source;
  return r;
}

}  // namespace d3d
