#include "common/core/rigid.h"

#include <gtest/gtest.h>

#include <cmath>
#include <sstream>
#include <string>

namespace d3d {
namespace {

TEST(Rigid, InterpolateEndpointsAndMidpoint) {
  const Rigid3d a = RigidFromQuaternion(Eigen::Quaterniond::Identity(), {0, 0, 0});
  const Rigid3d b = RigidFromQuaternion(
      Eigen::Quaterniond(Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitZ())), {2, 4, 6});
  EXPECT_LT(RotationAngleRad(InterpolateRigid(a, b, 0.0), a), 1e-12);
  EXPECT_LT(RotationAngleRad(InterpolateRigid(a, b, 1.0), b), 1e-12);
  const Rigid3d m = InterpolateRigid(a, b, 0.5);
  EXPECT_NEAR(RotationAngleRad(m, a), 0.2, 1e-12);
  EXPECT_NEAR((m.translation() - Eigen::Vector3d(1, 2, 3)).norm(), 0.0, 1e-12);
  const Rigid3d e = InterpolateRigid(a, b, 2.0);
  EXPECT_NEAR(RotationAngleRad(e, a), 0.8, 1e-9);
}

TEST(Rigid, LookRotationIsProperAndAims) {
  const Eigen::Matrix3d R = LookRotation({0, 0, -1}, {1, 0, 0});
  EXPECT_NEAR(R.determinant(), 1.0, 1e-12);
  EXPECT_TRUE(R.col(2).isApprox(Eigen::Vector3d(0, 0, -1)));
  EXPECT_TRUE(R.col(0).isApprox(Eigen::Vector3d(1, 0, 0)));
  EXPECT_THROW(LookRotation({0, 0, 1}, {0, 0, 2}), std::invalid_argument);
}

TEST(Rigid, TumPoseFieldsReadBackToThePose) {
  const Rigid3d p = RigidFromQuaternion(
      Eigen::Quaterniond(Eigen::AngleAxisd(2.5, Eigen::Vector3d(1, -2, 0.5).normalized())),
      {-12.25, 3.5, 48.125});
  const std::string s = TumPoseFields(p);
  EXPECT_EQ(s.front(), '-');
  EXPECT_NE(s.back(), ' ');
  std::istringstream in(s);
  double t[3], q[4];
  for (double& v : t) in >> v;
  for (double& v : q) in >> v;
  ASSERT_FALSE(in.fail()) << s;
  std::string rest;
  EXPECT_FALSE(in >> rest) << "7 fields, not more: " << s;
  const Rigid3d r =
      RigidFromQuaternion(Eigen::Quaterniond(q[3], q[0], q[1], q[2]), {t[0], t[1], t[2]});
  EXPECT_LT(TranslationDistanceMm(r, p), 1e-6);
  EXPECT_LT(RotationAngleRad(r, p), 1e-8);
}

}  // namespace
}  // namespace d3d
