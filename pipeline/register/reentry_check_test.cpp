#include "pipeline/register/reentry_check.h"

#include <gtest/gtest.h>

#include "pipeline/register/test_surfaces.h"

namespace d3d {
namespace {

using namespace d3d::testing;

class ReentryCheckTest : public ::testing::Test {
 protected:
  ReentryCheckTest() : hf_(7), cam_(TestCamera()) {
    kf_pose_ = LookDown(0, 0, 30);
    kf_samples_ = Samples(kf_pose_, 1, 4);
    view_pose_ = LookDown(1.5, 0.5, 30, 0.03, -0.02, 0.05);
    view_samples_ = Samples(view_pose_, 2, 2);
  }
  SurfacePoints Samples(const Rigid3d& pose, uint32_t seed, int stride) const {
    const SyntheticView v = RenderHeightField(hf_, cam_, pose, 0.004, seed);
    return SampleOrganised(v.points, v.normals, cv::Mat(), stride);
  }
  // The view's samples tested at `pose` against the keyframe.
  ReentryEvidence TestAt(const Rigid3d& pose, const ReentryCheckOptions& o = {}) const {
    ReentryCheck check(cam_, o);
    return check.Test(view_samples_, pose,
                      {{&kf_samples_, kf_pose_, kf_pose_ * kf_samples_.Centroid()}});
  }
  HeightField hf_;
  PinholeBrownConrady cam_;
  Rigid3d kf_pose_, view_pose_;
  SurfacePoints kf_samples_, view_samples_;
};

Rigid3d Moved(const Rigid3d& pose, const Eigen::Vector3d& t_world) {
  Rigid3d p = pose;
  p.translation() += t_world;
  return p;
}

TEST_F(ReentryCheckTest, TheTruePosePasses) {
  const ReentryEvidence e = TestAt(view_pose_);
  EXPECT_TRUE(e.ok) << e.reason;
  EXPECT_EQ(e.keyframes, 1);
  EXPECT_GT(e.agreeing, 2000);
  EXPECT_LT(e.violation_fraction(), 0.01);
}

TEST_F(ReentryCheckTest, AViewPlacedInSpaceTheKeyframeSawThroughFails) {
  // 1 mm toward the cameras (world +z): the view's points float in front of the keyframe's surface.
  const ReentryEvidence e = TestAt(Moved(view_pose_, {0, 0, 1.0}));
  EXPECT_FALSE(e.ok);
  EXPECT_GT(e.violation_fraction(), 0.5);
  EXPECT_NE(e.reason.find("seen-through"), std::string::npos);
}

TEST_F(ReentryCheckTest, AViewThatSawThroughTheKeyframesSurfaceFails) {
  // 1 mm away from the cameras: the view's points hide behind the keyframe's surface (the keyframe
  // says nothing of them), but the keyframe's surface now lies in front of what the view saw.
  const ReentryEvidence e = TestAt(Moved(view_pose_, {0, 0, -1.0}));
  EXPECT_FALSE(e.ok);
  EXPECT_GT(e.violation_fraction(), 0.3);
}

TEST_F(ReentryCheckTest, ANeighbouringFitShiftedAlongTheSurfaceFails) {
  // 2.5 mm sideways and turned 10 degrees: the relief no longer lines up.
  Rigid3d wrong = Moved(view_pose_, {2.5, 0, 0});
  wrong.linear() = Eigen::AngleAxisd(10 * M_PI / 180, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
                   wrong.linear();
  const ReentryEvidence e = TestAt(wrong);
  EXPECT_FALSE(e.ok) << e.violation_fraction();
}

TEST_F(ReentryCheckTest, NoVerdictWithoutKeyframesNearOrEnoughPoints) {
  ReentryCheckOptions near;
  near.max_centre_distance_mm = 1.0;  // the keyframe's surface centre is ~1.6 mm from the view's
  ReentryEvidence e = TestAt(Moved(view_pose_, {0, 0, 1.0}), near);
  EXPECT_TRUE(e.ok);
  EXPECT_EQ(e.keyframes, 0);
  ReentryCheckOptions many;
  many.min_tested = 1000000;
  e = TestAt(Moved(view_pose_, {0, 0, 1.0}), many);
  EXPECT_TRUE(e.ok);
  EXPECT_GT(e.seen_through, 0);
  ReentryCheckOptions off;
  off.enabled = false;
  e = TestAt(Moved(view_pose_, {0, 0, 1.0}), off);
  EXPECT_TRUE(e.ok);
  EXPECT_EQ(e.seen_through + e.agreeing, 0);
}

TEST(ReentryCheckOptions, CheckRefusesNonsense) {
  ReentryCheckOptions o;
  o.agree_mm = 1.0;  // above margin_mm
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = ReentryCheckOptions{};
  o.grid_scale = 0;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = ReentryCheckOptions{};
  o.max_violation_fraction = 1.5;
  EXPECT_THROW(o.Check(), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
