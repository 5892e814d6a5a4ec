// Initial alignment by 3-D local descriptors, for views whose 2-D images give no feature consensus
// (range scans from widely different viewpoints): Fast Point Feature Histograms (Rusu, Blodow &
// Beetz, "Fast Point Feature Histograms (FPFH) for 3D registration", ICRA 2009) on voxel keypoints,
// correspondences by nearest descriptor (mutual and/or Lowe's ratio), RANSAC rigid fit
// (rigid_fit.h: Umeyama per 3-sample with the edge-length pre-test), then a check of the
// hypothesis: a short point-to-plane ICP on the keypoints (icp.h) must find overlap and a
// well-conditioned geometry, and no second, disjoint consensus of a different pose may be nearly as
// large (symmetric scenes). Units: mm, rad. Transforms are target_from_source.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "common/core/rigid.h"
#include "pipeline/register/features.h"
#include "pipeline/register/rigid_fit.h"
#include "pipeline/register/surface_points.h"

namespace d3d {

constexpr int kFpfhBins = 11;             // per angular feature (α, φ, θ), as in the paper
constexpr int kFpfhSize = 3 * kFpfhBins;  // 33
using FpfhDescriptor =
    Eigen::Matrix<float, kFpfhSize, 1>;  // [α bins | φ bins | θ bins], each block sums to 100

struct FpfhOptions {
  // Keypoints: the centroid of the samples in each occupied cubic voxel of this edge (mm). 2.5 mm
  // gives ~2–3k keypoints on a Stanford bunny scan (0.5 mm grid).
  double voxel_mm = 2.5;
  // Keypoint normals: PCA of the keypoints within this radius (mm), oriented like the mean input
  // normal of the voxel; 0 keeps the mean input normal. Default 2 voxels.
  double normal_radius_mm = 5.0;
  // SPFH / FPFH neighbourhood radius (mm). Default 5 voxels (Open3D's and FGR's practice).
  double feature_radius_mm = 12.5;
  int max_neighbours = 100;  // nearest kept when more lie within feature_radius_mm
  int min_neighbours = 8;    // a keypoint with fewer gets no descriptor (dropped)
  // Correspondences: each source descriptor's nearest target descriptor (L2); mutual keeps it only
  // when the source descriptor is also the target's nearest; ratio < 1 applies Lowe's test
  // (nearest / second nearest distance).
  bool mutual = true;
  double ratio = 1.0;
  // RANSAC (rigid_fit.h). Defaults for 2.5 mm voxels: 1.5 voxels inlier threshold, triangles of
  // ≥ 4 voxels, edge lengths consistent within 10 %.
  RansacOptions ransac = DefaultRansac();
  // Verification of the RANSAC pose by point-to-plane ICP on the keypoints (gate and accepted RMS:
  // ransac.inlier_threshold_mm): fraction of source keypoints associated at least min_overlap, and
  // the eigenvalue ratio of the Hessian (IcpOptions::min_eigen_ratio) at least min_eigen_ratio
  // (planes, spheres, surfaces of revolution fail it).
  int verify_iterations = 15;
  double min_overlap = 0.1;
  double min_eigen_ratio = 2e-3;
  // The verification's degeneracy judged on the associated keypoints alone
  // (IcpOptions::conditioning_on_overlap): for a source much larger than its overlap.
  bool verify_conditioning_on_overlap = false;
  // Ambiguity: RANSAC is run again on the correspondences outside the winner's inliers; a second
  // consensus with ≥ ambiguity_ratio × the winner's inliers whose pose differs by more than
  // ambiguity_deg or ambiguity_mm, and that the verification below holds as well, fails the
  // alignment ("ambiguous": a symmetric scene). 0 disables.
  double ambiguity_ratio = 0.6;
  double ambiguity_deg = 5.0;
  double ambiguity_mm = 5.0;
  void Check() const;  // throws std::invalid_argument

  static RansacOptions DefaultRansac();
};

// Keypoints of one view with their normals and descriptors (same length), in that view's frame.
struct FpfhFeatures {
  std::vector<Eigen::Vector3f> points;   // mm
  std::vector<Eigen::Vector3f> normals;  // unit
  std::vector<FpfhDescriptor> descriptors;
  size_t size() const { return points.size(); }
};

// The centroid of the samples in each occupied voxel (edge voxel_mm > 0, cells aligned to the
// origin) and the normalised sum of their normals (when `in` has normals; a voxel whose sum
// vanishes gets a NaN normal). Weights are dropped. Order: by first sample of each voxel.
SurfacePoints VoxelDownsample(const SurfacePoints& in, double voxel_mm);

// The Darboux-frame pair feature of Rusu et al. 2009, §III (from PFH, Rusu et al. IROS 2008): the
// source s of the pair is the point whose normal makes the smaller angle with the line joining
// them; with d = (p_t − p_s)/‖p_t − p_s‖: u = n_s, v = u × d, w = u × v and
//   α = v · n_t,  φ = u · d,  θ = atan2(w · n_t, u · n_t).
// Returns (α, φ, θ); α, φ ∈ [−1, 1], θ ∈ [−π, π]. Zeros when the points coincide or d ∥ n_s.
Eigen::Vector3f DarbouxPairFeature(const Eigen::Vector3f& p1, const Eigen::Vector3f& n1,
                                   const Eigen::Vector3f& p2, const Eigen::Vector3f& n2);

// FPFH of the voxel keypoints of `surface` (points mm; normals required, unit, used for the
// orientation of the keypoint normals). SPFH(p): 11-bin histograms of α, φ, θ over p's neighbours
// within feature_radius_mm, each normalised to sum 100; FPFH(p) = SPFH(p) + (1/k) Σ_k SPFH(p_k) /
// ω_k with ω_k = ‖p − p_k‖ in mm (paper eq. 3), each 11-bin block normalised again to sum 100.
// Keypoints without a valid normal or with fewer than min_neighbours neighbours are dropped.
// Throws std::invalid_argument when the options are invalid or normals are missing.
FpfhFeatures ComputeFpfh(const SurfacePoints& surface, const FpfhOptions& options = {});

struct FpfhAlignResult : FeatureAlignResult {  // matches: correspondences offered to RANSAC
  int source_keypoints = 0, target_keypoints = 0;
  double overlap = 0;                  // verification ICP: associated fraction of source keypoints
  double eigen_ratio = 0;              // verification ICP: Hessian conditioning
  int rival_inliers = 0;               // the second, disjoint consensus (0: none)
  double rival_deg = 0, rival_mm = 0;  // its pose difference to the winner
  bool rival_verified =
      false;  // it passed the verification too, elsewhere (and so refused the alignment)
  // When rival_verified: the rival's pose after the verification ICP, so that a caller with more
  // evidence than the keypoints (a whole segment, its views' free space) may settle between the
  // two (target_from_source then holds the winner's).
  Rigid3d rival_target_from_source = Rigid3d::Identity();
};

// Correspondences by descriptor, RANSAC, verification (see FpfhOptions). target_from_source is the
// verification ICP's pose on the keypoints (accuracy about a tenth of the voxel). Expected failures
// (too few keypoints or correspondences, no consensus, low overlap, degenerate geometry, ambiguous)
// come back with ok = false and a reason starting with "fpfh: ". Deterministic (ransac.seed).
FpfhAlignResult AlignByFpfh(const FpfhFeatures& source, const FpfhFeatures& target,
                            const FpfhOptions& options = {});

}  // namespace d3d
