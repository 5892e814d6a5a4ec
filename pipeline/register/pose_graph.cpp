#include "pipeline/register/pose_graph.h"

#include <ceres/ceres.h>

#include <Eigen/Geometry>
#include <cmath>

namespace d3d {

void PoseGraphOptions::Check() const {
  D3D_CHECK_MSG(max_iterations > 0 && loop_huber_sigmas > 0, "PoseGraphOptions: invalid value");
}

namespace {

struct RelativePoseCost {
  RelativePoseCost(const Rigid3d& m, double st, double sr)
      : t_(m.translation()), q_(Eigen::Quaterniond(m.linear()).normalized()), wt_(1.0 / st), wr_(1.0 / sr) {}
  template <typename T>
  bool operator()(const T* ti, const T* qi, const T* tj, const T* qj, T* res) const {
    Eigen::Map<const Eigen::Matrix<T, 3, 1>> pa(ti), pb(tj);
    Eigen::Map<const Eigen::Quaternion<T>> qa(qi), qb(qj);
    const Eigen::Quaternion<T> qa_inv = qa.conjugate();
    const Eigen::Quaternion<T> q_ab = qa_inv * qb;
    const Eigen::Matrix<T, 3, 1> p_ab = qa_inv * (pb - pa);
    const Eigen::Quaternion<T> dq = q_.template cast<T>().conjugate() * q_ab;
    Eigen::Map<Eigen::Matrix<T, 6, 1>> r(res);
    r.template head<3>() = (p_ab - t_.template cast<T>()) * T(wt_);
    r.template tail<3>() = T(2.0) * dq.vec() * T(wr_);
    return true;
  }
  Eigen::Vector3d t_;
  Eigen::Quaterniond q_;
  double wt_, wr_;
};

}  // namespace

int PoseGraph::AddNode(const Rigid3d& p) {
  poses_.push_back(p);
  return static_cast<int>(poses_.size()) - 1;
}

void PoseGraph::AddEdge(const PoseGraphEdge& e) {
  D3D_CHECK_MSG(e.from >= 0 && e.to >= 0 && e.from < num_nodes() && e.to < num_nodes() && e.from != e.to,
                "PoseGraph::AddEdge: bad nodes " << e.from << " → " << e.to);
  D3D_CHECK_MSG(e.sigma_translation_mm > 0 && e.sigma_rotation_rad > 0, "PoseGraph::AddEdge: sigmas must be > 0");
  edges_.push_back(e);
}

double PoseGraph::EdgeResidual(int k) const {
  const PoseGraphEdge& e = edges_[static_cast<size_t>(k)];
  RelativePoseCost c(e.from_from_to, e.sigma_translation_mm, e.sigma_rotation_rad);
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
        new RelativePoseCost(e.from_from_to, e.sigma_translation_mm, e.sigma_rotation_rad));
    ceres::LossFunction* loss = e.loop ? new ceres::HuberLoss(o.loop_huber_sigmas) : nullptr;
    const auto a = static_cast<size_t>(e.from), b = static_cast<size_t>(e.to);
    problem.AddResidualBlock(cost, loss, t[a].data(), q[a].coeffs().data(), t[b].data(), q[b].coeffs().data());
  }
  bool manifold_used = false;
  for (size_t i = 0; i < poses_.size(); ++i) {
    if (!problem.HasParameterBlock(q[i].coeffs().data())) continue;
    problem.SetManifold(q[i].coeffs().data(), qm);
    manifold_used = true;
  }
  if (!manifold_used) delete qm;
  if (problem.HasParameterBlock(t[0].data())) {
    problem.SetParameterBlockConstant(t[0].data());
    problem.SetParameterBlockConstant(q[0].coeffs().data());
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
