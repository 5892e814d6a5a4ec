#include "common/core/rigid.h"

#include <gtest/gtest.h>

#include <cmath>

namespace d3d {
namespace {

TEST(Rigid, InterpolateEndpointsAndMidpoint) {
  const Rigid3d a = RigidFromQuaternion(Eigen::Quaterniond::Identity(), {0, 0, 0});
  const Rigid3d b = RigidFromQuaternion(Eigen::Quaterniond(Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitZ())), {2, 4, 6});
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

}  // namespace
}  // namespace d3d
