#include "sim/trajectory/trajectory.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <stdexcept>

namespace d3d {
namespace {

Rigid3d Pose(double angle, const Eigen::Vector3d& axis, const Eigen::Vector3d& t) {
  return RigidFromQuaternion(Eigen::Quaterniond(Eigen::AngleAxisd(angle, axis.normalized())), t);
}

// Five keys, uneven intervals, up to ~70° between consecutive rotations.
std::vector<TimedPose> WigglyKeys() {
  return {{0, Pose(0.0, {0, 0, 1}, {0, 0, 0})},
          {100'000'000, Pose(0.6, {1, 1, 0}, {5, 1, 0})},
          {350'000'000, Pose(1.2, {0, 1, 1}, {9, 6, 2})},
          {420'000'000, Pose(0.3, {1, 0, 1}, {10, 8, 5})},
          {1'000'000'007, Pose(-0.9, {1, 2, 3}, {2, 3, 4})}};
}

std::string TempPath(const std::string& name) {
  return (std::filesystem::temp_directory_path() / ("d3d_traj_test_" + name)).string();
}

void WriteFile(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

// Body angular velocity (rad/s) from R(a) to R(b).
Eigen::Vector3d BodyRate(const Trajectory& tr, int64_t a, int64_t b) {
  return LogSO3(tr.WorldFromProbe(a).linear().transpose() * tr.WorldFromProbe(b).linear()) /
         (static_cast<double>(b - a) * 1e-9);
}

Eigen::Vector3d LinearRate(const Trajectory& tr, int64_t a, int64_t b) {
  return (tr.WorldFromProbe(b).translation() - tr.WorldFromProbe(a).translation()) /
         (static_cast<double>(b - a) * 1e-9);
}

TEST(SO3, ExpLogAndJacobians) {
  const Eigen::Vector3d phi(0.3, -1.1, 0.7);
  EXPECT_TRUE(LogSO3(ExpSO3(phi)).isApprox(phi, 1e-12));
  EXPECT_TRUE((RightJacobianSO3(phi) * RightJacobianInvSO3(phi))
                  .isApprox(Eigen::Matrix3d::Identity(), 1e-12));
  // Exp(φ + δ) ≈ Exp(φ) Exp(J_r(φ) δ)
  const Eigen::Vector3d delta(1e-6, -2e-6, 0.5e-6);
  const Eigen::Matrix3d lhs = ExpSO3(phi + delta);
  const Eigen::Matrix3d rhs = ExpSO3(phi) * ExpSO3(RightJacobianSO3(phi) * delta);
  EXPECT_LT((lhs - rhs).norm(), 1e-11);
  const Eigen::Vector3d tiny(1e-9, 0, 0);
  EXPECT_TRUE((RightJacobianSO3(tiny) * RightJacobianInvSO3(tiny))
                  .isApprox(Eigen::Matrix3d::Identity(), 1e-12));
}

TEST(Trajectory, PassesThroughKeys) {
  const auto keys = WigglyKeys();
  const Trajectory tr(keys);
  EXPECT_EQ(tr.StartNs(), 0);
  EXPECT_EQ(tr.EndNs(), 1'000'000'007);
  ASSERT_EQ(tr.keys().size(), keys.size());
  for (const auto& k : keys) {
    const Rigid3d T = tr.WorldFromProbe(k.t_ns);
    EXPECT_LT(TranslationDistanceMm(T, k.world_from_probe), 1e-9) << k.t_ns;
    EXPECT_LT(RotationAngleRad(T, k.world_from_probe), 1e-9) << k.t_ns;
  }
}

TEST(Trajectory, IsC1AtTheKnots) {
  const auto keys = WigglyKeys();
  const Trajectory tr(keys);
  constexpr int64_t kDelta = 1000;  // 1 µs one-sided differences
  for (size_t i = 1; i + 1 < keys.size(); ++i) {
    const int64_t t = keys[i].t_ns;
    const Eigen::Vector3d vl = LinearRate(tr, t - kDelta, t), vr = LinearRate(tr, t, t + kDelta);
    const Eigen::Vector3d wl = BodyRate(tr, t - kDelta, t), wr = BodyRate(tr, t, t + kDelta);
    // The one-sided differences differ by ~acceleration × δ; a kink would make them differ by
    // O(|v|).
    EXPECT_LT((vl - vr).norm(), 1e-3 * std::max(1.0, vl.norm())) << "position kink at key " << i;
    EXPECT_LT((wl - wr).norm(), 1e-3 * std::max(1.0, wl.norm())) << "rotation kink at key " << i;
  }
  // Piecewise-geodesic interpolation (C0 only) of the same keys does have kinks: the check bites.
  const int64_t t = keys[2].t_ns;
  const double s_left = 1.0 - 1e-5, s_right = 1e-5;
  const Rigid3d a = InterpolateRigid(keys[1].world_from_probe, keys[2].world_from_probe, s_left);
  const Rigid3d b = InterpolateRigid(keys[2].world_from_probe, keys[3].world_from_probe, s_right);
  const double h1 = (keys[2].t_ns - keys[1].t_ns) * 1e-9, h2 = (keys[3].t_ns - t) * 1e-9;
  const Eigen::Vector3d vl =
      (keys[2].world_from_probe.translation() - a.translation()) / ((1 - s_left) * h1);
  const Eigen::Vector3d vr =
      (b.translation() - keys[2].world_from_probe.translation()) / (s_right * h2);
  EXPECT_GT((vl - vr).norm(), 1.0);
}

TEST(Trajectory, ClampsOutsideItsSpan) {
  const auto keys = WigglyKeys();
  const Trajectory tr(keys);
  EXPECT_TRUE(tr.WorldFromProbe(-5'000'000'000).isApprox(keys.front().world_from_probe));
  EXPECT_TRUE(tr.WorldFromProbe(7'000'000'000).isApprox(keys.back().world_from_probe));
  EXPECT_DOUBLE_EQ(LinearSpeedMmPerS(tr, -1'000'000'000), 0.0);
  EXPECT_DOUBLE_EQ(AngularSpeedRadPerS(tr, 9'000'000'000), 0.0);
}

TEST(Trajectory, RejectsBadKeys) {
  EXPECT_THROW(Trajectory({{0, Rigid3d::Identity()}}), std::invalid_argument);
  EXPECT_THROW(Trajectory({{5, Rigid3d::Identity()}, {5, Rigid3d::Identity()}}),
               std::invalid_argument);
  EXPECT_THROW(Trajectory({{5, Rigid3d::Identity()}, {3, Rigid3d::Identity()}}),
               std::invalid_argument);
  Rigid3d bad = Rigid3d::Identity();
  bad.linear() *= 2.0;
  EXPECT_THROW(Trajectory({{0, Rigid3d::Identity()}, {1, bad}}), std::invalid_argument);
  const Trajectory empty;
  EXPECT_TRUE(empty.empty());
  EXPECT_THROW(empty.WorldFromProbe(0), std::invalid_argument);
}

TEST(Trajectory, SpeedsOfAUniformMotion) {
  // Two keys: the Hermite tangents equal the chord, so the motion is uniform.
  const Trajectory tr(
      {{0, Pose(0, {0, 0, 1}, {0, 0, 0})}, {2'000'000'000, Pose(1.0, {0, 0, 1}, {20, 0, 0})}});
  EXPECT_NEAR(LinearSpeedMmPerS(tr, 1'000'000'000), 10.0, 1e-6);
  EXPECT_NEAR(AngularSpeedRadPerS(tr, 1'000'000'000), 0.5, 1e-6);
  EXPECT_NEAR(LinearSpeedMmPerS(tr, 0), 10.0, 1e-6);  // one-sided at the ends
  EXPECT_NEAR(tr.WorldFromProbe(500'000'000).translation().x(), 5.0, 1e-9);
}

TEST(Trajectory, TumRoundTripKeepsNanoseconds) {
  auto keys = WigglyKeys();
  keys[1].t_ns = 1'234'567'891'234'567'891;  // ~39 years in ns: ns resolution must survive
  keys[0].t_ns = -3;
  for (size_t i = 2; i < keys.size(); ++i)
    keys[i].t_ns = keys[1].t_ns + static_cast<int64_t>(i) * 333'333'333 + 1;
  const Trajectory tr(keys);
  const std::string path = TempPath("roundtrip.tum");
  ASSERT_TRUE(tr.SaveTum(path).ok());
  Trajectory back;
  const Status st = Trajectory::LoadTum(path, &back);
  ASSERT_TRUE(st.ok()) << st.ToString();
  ASSERT_EQ(back.keys().size(), keys.size());
  for (size_t i = 0; i < keys.size(); ++i) {
    EXPECT_NEAR(static_cast<double>(back.keys()[i].t_ns - keys[i].t_ns), 0.0, 1000.0);
    EXPECT_EQ(back.keys()[i].t_ns, keys[i].t_ns);  // in fact exact
    EXPECT_LT(TranslationDistanceMm(back.keys()[i].world_from_probe, keys[i].world_from_probe),
              1e-8);
    EXPECT_LT(RotationAngleRad(back.keys()[i].world_from_probe, keys[i].world_from_probe), 1e-10);
  }
  std::filesystem::remove(path);
}

TEST(Trajectory, TumReadsCommentsAndExponents) {
  const std::string path = TempPath("comments.tum");
  WriteFile(path,
            "# header\n\n  # indented comment\n"
            "1.5 0 0 0 0 0 0 1\r\n"
            "2e0 1 2 3 0 0 0.7071067811865476 0.7071067811865476\n");
  Trajectory tr;
  ASSERT_TRUE(Trajectory::LoadTum(path, &tr).ok());
  ASSERT_EQ(tr.keys().size(), 2u);
  EXPECT_EQ(tr.StartNs(), 1'500'000'000);
  EXPECT_EQ(tr.EndNs(), 2'000'000'000);
  EXPECT_NEAR(RotationAngleRad(tr.keys()[1].world_from_probe, Rigid3d::Identity()),
              std::numbers::pi / 2, 1e-12);
  std::filesystem::remove(path);
}

struct MalformedCase {
  const char* name;
  const char* text;
  const char* expect;  // substring of the message
};

TEST(Trajectory, TumMalformedNamesTheLine) {
  const MalformedCase cases[] = {
      {"fields", "# c\n0 0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n", ":3: expected 8 fields"},
      {"number", "0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n2 0 x 0 0 0 0 1\n", ":3: bad number 'x'"},
      {"time", "0 0 0 0 0 0 0 1\n1.2.3 0 0 0 0 0 0 1\n", ":2: bad timestamp"},
      {"quat", "0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 2\n", ":2: quaternion is not unit"},
      {"order", "0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", ":3: timestamp"},
      {"nan", "0 0 0 0 0 0 0 1\n1 nan 0 0 0 0 0 1\n", ":2: bad number 'nan'"},
      {"short", "# only one\n0 0 0 0 0 0 0 1\n", "at least 2 poses"},
  };
  for (const auto& c : cases) {
    const std::string path = TempPath(std::string("bad_") + c.name + ".tum");
    WriteFile(path, c.text);
    Trajectory tr;
    const Status st = Trajectory::LoadTum(path, &tr);
    EXPECT_EQ(st.code(), StatusCode::kParseError) << c.name << ": " << st.ToString();
    EXPECT_NE(st.message().find(c.expect), std::string::npos) << c.name << ": " << st.ToString();
    EXPECT_TRUE(tr.empty()) << c.name;
    std::filesystem::remove(path);
  }
  Trajectory tr;
  EXPECT_EQ(Trajectory::LoadTum(TempPath("does_not_exist.tum"), &tr).code(), StatusCode::kNotFound);
  EXPECT_FALSE(Trajectory().SaveTum(TempPath("empty.tum")).ok());
}

}  // namespace
}  // namespace d3d
