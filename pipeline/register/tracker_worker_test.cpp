// The tracker's keyframe work off the track (the feature worker thread, features on demand,
// deferred pose-graph edges) gives the same scan as inline. Its own test binary: tools/test.sh
// builds and runs it under ThreadSanitizer without compiling the rest of the register tests.
#include <gtest/gtest.h>

#include <opencv2/core.hpp>

#include "pipeline/register/test_surfaces.h"
#include "pipeline/register/tracker.h"

namespace d3d {
namespace {

using namespace d3d::testing;

class TrackerWorker : public ::testing::Test {
 protected:
  // The strip of tracker_test.cpp's TrackerScan.
  Rigid3d Truth(double x, double y) const {
    return LookDown(x, y, 30, 0.05 * std::sin(x), 0.04 * std::cos(x), 0.02 * x);
  }
  HeightField hf_{31};
};

TEST_F(TrackerWorker, KeyframeWorkOffTrackGivesTheSameScan) {
  // The same views through a tracker that does its keyframe work inside Track() and through ones
  // that hand the features to the worker thread or extract them on demand, and leave the pose-graph
  // edges to Optimize(): every result is identical, the feature relocalisation (which waits for the
  // worker, or extracts the candidates' features) and the optimised poses included. On demand, no
  // keyframe has features before the loss, and only the relocalisation's candidates have them
  // after. OpenCV's own loops (SIFT) sequential here: they run on oneTBB's workers, whose
  // synchronisation ThreadSanitizer cannot see (tools/test.sh runs this test under it for the
  // worker thread's).
  struct SequentialOpenCv {
    int before = cv::getNumThreads();
    SequentialOpenCv() { cv::setNumThreads(0); }
    ~SequentialOpenCv() { cv::setNumThreads(before); }
  } sequential_opencv;
  TrackerOptions o;
  o.keyframes.features.max_features = 800;
  const PinholeBrownConrady cam =
      TestCamera(160, 120, 500);  // the fixture's field of view, 4× fewer pixels
  o.odometry.min_view_samples /= 4;
  o.relocaliser.feature_candidates = 2;
  using Timing = KeyframeGraphOptions::FeatureTiming;
  for (const Timing timing : {Timing::kWorker, Timing::kOnDemand}) {
    SCOPED_TRACE(timing == Timing::kWorker ? "features on the worker" : "features on demand");
    TrackerOptions oa = o;
    oa.keyframes.feature_timing = timing;
    oa.keyframes.defer_edges = true;
    Tracker inline_features(cam, o), off_track(cam, oa);
    std::vector<Rigid3d> path;
    for (double x = -3; x <= 3.01; x += 1.0) path.push_back(Truth(x, 0));
    const size_t lost_at = path.size();
    path.push_back(Truth(25, 0));      // off the model: lost
    path.push_back(Truth(-3.1, 0.4));  // back over the strip: a re-entry candidate, by features ...
    path.push_back(Truth(-2.8, 0.4));  // ... confirmed here
    path.push_back(Truth(-2.5, 0.4));
    bool by_features = false;
    for (size_t i = 0; i < path.size(); ++i) {
      if (timing == Timing::kOnDemand && i == lost_at) {
        for (const Keyframe& kf : off_track.keyframes()) {
          EXPECT_TRUE(kf.features_pending());
          EXPECT_EQ(kf.features.size(), 0u);
          EXPECT_FALSE(kf.packed_feature_texture.empty());  // the inputs are kept (packed)
        }
      }
      const auto v = RenderHeightField(hf_, cam, path[i], 0.004, static_cast<uint32_t>(i + 1));
      const TrackResult a = inline_features.Track(v.points, v.normals, v.quality, v.texture);
      const TrackResult b = off_track.Track(v.points, v.normals, v.quality, v.texture);
      EXPECT_EQ(a.accepted, b.accepted) << "view " << i;
      EXPECT_EQ(a.state, b.state) << "view " << i;
      EXPECT_EQ(a.reason, b.reason) << "view " << i;
      EXPECT_EQ(a.new_keyframe, b.new_keyframe) << "view " << i;
      EXPECT_EQ(b.loops_added, 0) << "view " << i;  // deferred
      EXPECT_TRUE(a.world_from_cam.matrix() == b.world_from_cam.matrix()) << "view " << i;
      by_features = by_features || b.reason.find("feature inliers") != std::string::npos;
    }
    EXPECT_TRUE(by_features) << "the path must exercise a feature relocalisation";
    EXPECT_EQ(off_track.state(), TrackingState::kTracking);
    ASSERT_EQ(inline_features.keyframes().size(), off_track.keyframes().size());
    if (timing == Timing::kOnDemand) {
      size_t extracted = 0;
      for (const Keyframe& kf : off_track.keyframes()) {
        EXPECT_EQ(kf.features_pending(), kf.features.size() == 0);
        if (!kf.features_pending()) {
          EXPECT_TRUE(kf.packed_feature_texture.empty());  // the inputs are freed
        }
        extracted += !kf.features_pending();
      }
      EXPECT_GE(extracted, 1u);
      EXPECT_LE(extracted, static_cast<size_t>(o.relocaliser.feature_candidates));
      EXPECT_LT(extracted, off_track.keyframes().size())
          << "the path must leave keyframes no relocalisation needed";
    }
    PoseGraphSummary sa, sb;
    ASSERT_TRUE(inline_features.Optimize({}, &sa).ok());
    ASSERT_TRUE(off_track.Optimize({}, &sb).ok());
    EXPECT_GT(inline_features.loop_edges(), 0) << "the path must close a loop";
    EXPECT_EQ(inline_features.loop_edges(), off_track.loop_edges());
    for (int64_t i = 0; i < inline_features.views(); ++i) {
      Rigid3d pa, pb;
      ASSERT_EQ(inline_features.ViewPose(i, &pa), off_track.ViewPose(i, &pb));
      EXPECT_TRUE(pa.matrix() == pb.matrix()) << "view " << i;
    }
  }
}

}  // namespace
}  // namespace d3d
