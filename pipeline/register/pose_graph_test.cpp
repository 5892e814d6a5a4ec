#include "pipeline/register/pose_graph.h"

#include <gtest/gtest.h>

#include <random>

namespace d3d {
namespace {

Rigid3d CirclePose(int i, int n, double radius) {
  const double a = 2 * M_PI * i / n;
  Rigid3d T = Rigid3d::Identity();
  T.linear() = Eigen::AngleAxisd(a, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() =
      Eigen::Vector3d(radius * std::cos(a), radius * std::sin(a), 0.2 * std::sin(3 * a));
  return T;
}

TEST(PoseGraph, LoopClosureRemovesAnInjectedDrift) {
  const int n = 40;
  std::vector<Rigid3d> truth;
  for (int i = 0; i < n; ++i) truth.push_back(CirclePose(i, n, 25));
  // Odometry with a systematic bias: every step turns 0.02° too far and advances 5 µm too far.
  Rigid3d bias = Rigid3d::Identity();
  bias.linear() = Eigen::AngleAxisd(0.02 * M_PI / 180, Eigen::Vector3d(0.2, 0.3, 1).normalized())
                      .toRotationMatrix();
  bias.translation() = Eigen::Vector3d(0.005, 0.002, -0.001);
  PoseGraph g;
  Rigid3d pose = truth[0];
  g.AddNode(pose);
  for (int i = 1; i < n; ++i) {
    const Rigid3d step =
        truth[static_cast<size_t>(i - 1)].inverse() * truth[static_cast<size_t>(i)] * bias;
    pose = pose * step;
    g.AddNode(pose);
    PoseGraphEdge e;
    e.from = i - 1;
    e.to = i;
    e.from_from_to = step;
    g.AddEdge(e);
  }
  const double drift_before =
      TranslationDistanceMm(g.pose(n - 1), truth[static_cast<size_t>(n - 1)]);
  ASSERT_GT(drift_before, 0.3);
  // Loop closure: the last pose seen from the first, exact (and one from node 5 to node 35).
  for (auto [a, b] : {std::pair{0, n - 1}, std::pair{5, 35}}) {
    PoseGraphEdge e;
    e.from = a;
    e.to = b;
    e.from_from_to = truth[static_cast<size_t>(a)].inverse() * truth[static_cast<size_t>(b)];
    e.loop = true;
    g.AddEdge(e);
  }
  PoseGraphSummary s;
  ASSERT_TRUE(g.Optimize({}, &s).ok());
  EXPECT_TRUE(s.converged) << s.message;
  EXPECT_LT(s.final_cost, s.initial_cost);
  double worst = 0;
  for (int i = 0; i < n; ++i)
    worst = std::max(worst, TranslationDistanceMm(g.pose(i), truth[static_cast<size_t>(i)]));
  EXPECT_LT(worst, drift_before / 5) << "drift before " << drift_before;
  // End meets start: the relative pose of the loop edge now holds.
  const Rigid3d end_from_start = g.pose(n - 1).inverse() * g.pose(0);
  const Rigid3d want = truth[static_cast<size_t>(n - 1)].inverse() * truth[0];
  EXPECT_LT(TranslationDistanceMm(end_from_start, want), 0.05);
}

TEST(PoseGraph, FlagsADisagreeingLoopEdge) {
  PoseGraph g;
  for (int i = 0; i < 10; ++i) g.AddNode(CirclePose(i, 40, 25));
  for (int i = 1; i < 10; ++i) {
    PoseGraphEdge e;
    e.from = i - 1;
    e.to = i;
    e.from_from_to = g.pose(i - 1).inverse() * g.pose(i);
    g.AddEdge(e);
  }
  PoseGraphEdge bad;
  bad.from = 0;
  bad.to = 9;
  bad.from_from_to = g.pose(0).inverse() * g.pose(9);
  bad.from_from_to.translation() += Eigen::Vector3d(2.0, 0, 0);  // a false closure, 2 mm off
  bad.loop = true;
  g.AddEdge(bad);
  PoseGraphSummary s;
  ASSERT_TRUE(g.Optimize({}, &s).ok());
  ASSERT_FALSE(s.disagreeing_edges.empty());
  EXPECT_EQ(s.disagreeing_edges.back(), 9);
  // The robust loss keeps the trajectory close to the odometry.
  EXPECT_LT(TranslationDistanceMm(g.pose(9), CirclePose(9, 40, 25)), 0.5);
}

// The edge information converted from ICP's convention gives the same quadratic form as ICP's
// information on the left perturbation: ‖S r‖² ≈ ξᵀ Λ_icp ξ for T = Exp(ξ) · T_m (small ξ).
TEST(PoseGraph, EdgeInformationFromIcpMatchesTheLeftPerturbation) {
  std::mt19937 rng(7);
  std::normal_distribution<double> N(0, 1);
  Rigid3d m = Rigid3d::Identity();
  m.linear() =
      Eigen::AngleAxisd(0.4, Eigen::Vector3d(0.3, -0.5, 0.8).normalized()).toRotationMatrix();
  m.translation() = Eigen::Vector3d(3.0, -1.5, 0.7);
  Eigen::Matrix<double, 6, 6> A;
  for (int i = 0; i < 36; ++i) A(i / 6, i % 6) = N(rng);
  const Eigen::Matrix<double, 6, 6> info_icp =
      A * A.transpose() + 0.1 * Eigen::Matrix<double, 6, 6>::Identity();
  PoseGraphEdge e;
  e.from = 0;
  e.to = 1;
  e.from_from_to = m;
  e.information = EdgeInformationFromIcp(info_icp, m, 1.0);
  for (int trial = 0; trial < 5; ++trial) {
    Eigen::Matrix<double, 6, 1> xi;
    for (int i = 0; i < 6; ++i) xi(i) = 1e-4 * N(rng);
    Rigid3d d = Rigid3d::Identity();
    d.linear() =
        Eigen::AngleAxisd(xi.head<3>().norm(), xi.head<3>().normalized()).toRotationMatrix();
    d.translation() = xi.tail<3>();
    PoseGraph g;
    g.AddNode(Rigid3d::Identity());
    g.AddNode(d * m);
    g.AddEdge(e);
    const double want = xi.dot(info_icp * xi);
    const double got = g.EdgeResidual(0) * g.EdgeResidual(0);
    EXPECT_NEAR(got, want, 1e-3 * want + 1e-12) << "trial " << trial;
  }
}

// An edge that knows nothing about one direction (a slide along a groove: information only in
// the other five) gives way to a path of well-measured edges in that direction.
TEST(PoseGraph, AWeakDirectionGivesWayToWellMeasuredEdges) {
  std::vector<Rigid3d> truth;
  for (int i = 0; i < 4; ++i) truth.push_back(CirclePose(i, 40, 25));
  PoseGraph g;
  for (const auto& t : truth) g.AddNode(t);
  auto edge = [&](int a, int b) {
    PoseGraphEdge e;
    e.from = a;
    e.to = b;
    e.from_from_to = truth[static_cast<size_t>(a)].inverse() * truth[static_cast<size_t>(b)];
    e.information = Eigen::Matrix<double, 6, 6>::Identity() * 1e4;
    return e;
  };
  // 1 → 2 measured 0.3 mm off along its x, where it has no information; 0 → 2 and 1 → 3 → 2 exact.
  PoseGraphEdge weak = edge(1, 2);
  weak.from_from_to.translation() += Eigen::Vector3d(0.3, 0, 0);
  weak.information(0, 0) = 0;
  g.AddEdge(edge(0, 1));
  g.AddEdge(weak);
  g.AddEdge(edge(0, 2));
  g.AddEdge(edge(1, 3));
  g.AddEdge(edge(2, 3));
  g.set_pose(2, g.pose(1) * weak.from_from_to);  // start from the weak edge's belief
  PoseGraphSummary s;
  ASSERT_TRUE(g.Optimize({}, &s).ok());
  EXPECT_LT(TranslationDistanceMm(g.pose(2), truth[2]), 0.005);
}

// A change of world frame (every node moved by the same rigid G) changes nothing relative: the
// edges' residuals and the optimised relative poses stay the same. With G a half turn about an
// axis between +x and −y, the nodes' quaternions fall in opposite hemispheres (Eigen picks the
// sign by the largest diagonal entry, x for some nodes and y for others), and an information that
// couples rotation and translation (ICP's always does) must still weigh the same residual.
TEST(PoseGraph, AChangeOfWorldFrameChangesNothingRelative) {
  std::mt19937 rng(11);
  std::normal_distribution<double> N(0, 1);
  const int n = 6;
  std::vector<Rigid3d> truth;
  for (int i = 0; i < n; ++i) {
    Rigid3d t = CirclePose(i, 40, 25);
    t.linear() =
        Eigen::AngleAxisd(0.03 * N(rng), Eigen::Vector3d(N(rng), N(rng), N(rng)).normalized()) *
        t.linear();
    truth.push_back(t);
  }
  std::vector<PoseGraphEdge> edges;
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < std::min(n, a + 3); ++b) {
      PoseGraphEdge e;
      e.from = a;
      e.to = b;
      e.from_from_to = truth[static_cast<size_t>(a)].inverse() * truth[static_cast<size_t>(b)];
      e.from_from_to.translation() +=
          Eigen::Vector3d(0.02 * N(rng), 0.02 * N(rng), 0.02 * N(rng));  // measurement noise
      Eigen::Matrix<double, 6, 6> A;
      for (int i = 0; i < 36; ++i) A(i / 6, i % 6) = N(rng);
      e.information = EdgeInformationFromIcp(A * A.transpose() * 1e4, e.from_from_to, 1.0);
      e.loop = b - a > 1;
      edges.push_back(e);
    }
  auto build = [&](const Rigid3d& G) {
    PoseGraph g;
    for (const Rigid3d& t : truth) g.AddNode(G * t);
    for (const PoseGraphEdge& e : edges) g.AddEdge(e);
    return g;
  };
  PoseGraph ref = build(Rigid3d::Identity());
  std::vector<double> ref_residuals;
  for (int k = 0; k < static_cast<int>(edges.size()); ++k)
    ref_residuals.push_back(ref.EdgeResidual(k));
  PoseGraphSummary s;
  ASSERT_TRUE(ref.Optimize({}, &s).ok());
  for (const double tilt : {0.0, 0.01, -0.01}) {
    Rigid3d G = Rigid3d::Identity();
    G.linear() =
        Eigen::AngleAxisd(M_PI, Eigen::Vector3d(1, -1, tilt).normalized()).toRotationMatrix();
    G.translation() = Eigen::Vector3d(5, -3, 2);
    PoseGraph g = build(G);
    for (int k = 0; k < static_cast<int>(edges.size()); ++k)
      EXPECT_NEAR(g.EdgeResidual(k), ref_residuals[static_cast<size_t>(k)],
                  1e-6 * (1 + ref_residuals[static_cast<size_t>(k)]))
          << "edge " << k << ", tilt " << tilt;
    ASSERT_TRUE(g.Optimize({}, &s).ok());
    for (int i = 1; i < n; ++i) {
      const Rigid3d rel = (G * ref.pose(0)).inverse() * g.pose(i);
      const Rigid3d rel_ref = ref.pose(0).inverse() * ref.pose(i);
      EXPECT_LT(TranslationDistanceMm(rel, rel_ref), 1e-5) << "node " << i << ", tilt " << tilt;
      EXPECT_LT(RotationAngleRad(rel, rel_ref), 1e-7) << "node " << i << ", tilt " << tilt;
    }
  }
}

// Two chains with no edge between them (a scan segment not joined yet): each keeps its first node
// where it was, and the rest of each chain follows its own edges.
TEST(PoseGraph, EachConnectedPartKeepsItsFirstNode) {
  PoseGraph g;
  Rigid3d step = Rigid3d::Identity();
  step.translation() = Eigen::Vector3d(1, 0, 0);
  Rigid3d far = Rigid3d::Identity();
  far.translation() = Eigen::Vector3d(2000, 5, 0);
  for (int part = 0; part < 2; ++part) {
    const Rigid3d origin = part == 0 ? Rigid3d::Identity() : far;
    for (int i = 0; i < 4; ++i) {
      Rigid3d p = origin;
      p.translation() += Eigen::Vector3d(i * 1.01, 0.02 * i, 0);  // a little off the edges
      g.AddNode(p);
      if (i > 0) {
        PoseGraphEdge e;
        e.from = part * 4 + i - 1;
        e.to = part * 4 + i;
        e.from_from_to = step;
        g.AddEdge(e);
      }
    }
  }
  PoseGraphSummary summary;
  ASSERT_TRUE(g.Optimize({}, &summary).ok());
  EXPECT_TRUE(g.pose(0).isApprox(Rigid3d::Identity()));
  EXPECT_LT((g.pose(4).translation() - far.translation()).norm(),
            1e-9);  // held, not pulled anywhere
  for (int i = 1; i < 4; ++i) {
    EXPECT_LT((g.pose(i).translation() - Eigen::Vector3d(i, 0, 0)).norm(), 1e-6);
    EXPECT_LT((g.pose(4 + i).translation() - (far.translation() + Eigen::Vector3d(i, 0, 0))).norm(),
              1e-6);
  }
}

TEST(PoseGraph, TruncateKeepsTheEarlyEdgesBetweenKeptNodes) {
  PoseGraph g;
  for (int i = 0; i < 4; ++i) g.AddNode(Rigid3d::Identity());
  const std::vector<std::pair<int, int>> pairs = {{0, 1}, {1, 2}, {0, 2}, {2, 3}, {0, 1}, {1, 3}};
  for (const auto& [a, b] : pairs) {
    PoseGraphEdge e;
    e.from = a;
    e.to = b;
    g.AddEdge(e);
  }
  EXPECT_TRUE(g.HasEdge(3, 1));
  EXPECT_FALSE(g.HasEdge(0, 3));
  auto kept = [&g] {
    std::vector<std::pair<int, int>> out;
    for (const PoseGraphEdge& e : g.edges()) out.emplace_back(e.from, e.to);
    return out;
  };
  g.Truncate(4, 5);  // the first five edges, all nodes
  EXPECT_EQ(kept(), (std::vector<std::pair<int, int>>{{0, 1}, {1, 2}, {0, 2}, {2, 3}, {0, 1}}));
  g.Truncate(3);  // node 3 and its edge go
  EXPECT_EQ(g.num_nodes(), 3);
  EXPECT_EQ(kept(), (std::vector<std::pair<int, int>>{{0, 1}, {1, 2}, {0, 2}, {0, 1}}));
  EXPECT_THROW(g.Truncate(4), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
