#include "calib/camera/conditioning.h"

#include <ceres/crs_matrix.h>

#include <Eigen/Dense>
#include <cmath>

namespace d3d {

ConditioningReport ComputeCovariance(ceres::Problem* problem, const std::vector<double*>& blocks,
                                     int residual_count, double min_reciprocal_condition) {
  ConditioningReport rep;
  std::vector<double*> variable;
  for (double* b : blocks)
    if (!problem->IsParameterBlockConstant(b)) variable.push_back(b);
  ceres::Problem::EvaluateOptions eo;
  eo.parameter_blocks = variable;
  eo.num_threads = 1;
  double cost = 0;
  ceres::CRSMatrix crs;
  if (!problem->Evaluate(eo, &cost, nullptr, nullptr, &crs)) return rep;
  const int m = crs.num_rows, n = crs.num_cols;
  Eigen::MatrixXd JtJ = Eigen::MatrixXd::Zero(n, n);
  for (int r = 0; r < m; ++r) {
    for (int a = crs.rows[static_cast<size_t>(r)]; a < crs.rows[static_cast<size_t>(r) + 1]; ++a)
      for (int b = crs.rows[static_cast<size_t>(r)]; b < crs.rows[static_cast<size_t>(r) + 1]; ++b)
        JtJ(crs.cols[static_cast<size_t>(a)], crs.cols[static_cast<size_t>(b)]) +=
            crs.values[static_cast<size_t>(a)] * crs.values[static_cast<size_t>(b)];
  }
  Eigen::VectorXd d(n);
  for (int i = 0; i < n; ++i) d[i] = JtJ(i, i) > 0 ? 1.0 / std::sqrt(JtJ(i, i)) : 0.0;
  const Eigen::MatrixXd S = d.asDiagonal() * JtJ * d.asDiagonal();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(S);
  const double lmax = eig.eigenvalues().maxCoeff(), lmin = eig.eigenvalues().minCoeff();
  rep.reciprocal_condition = lmax > 0 ? std::max(0.0, lmin) / lmax : 0.0;
  const int dof = std::max(1, residual_count - n);
  rep.residual_sigma = std::sqrt(2.0 * cost / dof);
  rep.ok = rep.reciprocal_condition >= min_reciprocal_condition && (d.array() > 0).all();
  rep.sigma.assign(static_cast<size_t>(n), 0.0);
  if (!rep.ok) return rep;
  const Eigen::MatrixXd inv = eig.eigenvectors() * eig.eigenvalues().cwiseInverse().asDiagonal() *
                              eig.eigenvectors().transpose();
  for (int i = 0; i < n; ++i)
    rep.sigma[static_cast<size_t>(i)] =
        rep.residual_sigma * d[i] * std::sqrt(std::max(0.0, inv(i, i)));
  return rep;
}

}  // namespace d3d
