#include "pipeline/register/pose_graph.h"

#include <ceres/ceres.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

namespace d3d {

void PoseGraphOptions::Check() const {
  D3D_CHECK_MSG(max_iterations > 0 && loop_huber_sigmas > 0, "PoseGraphOptions: invalid value");
}

namespace {

// Square root S of an edge's information (‖S r‖² = rᵀ Λ r): from the σs, or from Λ by an
// eigen-decomposition with the small eigenvalues floored.
Eigen::Matrix<double, 6, 6> SqrtInformation(const PoseGraphEdge& e) {
  Eigen::Matrix<double, 6, 6> S = Eigen::Matrix<double, 6, 6>::Zero();
  if (e.information.isZero(0)) {
    S.diagonal() << Eigen::Vector3d::Constant(1.0 / e.sigma_translation_mm),
        Eigen::Vector3d::Constant(1.0 / e.sigma_rotation_rad);
    return S;
  }
  const Eigen::Matrix<double, 6, 6> L = 0.5 * (e.information + e.information.transpose());
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> es(L);
  Eigen::Matrix<double, 6, 1> ev = es.eigenvalues();
  const double floor = std::max(ev.maxCoeff(), 1e-300) * 1e-9;
  for (int i = 0; i < 6; ++i) ev(i) = std::sqrt(std::max(ev(i), floor));
  return ev.asDiagonal() * es.eigenvectors().transpose();
}

struct RelativePoseCost {
  RelativePoseCost(const Rigid3d& m, const Eigen::Matrix<double, 6, 6>& sqrt_info)
      : t_(m.translation()), q_(Eigen::Quaterniond(m.linear()).normalized()), S_(sqrt_info) {}
  template <typename T>
  bool operator()(const T* ti, const T* qi, const T* tj, const T* qj, T* res) const {
    Eigen::Map<const Eigen::Matrix<T, 3, 1>> pa(ti), pb(tj);
    Eigen::Map<const Eigen::Quaternion<T>> qa(qi), qb(qj);
    const Eigen::Quaternion<T> qa_inv = qa.conjugate();
    const Eigen::Quaternion<T> q_ab = qa_inv * qb;
    const Eigen::Matrix<T, 3, 1> p_ab = qa_inv * (pb - pa);
    const Eigen::Quaternion<T> dq = q_.template cast<T>().conjugate() * q_ab;
    // q and −q are the same rotation, and the nodes' quaternions come in either sign (Eigen's
    // conversion from a matrix picks one by the largest diagonal entry, so two nearby orientations
    // can land in opposite hemispheres). 2·vec(dq) is the small rotation θ only for the
    // representative with w ≥ 0; with the other, r_θ flips sign while r_t does not, and an
    // information that couples rotation and translation (ICP's) then weighs a wrong residual.
    const T sign = dq.w() < T(0) ? T(-1) : T(1);
    Eigen::Matrix<T, 6, 1> r0;
    r0.template head<3>() = p_ab - t_.template cast<T>();
    r0.template tail<3>() = T(2.0) * sign * dq.vec();
    Eigen::Map<Eigen::Matrix<T, 6, 1>> r(res);
    r = S_.template cast<T>() * r0;
    return true;
  }
  Eigen::Vector3d t_;
  Eigen::Quaterniond q_;
  Eigen::Matrix<double, 6, 6> S_;
};

}  // namespace

Eigen::Matrix<double, 6, 6> EdgeInformationFromIcp(
    const Eigen::Matrix<double, 6, 6>& icp_information, const Rigid3d& m, double scale) {
  const Eigen::Matrix3d R = m.linear();
  const Eigen::Vector3d t = m.translation();
  Eigen::Matrix3d tx;
  tx << 0, -t.z(), t.y(), t.z(), 0, -t.x(), -t.y(), t.x(), 0;
  Eigen::Matrix<double, 6, 6> J = Eigen::Matrix<double, 6, 6>::Zero();
  J.block<3, 3>(0, 3) = R;  // ω = R_m θ
  J.block<3, 3>(3, 0) = Eigen::Matrix3d::Identity();
  J.block<3, 3>(3, 3) = tx * R;  // δ = r_t + [t_m]× R_m θ
  const Eigen::Matrix<double, 6, 6> L = scale * J.transpose() * icp_information * J;
  return 0.5 * (L + L.transpose());
}

int PoseGraph::AddNode(const Rigid3d& p) {
  poses_.push_back(p);
  return static_cast<int>(poses_.size()) - 1;
}

void PoseGraph::Truncate(int n, size_t max_edges) {
  D3D_CHECK_MSG(n >= 0 && n <= num_nodes(),
                "PoseGraph::Truncate: " << n << " nodes of " << num_nodes());
  poses_.resize(static_cast<size_t>(n));
  if (edges_.size() > max_edges) edges_.resize(max_edges);
  edges_.erase(std::remove_if(edges_.begin(), edges_.end(),
                              [n](const PoseGraphEdge& e) { return e.from >= n || e.to >= n; }),
               edges_.end());
}

bool PoseGraph::HasEdge(int a, int b) const {
  return std::any_of(edges_.begin(), edges_.end(), [a, b](const PoseGraphEdge& e) {
    return (e.from == a && e.to == b) || (e.from == b && e.to == a);
  });
}

void PoseGraph::AddEdge(const PoseGraphEdge& e) {
  D3D_CHECK_MSG(
      e.from >= 0 && e.to >= 0 && e.from < num_nodes() && e.to < num_nodes() && e.from != e.to,
      "PoseGraph::AddEdge: bad nodes " << e.from << " → " << e.to);
  D3D_CHECK_MSG(e.sigma_translation_mm > 0 && e.sigma_rotation_rad > 0,
                "PoseGraph::AddEdge: sigmas must be > 0");
  D3D_CHECK_MSG(e.information.allFinite() && e.information.trace() >= 0,
                "PoseGraph::AddEdge: information must be finite, PSD");
  edges_.push_back(e);
}

double PoseGraph::EdgeResidual(int k) const {
  const PoseGraphEdge& e = edges_[static_cast<size_t>(k)];
  RelativePoseCost c(e.from_from_to, SqrtInformation(e));
  const Rigid3d& a = poses_[static_cast<size_t>(e.from)];
  const Rigid3d& b = poses_[static_cast<size_t>(e.to)];
  const Eigen::Quaterniond qa(a.linear()), qb(b.linear());
  const Eigen::Vector3d ta = a.translation(), tb = b.translation();
  double r[6];
  c(ta.data(), qa.coeffs().data(), tb.data(), qb.coeffs().data(), r);
  return Eigen::Map<Eigen::Matrix<double, 6, 1>>(r).norm();
}

Status PoseGraph::Optimize(const PoseGraphOptions& o, PoseGraphSummary* s) {
  o.Check();
  if (poses_.empty()) return InvalidArgument("pose graph: no nodes");
  std::vector<Eigen::Vector3d> t(poses_.size());
  std::vector<Eigen::Quaterniond> q(poses_.size());
  for (size_t i = 0; i < poses_.size(); ++i) {
    t[i] = poses_[i].translation();
    q[i] = Eigen::Quaterniond(poses_[i].linear()).normalized();
  }
  ceres::Problem problem;
  ceres::Manifold* qm = new ceres::EigenQuaternionManifold;  // owned by the problem
  for (const PoseGraphEdge& e : edges_) {
    auto* cost = new ceres::AutoDiffCostFunction<RelativePoseCost, 6, 3, 4, 3, 4>(
        new RelativePoseCost(e.from_from_to, SqrtInformation(e)));
    ceres::LossFunction* loss = e.loop ? new ceres::HuberLoss(o.loop_huber_sigmas) : nullptr;
    const auto a = static_cast<size_t>(e.from), b = static_cast<size_t>(e.to);
    problem.AddResidualBlock(cost, loss, t[a].data(), q[a].coeffs().data(), t[b].data(),
                             q[b].coeffs().data());
  }
  bool manifold_used = false;
  for (size_t i = 0; i < poses_.size(); ++i) {
    if (!problem.HasParameterBlock(q[i].coeffs().data())) continue;
    problem.SetManifold(q[i].coeffs().data(), qm);
    manifold_used = true;
  }
  if (!manifold_used) delete qm;
  // The first node of each connected part is held: node 0, and the first keyframe of a scan
  // segment not joined to it (Tracker: segments), whose frame nothing else fixes.
  std::vector<int> part(poses_.size());
  for (size_t i = 0; i < part.size(); ++i) part[i] = static_cast<int>(i);
  auto root = [&](int i) {
    while (part[static_cast<size_t>(i)] != i)
      i = part[static_cast<size_t>(i)] = part[static_cast<size_t>(part[static_cast<size_t>(i)])];
    return i;
  };
  for (const PoseGraphEdge& e : edges_) {
    const int a = root(e.from), b = root(e.to);
    part[static_cast<size_t>(std::max(a, b))] = std::min(a, b);  // the smaller node stays the root
  }
  for (size_t i = 0; i < poses_.size(); ++i) {
    if (root(static_cast<int>(i)) != static_cast<int>(i) || !problem.HasParameterBlock(t[i].data()))
      continue;
    problem.SetParameterBlockConstant(t[i].data());
    problem.SetParameterBlockConstant(q[i].coeffs().data());
  }
  ceres::Solver::Options so;
  so.max_num_iterations = o.max_iterations;
  so.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  so.num_threads = 1;
  ceres::Solver::Summary sum;
  if (!edges_.empty()) ceres::Solve(so, &problem, &sum);
  for (size_t i = 0; i < poses_.size(); ++i) {
    Rigid3d p = Rigid3d::Identity();
    p.linear() = q[i].normalized().toRotationMatrix();
    p.translation() = t[i];
    poses_[i] = p;
  }
  if (s) {
    s->converged = edges_.empty() || sum.termination_type == ceres::CONVERGENCE;
    s->message = edges_.empty() ? "no edges" : sum.BriefReport();
    s->initial_cost = sum.initial_cost;
    s->final_cost = sum.final_cost;
    s->iterations = static_cast<int>(sum.iterations.size());
    s->disagreeing_edges.clear();
    for (int k = 0; k < static_cast<int>(edges_.size()); ++k)
      if (EdgeResidual(k) > 3.0 * std::sqrt(6.0)) s->disagreeing_edges.push_back(k);
  }
  return Status::Ok();
}

}  // namespace d3d
