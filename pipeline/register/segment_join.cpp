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

// Samples of the segment at main_from_segment that contradict the main model: its nearest sample
// lies within conflict_radius_mm, and the segment's sample is off that surface along its normal by
// more than conflict_depth_mm while beside it within conflict_depth_mm (a surface where the main
// views saw another one, in front of or behind it).
int CountConflicts(const SurfacePoints& segment, const KdTreeTarget& main,
                   const Rigid3d& main_from_segment, const SegmentJoinOptions& o) {
  const Eigen::Matrix3f R = main_from_segment.linear().cast<float>();
  const Eigen::Vector3f t = main_from_segment.translation().cast<float>();
  const float depth = static_cast<float>(o.conflict_depth_mm);
  int conflicts = 0;
  for (const Eigen::Vector3f& p : segment.points) {
    const Eigen::Vector3f q = R * p + t;
    Eigen::Vector3f m, n;
    if (!main.Find(q, static_cast<float>(o.conflict_radius_mm), &m, &n)) continue;
    const Eigen::Vector3f d = q - m;
    const float along = n.dot(d);
    conflicts += std::abs(along) > depth && (d - along * n).norm() < depth;
  }
  return conflicts;
}

// An FPFH ambiguity (fpfh: two verified consensuses elsewhere) settled by the whole segment: each
// pose refined by RefineSegmentJoin; one that holds where the other does not is the join; when
// both hold, the one whose samples contradict the main model (CountConflicts) at most
// max_conflict_share as often as the other's, which must have min_conflicts.
SegmentJoinResult SettleAmbiguity(const SegmentJoinTarget& segment, const SegmentJoinTarget& target,
                                  const FpfhAlignResult& fpfh, const SegmentJoinOptions& options) {
  SegmentJoinResult a = RefineSegmentJoin(segment, target, fpfh.target_from_source, options);
  SegmentJoinResult b = RefineSegmentJoin(segment, target, fpfh.rival_target_from_source, options);
  const auto why = [](const SegmentJoinResult& j) {
    return j.ok ? std::to_string(j.icp.correspondences) + " samples, rmse " +
                      std::to_string(static_cast<int>(std::lround(j.icp.rmse_mm * 1000))) + " um"
                : j.reason;
  };
  // Both refined onto one pose (the segment's centroid within ambiguity_mm, its turn within
  // ambiguity_deg): the rival was the winner reached from elsewhere.
  const Eigen::Vector3d c = segment.samples.Centroid();
  const bool same =
      a.ok && b.ok &&
      (a.main_from_segment * c - b.main_from_segment * c).norm() <= options.fpfh.ambiguity_mm &&
      RotationAngleRad(a.main_from_segment, b.main_from_segment) * 180 / M_PI <=
          options.fpfh.ambiguity_deg;
  bool take_a = a.ok && (!b.ok || same), take_b = b.ok && !a.ok;
  std::string both = "the consensus: " + why(a) + "; the rival: " + why(b);
  if (a.ok && b.ok && !same) {
    const KdTreeTarget main(target.samples);
    const int ca = CountConflicts(segment.samples, main, a.main_from_segment, options);
    const int cb = CountConflicts(segment.samples, main, b.main_from_segment, options);
    const auto clear = [&](int winner, int loser) {
      return loser >= options.min_conflicts && winner <= options.max_conflict_share * loser;
    };
    take_a = clear(ca, cb);
    take_b = clear(cb, ca);
    both +=
        "; samples off the model's surface: " + std::to_string(ca) + " and " + std::to_string(cb);
  }
  SegmentJoinResult r = take_b ? b : a;
  r.fpfh = fpfh;
  if (!take_a && !take_b) {
    r.ok = false;
    r.reason = fpfh.reason + (a.ok && b.ok ? "; the segment holds both (" : "; neither holds (") +
               both + ")";
    return r;
  }
  r.settled = true;
  r.reason = fpfh.reason + "; settled by the whole segment (" + both + ")";
  return r;
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
  o.verify_conditioning_on_overlap = true;  // a segment is larger than where it meets the model
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
  o.conditioning_on_overlap = true;
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
  D3D_CHECK_MSG(conflict_radius_mm > conflict_depth_mm && conflict_depth_mm > 0 &&
                    min_conflicts >= 1 && max_conflict_share >= 0 && max_conflict_share < 1,
                "SegmentJoinOptions: conflict_radius_mm > conflict_depth_mm > 0, min_conflicts >= "
                "1, max_conflict_share in [0, 1)");
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
  if (!r.fpfh.ok && r.fpfh.rival_verified && options.settle_ambiguity)
    return SettleAmbiguity(segment, target, r.fpfh, options);
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
