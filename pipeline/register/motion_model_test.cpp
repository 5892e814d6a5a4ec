#include "pipeline/register/motion_model.h"

#include <gtest/gtest.h>

namespace d3d {
namespace {

Rigid3d At(double x_mm, double yaw_deg) {
  Rigid3d T = Rigid3d::Identity();
  T.linear() = Eigen::AngleAxisd(yaw_deg * M_PI / 180, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(x_mm, 0.5 * x_mm, 0);
  return T;
}

TEST(MotionModel, PredictsTheLastStepPerViewElapsed) {
  MotionModel m;
  m.BeginView(0, 0);
  EXPECT_TRUE(m.Predict().isApprox(Rigid3d::Identity()));  // nothing placed
  m.Advance(At(0, 0), false);
  m.BeginView(1, 0);
  EXPECT_FALSE(m.HasVelocity());
  EXPECT_TRUE(m.Predict().isApprox(At(0, 0)));  // one pose: no step yet
  m.Advance(At(1, 2), false);
  // Two views later (one skipped): twice the step.
  m.BeginView(3, 0);
  ASSERT_TRUE(m.HasVelocity());
  EXPECT_DOUBLE_EQ(m.ViewsElapsed(), 2.0);
  // The step in the camera frame, twice: its rotation twice and its translation twice.
  const Rigid3d step = At(0, 0).inverse() * At(1, 2);
  Rigid3d twice = Rigid3d::Identity();
  twice.linear() = step.linear() * step.linear();
  twice.translation() = 2 * step.translation();
  const Rigid3d want = At(1, 2) * twice;
  EXPECT_LT(TranslationDistanceMm(m.Predict(), want), 1e-9);
  EXPECT_LT(RotationAngleRad(m.Predict(), want), 1e-9);
  // More than 8 steps: the last pose, not an extrapolation.
  m.BeginView(20, 0);
  EXPECT_TRUE(m.Predict().isApprox(At(1, 2)));
  // A restart (a re-entry) has no step across it; nor has a new segment's start.
  m.BeginView(21, 0);
  m.Advance(At(10, 0), true);
  m.BeginView(22, 0);
  EXPECT_FALSE(m.HasVelocity());
  m.Advance(At(11, 0), false);
  m.ForgetVelocity();
  m.BeginView(23, 0);
  EXPECT_TRUE(m.Predict().isApprox(At(11, 0)));
}

TEST(MotionModel, ByCaptureTimeWithAViewPeriod) {
  MotionModelOptions o;
  o.view_period_ns = 33'000'000;
  MotionModel m(o);
  m.BeginView(0, 1'000'000'000);
  m.Advance(At(0, 0), false);
  m.BeginView(1, 1'033'000'000);
  m.Advance(At(1, 0), false);
  // The next view processed came 3 periods later (a busy host): 3 steps, 3 views elapsed.
  m.BeginView(2, 1'132'000'000);
  EXPECT_NEAR(m.ViewsElapsed(), 3.0, 1e-9);
  EXPECT_NEAR(m.ViewsSince(0, 1'000'000'000), 4.0, 1e-9);  // since an earlier view, by time too
  EXPECT_DOUBLE_EQ(m.ViewsSince(0, 0), 2.0);  // its capture time unknown: views counted
  EXPECT_LT(TranslationDistanceMm(m.Predict(), At(4, 0)), 1e-9);
}

TEST(MotionModel, TheMotionCheckScalesWithTheViewsElapsed) {
  MotionModel m;  // 2.5 mm, 10 deg per view
  m.BeginView(0, 0);
  m.Advance(At(0, 0), false);
  m.BeginView(1, 0);
  std::string why;
  EXPECT_TRUE(m.Consistent(At(2, 0), &why));   // 2.2 mm
  EXPECT_FALSE(m.Consistent(At(3, 0), &why));  // 3.4 mm
  EXPECT_NE(why.find("inconsistent motion"), std::string::npos);
  EXPECT_FALSE(m.Consistent(At(0, 12), nullptr));  // 12 deg
  m.BeginView(2, 0);
  EXPECT_TRUE(m.Consistent(At(3, 0), nullptr));  // two views: 5 mm allowed
  EXPECT_TRUE(m.ConsistentFrom(At(3, 0), 1, At(4, 0), nullptr));
  // A frame moved (a segment joined): the last pose with it.
  Rigid3d shift = Rigid3d::Identity();
  shift.translation() = Eigen::Vector3d(100, 0, 0);
  m.MoveFrame(shift);
  EXPECT_TRUE(m.last_pose().isApprox(shift * At(0, 0)));
  m.Reset();
  EXPECT_EQ(m.last_view(), -1);
  MotionModelOptions bad;
  bad.max_step_mm = 0;
  EXPECT_THROW(MotionModel{bad}, std::invalid_argument);
}

}  // namespace
}  // namespace d3d
