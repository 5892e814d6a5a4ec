#include "pipeline/register/segment_join.h"

#include <cmath>
#include <cstdio>

#include "common/core/status.h"

namespace d3d {
namespace {

// Samples thinned to one per sample_voxel_mm voxel, those without a normal dropped.
SurfacePoints MakeSegmentJoinSamples(const SurfacePoints& points,
                                     const SegmentJoinOptions& options) {
  const SurfacePoints thinned = VoxelDownsample(points, options.sample_voxel_mm);
  // VoxelDownsample leaves NaN normals where a voxel's normals cancel: drop those samples.
  SurfacePoints clean;
  for (size_t i = 0; i < thinned.size(); ++i)
    if (thinned.normals[i].allFinite()) {
      clean.points.push_back(thinned.points[i]);
      clean.normals.push_back(thinned.normals[i]);
    }
  return clean;
}

}  // namespace

FpfhOptions DentalFpfh() {
  FpfhOptions o;
  o.voxel_mm = 1.0;
  o.normal_radius_mm = 2.0;
  o.feature_radius_mm = 5.0;
  o.ransac = RansacOptions{.inlier_threshold_mm = 1.5,
                           .max_iterations = 50000,
                           .confidence = 0.999,
                           .min_inliers = 8,
                           .min_inlier_ratio = 0.02,
                           .min_sample_spread_mm = 4,
                           .min_inlier_spread_mm = 1.0,
                           .max_edge_ratio_error = 0.1,
                           .seed = 1};
  o.ambiguity_mm = 2.0;
  o.ambiguity_deg = 5.0;
  return o;
}

FpfhOptions FineDentalFpfh() {
  FpfhOptions o = DentalFpfh();
  o.voxel_mm = 0.5;
  o.normal_radius_mm = 1.0;
  o.feature_radius_mm = 3.0;
  return o;
}

IcpOptions SegmentJoinIcp() {
  IcpOptions o;
  o.levels = {{2, 15, 1.0, 0.7}, {1, 10, 0.3, 0.9}, {1, 8, 0.15, 1.0}};
  o.max_rmse_mm = 0.04;
  o.min_overlap = 0.02;
  return o;
}

void SegmentJoinOptions::Check() const {
  D3D_CHECK_MSG(sample_voxel_mm > 0, "SegmentJoinOptions: sample_voxel_mm must be > 0");
  D3D_CHECK_MSG(min_correspondences >= 1, "SegmentJoinOptions: min_correspondences must be >= 1");
  D3D_CHECK_MSG(min_contained_fraction >= 0 && min_contained_fraction <= 1 &&
                    min_contained_correspondences >= 1,
                "SegmentJoinOptions: min_contained_fraction in [0, 1] (0 = off), "
                "min_contained_correspondences >= 1");
  D3D_CHECK_MSG(min_eigen_ratio >= 0 && min_eigen_ratio < 1,
                "SegmentJoinOptions: min_eigen_ratio in [0, 1)");
  fpfh.Check();
  icp.Check();
}

SegmentJoinTarget MakeSegmentJoinTarget(const SurfacePoints& main,
                                        const SegmentJoinOptions& options) {
  options.Check();
  SegmentJoinTarget t;
  t.samples = MakeSegmentJoinSamples(main, options);
  if (!t.samples.empty()) t.features = ComputeFpfh(t.samples, options.fpfh);
  return t;
}

SegmentJoinResult JoinSegment(const SurfacePoints& segment, const SegmentJoinTarget& target,
                              const SegmentJoinOptions& options) {
  if (target.empty()) {  // before the segment's features are made
    SegmentJoinResult r;
    r.reason = "the main model is empty";
    return r;
  }
  return JoinSegment(MakeSegmentJoinTarget(segment, options), target, options);
}

SegmentJoinResult JoinSegment(const SegmentJoinTarget& segment, const SegmentJoinTarget& target,
                              const SegmentJoinOptions& options) {
  SegmentJoinResult r;
  if (target.empty() || segment.empty()) {
    r.reason = target.empty() ? "the main model is empty" : "the segment is empty";
    return r;
  }
  r.fpfh = AlignByFpfh(segment.features, target.features, options.fpfh);
  if (!r.fpfh.ok) {
    r.reason = r.fpfh.reason;
    return r;
  }
  SegmentJoinResult refined =
      RefineSegmentJoin(segment, target, r.fpfh.target_from_source, options);
  refined.fpfh = r.fpfh;
  if (!refined.ok) {
    // Where the consensus put the segment (main_from_segment's angle and translation): a refused
    // join that proposes the same pose again and again is one wrong consensus or a right pose the
    // verification does not hold; the truth tells which (docs/decisions/0011).
    const Rigid3d& T = r.fpfh.target_from_source;
    char at[96];
    std::snprintf(at, sizeof at, "after fpfh (%.1f deg, %.1f mm): ",
                  RotationAngleRad(T, Rigid3d::Identity()) * 180 / M_PI, T.translation().norm());
    refined.reason = at + refined.reason;
  }
  return refined;
}

SegmentJoinResult RefineSegmentJoin(const SegmentJoinTarget& segment,
                                    const SegmentJoinTarget& target,
                                    const Rigid3d& main_from_segment,
                                    const SegmentJoinOptions& options) {
  SegmentJoinResult r;
  if (target.empty() || segment.empty()) {
    r.reason = target.empty() ? "the main model is empty" : "the segment is empty";
    return r;
  }
  const SurfacePoints& source = segment.samples;
  r.icp = RegisterIcp(source, KdTreeTarget(target.samples), main_from_segment, options.icp);
  if (!r.icp.ok) {
    r.reason = "icp: " + r.icp.reason;
    return r;
  }
  const int on_main = r.icp.correspondences;
  const bool contained =
      options.min_contained_fraction > 0 && on_main >= options.min_contained_correspondences &&
      on_main >= options.min_contained_fraction * static_cast<double>(source.size());
  if (on_main < options.min_correspondences && !contained) {
    char need[160];
    std::snprintf(need, sizeof need,
                  "too little overlap (%d of %zu samples on the main model, need %d, or %.0f %% of "
                  "the segment and %d)",
                  on_main, source.size(), options.min_correspondences,
                  options.min_contained_fraction * 100, options.min_contained_correspondences);
    r.reason = need;
    return r;
  }
  if (r.icp.eigen_ratio < options.min_eigen_ratio) {
    r.reason = "degenerate overlap (eigen ratio " + std::to_string(r.icp.eigen_ratio) + ")";
    return r;
  }
  r.ok = true;
  r.main_from_segment = r.icp.target_from_source;
  return r;
}

}  // namespace d3d
