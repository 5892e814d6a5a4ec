// Covariance and conditioning of a least-squares problem at its solution, for the calibration
// steps: J (tangent space) from Ceres, Jacobi column scaling D (unit column norms), then
// C = σ² D⁻¹ (DᵀJᵀJD ... scaled normal matrix)⁻¹ D⁻¹ with σ² = Σr² / (m − n). The reciprocal
// condition number is that of the scaled normal matrix (eigenvalue ratio), so parameters in px, mm,
// rad and distortion coefficients are comparable.
#pragma once

#include <ceres/problem.h>

#include <vector>

namespace d3d {

struct ConditioningReport {
  bool ok = false;  // false: rank-deficient (reciprocal condition < min_reciprocal_condition)
  double reciprocal_condition = 0;
  double residual_sigma = 0;  // σ, units of the residuals
  std::vector<double> sigma;  // standard deviation of each tangent-space parameter, block order
};

// `blocks`: the parameter blocks in the order wanted (all must be in the problem; constant blocks
// are skipped). residual_count: total number of residuals.
ConditioningReport ComputeCovariance(ceres::Problem* problem, const std::vector<double*>& blocks,
                                     int residual_count, double min_reciprocal_condition = 1e-12);

}  // namespace d3d
