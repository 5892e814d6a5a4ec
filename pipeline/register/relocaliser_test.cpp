#include "pipeline/register/relocaliser.h"

#include <gtest/gtest.h>

#include "pipeline/register/test_surfaces.h"

namespace d3d {
namespace {

using namespace d3d::testing;

KeyframeGraphOptions FewFeatures() {
  KeyframeGraphOptions o;
  o.detect_loops = false;
  o.features.max_features = 800;
  return o;
}

// A strip of views placed at their true poses (x −4 … 2 mm), as the tracker would have left them,
// and the relocaliser over them.
class RelocaliserTest : public ::testing::Test {
 protected:
  RelocaliserTest()
      : hf_(31),
        cam_(TestCamera()),
        odometry_(cam_, {}),
        keyframes_(FewFeatures(), DefaultTrackerIcp(), true),
        segments_(SegmentOptions{}, &odometry_, &keyframes_, true),
        relocaliser_(cam_, RelocaliserOptions{}, &odometry_, &motion_, &keyframes_, &segments_) {
    for (double x = -4; x <= 2.01; x += 0.5) {
      const Rigid3d pose = Truth(x);
      const SyntheticView v = View(pose, static_cast<uint32_t>(view_ + 1));
      motion_.BeginView(view_, 0);
      odometry_.Insert(v.points, v.normals, pose);
      TrackResult out;
      keyframes_.Update(v.points, v.normals, v.texture, pose, view_, 0, &out);
      motion_.Advance(pose, false);
      ++view_;
    }
  }
  static Rigid3d Truth(double x, double y = 0) { return LookDown(x, y, 30, 0.03, -0.02, 0.01 * x); }
  SyntheticView View(const Rigid3d& pose, uint32_t seed) const {
    return RenderHeightField(hf_, cam_, pose, 0.004, seed);
  }
  SurfacePoints Samples(const SyntheticView& v) const {
    SurfacePoints s;
    SampleOrganised(v.points, v.normals, v.quality, 2, &s);
    return s;
  }
  HeightField hf_;
  PinholeBrownConrady cam_;
  Odometry odometry_;
  MotionModel motion_;
  KeyframeGraph keyframes_;
  Segments segments_;
  Relocaliser relocaliser_;
  int64_t view_ = 0;
};

TEST(RelocaliserOptions, CheckRefusesWhatCannotWork) {
  EXPECT_NO_THROW(RelocaliserOptions().Check());
  RelocaliserOptions o;
  o.feature_candidates = 0;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = RelocaliserOptions();
  o.min_eigen_ratio = 1;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = RelocaliserOptions();
  o.jump_check_deg = -1;
  EXPECT_THROW(o.Check(), std::invalid_argument);
}

// A gap: the tracker is lost, or more than direct_max_views views passed since the last placed one.
// A jump: a pose farther from the prediction than jump_check_mm / _deg per view it spans.
TEST_F(RelocaliserTest, TellsAGapAndAJump) {
  motion_.BeginView(view_, 0);
  EXPECT_FALSE(relocaliser_.AfterGap(false));
  EXPECT_TRUE(relocaliser_.AfterGap(true));
  const Rigid3d pred = motion_.Predict();
  Rigid3d near = pred, far = pred;
  near.translation().x() += 1.0;
  far.translation().x() += 2.0;
  EXPECT_FALSE(relocaliser_.JumpsFromPrediction(near));
  EXPECT_TRUE(relocaliser_.JumpsFromPrediction(far));
  Rigid3d turned = pred;
  turned.linear() = pred.linear() *
                    Eigen::AngleAxisd(4 * M_PI / 180, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  EXPECT_TRUE(relocaliser_.JumpsFromPrediction(turned));
  motion_.BeginView(view_ + 2, 0);  // three views since the last placed one: a gap, a longer reach
  EXPECT_TRUE(relocaliser_.AfterGap(false));
  EXPECT_FALSE(relocaliser_.JumpsFromPrediction(far));
  // A jump needs a re-entry's residual.
  IcpResult loose;
  loose.ok = true;
  loose.rmse_mm = 0.05;
  loose.overlap = 0.9;
  std::string why;
  EXPECT_FALSE(relocaliser_.MeetsJumpStandard(SurfacePoints(), loose, false, &why));
  EXPECT_NE(why.find("a jump needs"), std::string::npos) << why;
}

// After a lift the probe comes back 2.5 mm behind where it left: the local search finds it at its
// true pose, and a view off the model is refused with the reason of each start.
TEST_F(RelocaliserTest, TheLocalSearchFindsAViewBackNearWhereItLeft) {
  motion_.BeginView(view_ + 3, 0);
  const Rigid3d truth = Truth(-0.5, 0.3);
  TrackResult out;
  bool from_prediction = true;
  ASSERT_TRUE(relocaliser_.SearchLocally(Samples(View(truth, 500)), true, &out, &from_prediction))
      << out.reason;
  EXPECT_LT(TranslationDistanceMm(out.world_from_cam, truth), 0.01);
  EXPECT_TRUE(out.reentry.ok) << out.reentry.reason;
  TrackResult off;
  EXPECT_FALSE(
      relocaliser_.SearchLocally(Samples(View(Truth(25), 501)), true, &off, &from_prediction));
  EXPECT_NE(off.reason.find("from the last pose"), std::string::npos) << off.reason;
  // Without a velocity the prediction is the last pose: that start is registered once, and its
  // result stands for both (the same pose as registering it twice, at half the cost).
  motion_.ForgetVelocity();
  TrackResult again;
  EXPECT_FALSE(
      relocaliser_.SearchLocally(Samples(View(Truth(25), 501)), true, &again, &from_prediction));
  EXPECT_NE(again.reason.find("from the last pose: as from the prediction"), std::string::npos)
      << again.reason;
  TrackResult back;
  ASSERT_TRUE(relocaliser_.SearchLocally(Samples(View(truth, 500)), true, &back, &from_prediction))
      << back.reason;
  EXPECT_LT(TranslationDistanceMm(back.world_from_cam, truth), 0.01);
}

// Farther than the local search reaches, keyframe features place the view.
TEST_F(RelocaliserTest, FeaturesPlaceAViewTheLocalSearchCannotReach) {
  motion_.BeginView(view_ + 3, 0);
  const Rigid3d truth = Truth(-3.2, 0.4);
  const SyntheticView v = View(truth, 600);
  TrackResult out;
  ASSERT_TRUE(relocaliser_.SearchByFeatures(Samples(v), v.points, v.texture, true, &out))
      << out.reason;
  EXPECT_NE(out.reason.find("feature inliers"), std::string::npos) << out.reason;
  EXPECT_LT(TranslationDistanceMm(out.world_from_cam, truth), 0.01);
}

// A re-entry candidate is confirmed by the next view near it, and dropped when the next view lies
// farther from it than the hand moves in one view.
TEST_F(RelocaliserTest, TheNextViewConfirmsOrDropsACandidate) {
  motion_.BeginView(view_ + 5, 0);
  relocaliser_.SetCandidate(view_ + 5, 0, Truth(-1), "test");
  motion_.BeginView(view_ + 6, 0);
  TrackResult out;
  ASSERT_TRUE(relocaliser_.Confirm(Samples(View(Truth(-0.6), 700)), true, &out)) << out.reason;
  EXPECT_FALSE(relocaliser_.candidate().pending);
  EXPECT_LT(TranslationDistanceMm(out.world_from_cam, Truth(-0.6)), 0.01);
  // A candidate 3.5 mm from where the next view really is (as if fitted onto similar ground).
  relocaliser_.SetCandidate(view_ + 6, 0, Truth(-4.0), "test");
  motion_.BeginView(view_ + 7, 0);
  TrackResult wrong;
  EXPECT_FALSE(relocaliser_.Confirm(Samples(View(Truth(-0.5), 701)), true, &wrong));
  EXPECT_FALSE(wrong.reason.empty());
  relocaliser_.DropCandidate();
  EXPECT_FALSE(relocaliser_.candidate().pending);
}

}  // namespace
}  // namespace d3d
