// Rigid alignment of 3-D correspondences: weighted least squares (Kabsch / Umeyama without scale)
// and RANSAC around it. Units: mm. Transforms are target_from_source.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "common/core/rigid.h"

namespace d3d {

// One 3-D correspondence: the same surface point seen in the source and in the target frame (mm).
struct Correspondence3d {
  Eigen::Vector3d source = Eigen::Vector3d::Zero();
  Eigen::Vector3d target = Eigen::Vector3d::Zero();
  double weight = 1.0;  // ≥ 0
};

// The rigid transform minimising Σ wᵢ ‖R sᵢ + t − tᵢ‖² (Umeyama 1991, "Least-squares estimation of
// transformation parameters between two point patterns", IEEE PAMI 13(4), eqs. 34–43 with c = 1;
// Kabsch 1976): SVD of the weighted cross-covariance, with the reflection fix. nullopt when fewer
// than 3 correspondences carry weight, or when the source points are (near) collinear (second
// singular value of the weighted scatter < min_spread_mm² · total weight): the rotation about
// that line is then undetermined.
std::optional<Rigid3d> FitRigid(const std::vector<Correspondence3d>& correspondences,
                                double min_spread_mm = 1e-3);

struct RansacOptions {
  double inlier_threshold_mm = 0.1;  // ‖R s + t − t‖ below this is an inlier
  int max_iterations = 2000;         // hypotheses drawn at most
  double confidence = 0.999;       // stop when an all-inlier sample was drawn with this probability
  int min_inliers = 12;            // fewer inliers: failure ("too few inliers")
  double min_inlier_ratio = 0.05;  // of all correspondences; fewer: failure
  double min_sample_spread_mm =
      0.5;  // a sample whose triangle has a side or height below this is skipped
  // Inlier set must span a plane: its second principal standard deviation (mm) at least this, else
  // failure ("degenerate inlier set": all on a line, the rotation about it is unknown).
  double min_inlier_spread_mm = 0.3;
  // Edge-length consistency pre-test (Buch et al. 2013 style): a sample is drawn again when two of
  // its source edges differ from the target edges by more than this fraction.
  double max_edge_ratio_error = 0.1;
  uint32_t seed = 1;   // random generator seed (results are deterministic)
  void Check() const;  // throws std::invalid_argument
};

struct RansacResult {
  bool ok = false;
  std::string reason;  // why not ok (empty when ok)
  Rigid3d target_from_source = Rigid3d::Identity();
  std::vector<int> inliers;   // indices into the correspondences
  double inlier_rmse_mm = 0;  // residual of the refit on the inliers
  int iterations = 0;
};

// RANSAC (Fischler & Bolles 1981) over minimal samples of 3 correspondences, each hypothesis fitted
// with FitRigid (a rigid transform, unlike cv::estimateAffine3D's affine), the best consensus refit
// on all its inliers (twice, re-collecting inliers). Expected failures come back in `reason`.
RansacResult RansacRigid(const std::vector<Correspondence3d>& correspondences,
                         const RansacOptions& options = {});

}  // namespace d3d
