// A pose graph of keyframes with odometry and loop-closure edges, optimised with Ceres
// (nonlinear least squares; the residual of Ceres' own pose_graph_3d example formulation,
// Kümmerle et al. 2011 g2o / Grisetti et al. 2010 "A tutorial on graph-based SLAM"):
//   for an edge i→j with measurement T_ij = node_i_from_node_j,
//   r = [ R_iᵀ (t_j − t_i) − t_ij ;  2 · vec(q_ijᵀ · q_iᵀ q_j) ] scaled by (1/σ_t, 1/σ_r)
// (or whitened by the edge's full information matrix, e.g. from the ICP that measured it), where
// the quaternion product is taken with w ≥ 0: q and −q are the same rotation, but only that sign
// gives r_θ = θ, and a full information couples the sign of r_θ with r_t. Each node's pose
// world_from_node is (t, unit quaternion on Ceres' EigenQuaternionManifold), the first node (of
// each connected part) is held fixed, and loop-closure edges have a Huber loss so that one false
// closure cannot bend the whole arch. Units: mm, rad.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "common/core/rigid.h"
#include "common/core/status.h"

namespace d3d {

struct PoseGraphEdge {
  int from = 0, to = 0;
  Rigid3d from_from_to = Rigid3d::Identity();  // measured node_from ← node_to
  double sigma_translation_mm = 0.01;
  double sigma_rotation_rad = 2e-4;
  // Full information of the residual [r_t (mm, `from` frame); r_θ (rad, `to` frame)] (the
  // residual of the header comment before its σ scaling). All zero (the default): the σs above
  // are used. Symmetric positive semi-definite; directions with (almost) no information are
  // floored at 1e-9 of the largest eigenvalue. See EdgeInformationFromIcp.
  Eigen::Matrix<double, 6, 6> information = Eigen::Matrix<double, 6, 6>::Zero();
  bool loop = false;  // loop closure (robust loss) or odometry
};

// Converts an ICP information matrix (icp.h IcpResult::information: left perturbation [ω (rad),
// t (mm)] of target_from_source, about the target origin) of a measured from_from_to into the
// edge residual's information, times `scale` (ICP's Gauss–Newton information treats every sample
// as independent; scale < 1 accounts for correlated errors). With T = Exp([ω; δ]) · T_m and
// T = T_m · Exp(θ) (rotation) the residual is r_θ = θ, r_t = ω × t_m + δ, so
// [ω; δ] = J [r_t; r_θ], J = [[0, R_m], [I, [t_m]× R_m]] and Λ_r = scale · Jᵀ Λ_icp J.
Eigen::Matrix<double, 6, 6> EdgeInformationFromIcp(
    const Eigen::Matrix<double, 6, 6>& icp_information, const Rigid3d& from_from_to, double scale);

struct PoseGraphOptions {
  int max_iterations = 100;
  double loop_huber_sigmas = 3.0;  // Huber threshold of loop edges, in units of their σ
  void Check() const;
};

struct PoseGraphSummary {
  bool converged = false;
  std::string message;  // Ceres' brief report
  double initial_cost = 0, final_cost = 0;
  int iterations = 0;
  // Edges whose normalised residual stays above 3 σ after optimisation ("disagreeing views").
  std::vector<int> disagreeing_edges;
};

class PoseGraph {
 public:
  int AddNode(const Rigid3d& world_from_node);
  void AddEdge(const PoseGraphEdge& edge);  // throws std::invalid_argument for unknown nodes
  // Keeps nodes 0 … num_nodes − 1 and, of the first max_edges edges, those between them (in their
  // order); the others go. Throws std::invalid_argument for num_nodes < 0 or above num_nodes().
  void Truncate(int num_nodes, size_t max_edges = SIZE_MAX);
  int num_nodes() const { return static_cast<int>(poses_.size()); }
  const std::vector<PoseGraphEdge>& edges() const { return edges_; }
  bool HasEdge(int a, int b) const;  // an edge joins nodes a and b (either direction)
  const Rigid3d& pose(int node) const { return poses_[static_cast<size_t>(node)]; }
  void set_pose(int node, const Rigid3d& p) { poses_[static_cast<size_t>(node)] = p; }
  // Optimises all but the first node of each connected part (node 0 in a connected graph).
  // INVALID_ARGUMENT for an empty graph.
  [[nodiscard]] Status Optimize(const PoseGraphOptions& options, PoseGraphSummary* summary);
  // Normalised residual norm of an edge at the current poses.
  double EdgeResidual(int edge) const;

 private:
  std::vector<Rigid3d> poses_;
  std::vector<PoseGraphEdge> edges_;
};

}  // namespace d3d
