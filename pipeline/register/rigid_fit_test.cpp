#include "pipeline/register/rigid_fit.h"

#include <gtest/gtest.h>

#include <random>

namespace d3d {
namespace {

Rigid3d Known() {
  Rigid3d T = Rigid3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, -0.5).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(3, -2, 10);
  return T;
}

TEST(FitRigid, RecoversAKnownTransformExactly) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> U(-5, 5);
  const Rigid3d T = Known();
  std::vector<Correspondence3d> c;
  for (int i = 0; i < 20; ++i) {
    Eigen::Vector3d s(U(rng), U(rng), U(rng));
    c.push_back({s, T * s, 1.0});
  }
  const auto fit = FitRigid(c);
  ASSERT_TRUE(fit.has_value());
  EXPECT_LT(RotationAngleRad(*fit, T), 1e-10);
  EXPECT_LT(TranslationDistanceMm(*fit, T), 1e-9);
  EXPECT_NEAR(fit->linear().determinant(), 1.0, 1e-12);
}

TEST(FitRigid, RefusesCollinearPoints) {
  std::vector<Correspondence3d> c;
  for (int i = 0; i < 10; ++i)
    c.push_back({Eigen::Vector3d(i, 2 * i, 0), Eigen::Vector3d(i, 2 * i, 1), 1.0});
  EXPECT_FALSE(FitRigid(c).has_value());
}

TEST(RansacRigid, FindsTheInliersAmongOutliers) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> U(-8, 8);
  std::normal_distribution<double> N(0, 0.01);
  const Rigid3d T = Known();
  std::vector<Correspondence3d> c;
  for (int i = 0; i < 200; ++i) {
    Eigen::Vector3d s(U(rng), U(rng), U(rng));
    Eigen::Vector3d t = T * s + Eigen::Vector3d(N(rng), N(rng), N(rng));
    if (i % 5 < 3) t = Eigen::Vector3d(U(rng), U(rng), U(rng));  // 60 % outliers
    c.push_back({s, t, 1.0});
  }
  const RansacResult r = RansacRigid(c);
  ASSERT_TRUE(r.ok) << r.reason;
  EXPECT_GE(r.inliers.size(), 75u);
  EXPECT_LT(RotationAngleRad(r.target_from_source, T), 0.003);
  EXPECT_LT(TranslationDistanceMm(r.target_from_source, T), 0.02);
}

// Many correspondences, few inliers (10 % of 5000), the others near misses within ±3 mm of the true
// match (as 3-D descriptor matching gives: a neighbouring point of similar shape). The first
// hypotheses then explain one or two correspondences, for which the iteration bound
// log(1 − p)/log(1 − w³) exceeds an int; RANSAC must keep drawing up to max_iterations, not stop.
TEST(RansacRigid, KeepsDrawingWhenTheFirstConsensusIsTiny) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> U(-50, 50), Miss(-3, 3);
  std::normal_distribution<double> N(0, 0.01);
  const Rigid3d T = Known();
  std::vector<Correspondence3d> c;
  for (int i = 0; i < 5000; ++i) {
    const Eigen::Vector3d s(U(rng), U(rng), U(rng));
    const Eigen::Vector3d e = i % 10 == 0 ? Eigen::Vector3d(N(rng), N(rng), N(rng))
                                          : Eigen::Vector3d(Miss(rng), Miss(rng), Miss(rng));
    c.push_back({s, T * s + e, 1.0});
  }
  RansacOptions o;
  o.max_iterations = 20000;
  const RansacResult r = RansacRigid(c, o);
  ASSERT_TRUE(r.ok) << r.reason;
  EXPECT_GE(r.inliers.size(), 480u);
  EXPECT_LT(RotationAngleRad(r.target_from_source, T), 0.003);
}

TEST(RansacRigid, FailsCleanlyOnDegenerateOrRandomInput) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> U(-8, 8);
  std::vector<Correspondence3d> random;
  for (int i = 0; i < 100; ++i)
    random.push_back(
        {Eigen::Vector3d(U(rng), U(rng), U(rng)), Eigen::Vector3d(U(rng), U(rng), U(rng)), 1});
  const RansacResult r = RansacRigid(random);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.reason.find("inlier"), std::string::npos) << r.reason;
  // All correspondences on one line: rotation about it unknown.
  std::vector<Correspondence3d> line;
  const Rigid3d T = Known();
  for (int i = 0; i < 50; ++i) {
    const Eigen::Vector3d s(0.3 * i, 0.1 * i, 0);
    line.push_back({s, T * s, 1});
  }
  const RansacResult l = RansacRigid(line);
  EXPECT_FALSE(l.ok);
  EXPECT_FALSE(l.reason.empty());
  EXPECT_FALSE(RansacRigid({}).ok);
}

}  // namespace
}  // namespace d3d
