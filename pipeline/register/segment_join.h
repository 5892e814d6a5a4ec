// Joining two scan segments: the model of a segment that started in its own frame (the tracker
// could not place it on the scan: a lift, a loss over new ground) registered onto the main model
// once they overlap. Global registration, then verification:
//  1. FPFH on voxel keypoints of both models (fpfh.h: Rusu et al. 2009) → RANSAC rigid fit, whose
//     own checks refuse a degenerate geometry and a consensus that a second, disjoint one nearly
//     matches (the neighbouring, similar tooth; the other quadrant): such an ambiguity is settled
//     by the whole segment (settle_ambiguity) or refused;
//  2. ICP of the segment's samples onto the main model's (k-d tree association, gates 1.0 → 0.15
//     mm) from that pose: residual at most icp.max_rmse_mm, at least min_correspondences samples of
//     the segment on the main model (a segment grows over new ground, so a fraction would say
//     little; a small segment lying almost whole on it joins by min_contained_fraction), and well
//     constrained (eigen ratio at least min_eigen_ratio).
// The caller adds its own checks (the tracker: its keyframes' visibility, reentry_check.h).
// Units: mm. Transforms target_from_source: main_from_segment.
#pragma once

#include <string>

#include "common/core/rigid.h"
#include "pipeline/register/fpfh.h"
#include "pipeline/register/icp.h"
#include "pipeline/register/surface_points.h"

namespace d3d {

// FPFH at the scale of teeth: 1 mm keypoints, 2 mm normals, 5 mm features; RANSAC inliers within
// 1.5 mm, samples spread ≥ 4 mm, at least 8 inliers (a consensus is a proposal: the ICP of step 2
// decides; docs/decisions/0005); a verified rival consensus 2 mm or 5° away at 0.6 × the inliers
// makes it ambiguous; the verification's conditioning judged on the keypoints that meet.
FpfhOptions DentalFpfh();
// The same at half the scale: 0.5 mm keypoints, 1 mm normals, 3 mm features (four times the
// keypoints). Ground seen from directions no main view had (a lingual pass resumed as a segment
// after a loss at the turn) shares too few 1 mm keypoints' descriptors with the model; the finer
// ones describe the cusps and fissures themselves (docs/decisions/0022).
FpfhOptions FineDentalFpfh();
// Levels 1.0 → 0.3 → 0.15 mm, residual ≤ 0.04 mm, overlap floor 0.02 (min_correspondences decides),
// the conditioning judged on the overlap (conditioning_on_overlap).
IcpOptions SegmentJoinIcp();

struct SegmentJoinOptions {
  // Samples are first thinned to one per voxel of this edge (mm) for the ICP.
  double sample_voxel_mm = 0.3;
  FpfhOptions fpfh = DentalFpfh();
  IcpOptions icp = SegmentJoinIcp();
  int min_correspondences =
      1500;  // of the segment's thinned samples (~135 mm² at 0.3 mm: a molar's crown)
  // A segment that lies almost whole on the main model (a few views over ground scanned before,
  // cut off by a loss at a pass's turn) has fewer samples than min_correspondences in all: it
  // joins when at least this share of its samples, and min_contained_correspondences of them
  // (~45 mm² at 0.3 mm: about one view's field), lie on the main model. 0 = off.
  double min_contained_fraction = 0.8;
  int min_contained_correspondences = 500;
  // The ICP's eigenvalue ratio, judged on the segment's samples that meet the main model
  // (SegmentJoinIcp: IcpOptions::conditioning_on_overlap), not on its whole length: a quadrant
  // that meets the model at its incisors is as well held there as their surface allows.
  double min_eigen_ratio = 0.005;
  // FPFH's ambiguity (two verified consensuses elsewhere: the left and right quadrants of an arch
  // look alike) settled by the whole segment: both poses refined as above; the join is the one that
  // holds when the other does not. When both hold, the one whose samples contradict the main model
  // (a sample whose nearest main sample lies within conflict_radius_mm, off its surface along the
  // normal by more than conflict_depth_mm and beside it within that: a surface where the main
  // views saw another) at most max_conflict_share as often as the other, which has at least
  // min_conflicts (~18 mm² at 0.3 mm). Otherwise, or with false: refused as ambiguous.
  bool settle_ambiguity = true;
  double conflict_radius_mm = 2.0;
  double conflict_depth_mm = 0.5;
  int min_conflicts = 200;
  double max_conflict_share = 0.25;
  void Check() const;  // throws std::invalid_argument
};

struct SegmentJoinResult {
  bool ok = false;
  std::string reason;  // why not; for a settled ambiguity, how
  Rigid3d main_from_segment = Rigid3d::Identity();
  bool settled = false;  // FPFH was ambiguous and the whole segment settled it (settle_ambiguity)
  FpfhAlignResult fpfh;
  IcpResult icp;
};

// The main model's FPFH keypoints, kept by a caller that joins several times against one model.
struct SegmentJoinTarget {
  SurfacePoints samples;  // thinned (sample_voxel_mm), world
  FpfhFeatures features;
  bool empty() const { return samples.empty(); }
};
// main: the main model's samples (world, normals required). The same preparation (thinned
// samples and their FPFH features) serves a segment that is joined more than one way.
SegmentJoinTarget MakeSegmentJoinTarget(const SurfacePoints& main,
                                        const SegmentJoinOptions& options);

// Registers `segment` (its samples in its own frame, normals required) onto the target.
SegmentJoinResult JoinSegment(const SurfacePoints& segment, const SegmentJoinTarget& target,
                              const SegmentJoinOptions& options);
// The same for a segment already prepared by MakeSegmentJoinTarget.
SegmentJoinResult JoinSegment(const SegmentJoinTarget& segment, const SegmentJoinTarget& target,
                              const SegmentJoinOptions& options);

// Step 2 alone, from a pose found elsewhere (the tracker's keyframe features): ICP of the prepared
// segment's samples onto the target from main_from_segment, and the same checks.
SegmentJoinResult RefineSegmentJoin(const SegmentJoinTarget& segment,
                                    const SegmentJoinTarget& target,
                                    const Rigid3d& main_from_segment,
                                    const SegmentJoinOptions& options);

}  // namespace d3d
