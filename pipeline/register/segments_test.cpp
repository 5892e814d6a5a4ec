#include "pipeline/register/segments.h"

#include <gtest/gtest.h>

#include "pipeline/register/test_surfaces.h"

namespace d3d {
namespace {

using namespace d3d::testing;

KeyframeGraphOptions PlainKeyframes() {
  KeyframeGraphOptions o;
  o.detect_loops = false;
  return o;
}

class SegmentsTest : public ::testing::Test {
 protected:
  SegmentsTest()
      : hf_(31),
        cam_(TestCamera()),
        odometry_(cam_, {}),
        keyframes_(PlainKeyframes(), DefaultTrackerIcp(), false) {}
  // View `view` of the true pose `truth`, placed at `pose` (its segment's frame) in the model and
  // the keyframes.
  void Place(const Rigid3d& truth, const Rigid3d& pose, int64_t view, int segment) {
    const SyntheticView v =
        RenderHeightField(hf_, cam_, truth, 0.004, static_cast<uint32_t>(view + 1));
    odometry_.Insert(v.points, v.normals, pose);
    TrackResult out;
    keyframes_.Update(v.points, v.normals, v.texture, pose, view, segment, &out);
  }
  // Main views looking down at x = −8 … 0 mm, then a segment started, with views at x = −4 … 4 mm
  // (y = 0.5) placed at their true poses moved by an error the join must find (1.2 mm, 4°) in the
  // segment's frame; `step_mm` apart. Returns segment_from_main; *view: the next view's number,
  // *first_segment_view and *main_keyframes (optional) what their names say.
  Rigid3d PlaceMainAndSegment(Segments* segments, double step_mm, int64_t* view,
                              int64_t* first_segment_view = nullptr,
                              int* main_keyframes = nullptr) {
    for (double x = -8; x <= 0.01; x += step_mm, ++*view)
      Place(LookDown(x, 0, 30), LookDown(x, 0, 30), *view, 0);
    if (main_keyframes) *main_keyframes = keyframes_.size();
    Rigid3d pose;
    TrackResult out;
    segments->Start(*view, LookDown(0, 0, 30), &pose, &out);
    Rigid3d error = Rigid3d::Identity();
    error.linear() = Eigen::AngleAxisd(4 * M_PI / 180, Eigen::Vector3d(0.2, 0.3, 1).normalized())
                         .toRotationMatrix();
    error.translation() = Eigen::Vector3d(1.0, -0.6, 0.3);
    const Rigid3d segment_from_main = segments->MainFromSegmentFrame(1).inverse() * error;
    if (first_segment_view) *first_segment_view = *view;
    for (double x = -4; x <= 4.01; x += step_mm, ++*view)
      Place(LookDown(x, 0.5, 30), segment_from_main * LookDown(x, 0.5, 30), *view, 1);
    return segment_from_main;
  }
  HeightField hf_;
  PinholeBrownConrady cam_;
  Odometry odometry_;
  KeyframeGraph keyframes_;
};

TEST(SegmentOptions, CheckRefusesWhatCannotWork) {
  EXPECT_NO_THROW(SegmentOptions().Check());
  SegmentOptions o;
  o.max_segments = 0;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = SegmentOptions();
  o.join_every = 0;
  EXPECT_THROW(o.Check(), std::invalid_argument);
}

// after_views refused views in a row, then the next starts a segment (up to max_segments), in a
// frame 2 m along x from the main one, apart until joined; undo does not reach back before it.
TEST_F(SegmentsTest, CountsRefusedViewsAndStartsASegmentApart) {
  SegmentOptions o;
  o.after_views = 2;
  o.max_segments = 2;
  Segments segments(o, &odometry_, &keyframes_, false);
  EXPECT_EQ(segments.size(), 1);
  EXPECT_TRUE(segments.InMain(0));
  EXPECT_FALSE(segments.JoinDue());  // the main segment never joins
  for (int64_t v = 0; v < 3; ++v)
    Place(LookDown(0.5 * static_cast<double>(v), 0, 30),
          LookDown(0.5 * static_cast<double>(v), 0, 30), v, 0);
  EXPECT_FALSE(segments.CountRefused());
  EXPECT_FALSE(segments.CountRefused());
  EXPECT_TRUE(segments.CountRefused());
  EXPECT_EQ(segments.refused_in_row(), 3);
  const Rigid3d last = LookDown(1, 0, 30);
  Rigid3d pose;
  TrackResult out;
  segments.Start(6, last, &pose, &out);
  EXPECT_TRUE(out.new_segment);
  EXPECT_EQ(out.state, TrackingState::kTracking);
  EXPECT_NE(out.reason.find("new segment 1 after 3 views"), std::string::npos) << out.reason;
  EXPECT_EQ(segments.size(), 2);
  EXPECT_EQ(segments.active(), 1);
  EXPECT_FALSE(segments.InMain(1));
  EXPECT_EQ(segments.refused_in_row(), 0);
  EXPECT_TRUE(segments.StartsAt(6));
  EXPECT_FALSE(segments.StartsAt(5));
  EXPECT_EQ(segments.undo_barrier_view(), 7);
  EXPECT_TRUE(pose.isApprox(segments.MainFromSegmentFrame(1).inverse() * last));
  EXPECT_DOUBLE_EQ(pose.translation().x() - last.translation().x(), kSegmentSpacingMm);
  EXPECT_EQ(SegmentOfPoint(pose.translation().cast<float>()), 1);
  EXPECT_FALSE(segments.KeyframeInActive(0));  // a main keyframe, and the track is apart
  // Full: no third segment.
  for (int i = 0; i < 4; ++i) EXPECT_FALSE(segments.CountRefused());
  // A join is due once the segment has a new keyframe, and once per join_every keyframes.
  EXPECT_FALSE(segments.JoinDue());
  Place(LookDown(1, 0, 30), pose, 7, 1);
  EXPECT_TRUE(segments.KeyframeInActive(keyframes_.size() - 1));
  EXPECT_TRUE(segments.JoinDue());
  EXPECT_FALSE(segments.JoinDue());
}

// A segment that overlaps the main model is found on it (FPFH + RANSAC + ICP) at the transform
// it was placed with, and the merge moves its keyframes and model samples into the main frame,
// with loop edges to the main keyframes.
TEST_F(SegmentsTest, FindsAndMergesASegmentThatOverlapsTheMainModel) {
  SegmentOptions o;
  o.join.min_correspondences = 300;  // the test's views are 9.6 × 7.2 mm
  Segments segments(o, &odometry_, &keyframes_, false);
  int64_t view = 0, first_segment_view = 0;
  int main_keyframes = 0;
  const Rigid3d segment_from_main =
      PlaceMainAndSegment(&segments, 0.5, &view, &first_segment_view, &main_keyframes);
  SegmentJoinResult join;
  int newest = -1;
  std::string how, why;
  ASSERT_TRUE(segments.FindJoin(1, false, &join, &newest, &how, &why)) << why;
  EXPECT_EQ(how, "fpfh");
  EXPECT_EQ(newest, keyframes_.size() - 1);
  // Judged where the surface is (the transform's own origin lies 2 m away, in the main frame).
  const Eigen::Vector3d on_surface = segment_from_main * Eigen::Vector3d(0, 0.5, 0);
  EXPECT_LT((join.main_from_segment * on_surface - Eigen::Vector3d(0, 0.5, 0)).norm(), 0.02);
  EXPECT_LT(RotationAngleRad(join.main_from_segment, segment_from_main.inverse()) * 180 / M_PI,
            0.05);
  const size_t edges = keyframes_.edges();
  segments.Merge(1, join.main_from_segment, newest, view);
  EXPECT_TRUE(segments.InMain(1));
  EXPECT_EQ(segments.joined(), 1);
  EXPECT_EQ(segments.undo_barrier_view(), view + 1);
  for (const Eigen::Vector3f& p : odometry_.model().points()) ASSERT_EQ(SegmentOfPoint(p), 0);
  for (int k = main_keyframes; k < keyframes_.size(); ++k) {
    const Keyframe& kf = keyframes_.keyframes()[static_cast<size_t>(k)];
    const Rigid3d truth =
        LookDown(-4 + 0.5 * static_cast<double>(kf.view - first_segment_view), 0.5, 30);
    EXPECT_LT(TranslationDistanceMm(keyframes_.world_from_keyframe(k), truth), 0.03)
        << "keyframe " << k;
  }
  ASSERT_GT(keyframes_.edges(), edges);
  for (size_t e = edges; e < keyframes_.edges(); ++e)
    EXPECT_TRUE(keyframes_.graph().edges()[e].loop);
}

// The end of the scan's last try describes both models again on finer keypoints: a segment whose
// coarse FPFH join cannot hold (here: its verification is made impossible) joins that way, at the
// placed transform, only at the end, and not with join_fine_at_end off.
class FineJoinAtTheEnd : public SegmentsTest, public ::testing::WithParamInterface<bool> {};

TEST_P(FineJoinAtTheEnd, JoinsWhatTheCoarseKeypointsDoNot) {
  const bool fine = GetParam();
  SegmentOptions o;
  o.join.min_correspondences = 300;
  o.join.fpfh.min_overlap = 1.0;  // the coarse FPFH's verification never passes
  o.join_starts_at_end = 0;
  o.join_fine_at_end = fine;
  Segments segments(o, &odometry_, &keyframes_, false);
  int64_t view = 0;
  const Rigid3d segment_from_main = PlaceMainAndSegment(&segments, 1.0, &view);
  SegmentJoinResult join;
  int newest = -1;
  std::string how, why;
  EXPECT_FALSE(segments.FindJoin(1, false, &join, &newest, &how, &why));
  EXPECT_EQ(why.find("fine fpfh"), std::string::npos) << why;  // not during the scan
  const bool joined = segments.FindJoin(1, true, &join, &newest, &how, &why);
  if (!fine) {
    EXPECT_FALSE(joined) << how;
    return;
  }
  ASSERT_TRUE(joined) << why;
  EXPECT_EQ(how, "fine fpfh");
  const Eigen::Vector3d on_surface = segment_from_main * Eigen::Vector3d(0, 0.5, 0);
  EXPECT_LT((join.main_from_segment * on_surface - Eigen::Vector3d(0, 0.5, 0)).norm(), 0.02);
  EXPECT_LT(RotationAngleRad(join.main_from_segment, segment_from_main.inverse()) * 180 / M_PI,
            0.05);
}
INSTANTIATE_TEST_SUITE_P(OnAndOff, FineJoinAtTheEnd, ::testing::Bool());

// A segment with nothing in common with the main model is not joined, and says why.
TEST_F(SegmentsTest, ASegmentApartFromTheModelIsNotJoined) {
  SegmentOptions o;
  o.join.min_correspondences = 300;
  Segments segments(o, &odometry_, &keyframes_, false);
  int64_t view = 0;
  for (double x = -20; x <= -14.99; x += 0.5, ++view)
    Place(LookDown(x, 0, 30), LookDown(x, 0, 30), view, 0);
  Rigid3d pose;
  TrackResult out;
  SegmentJoinResult join;
  int newest = -1;
  std::string how, why;
  EXPECT_FALSE(
      segments.FindJoin(1, false, &join, &newest, &how, &why));  // no such segment yet: empty
  EXPECT_EQ(why, "the segment is empty");
  segments.Start(view, LookDown(-15, 0, 30), &pose, &out);
  const Rigid3d segment_from_main = segments.MainFromSegmentFrame(1).inverse();
  for (double x = 14; x <= 19.01; x += 0.5, ++view)
    Place(LookDown(x, 0, 30), segment_from_main * LookDown(x, 0, 30), view, 1);
  EXPECT_FALSE(segments.FindJoin(1, false, &join, &newest, &how, &why));
  EXPECT_FALSE(why.empty());
  EXPECT_FALSE(segments.InMain(1));
}

}  // namespace
}  // namespace d3d
