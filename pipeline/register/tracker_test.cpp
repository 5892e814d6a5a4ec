#include "pipeline/register/tracker.h"

#include <gtest/gtest.h>

#include <opencv2/core.hpp>

#include "pipeline/register/test_surfaces.h"

namespace d3d {
namespace {

using namespace d3d::testing;

class TrackerScan : public ::testing::Test {
 protected:
  TrackerScan() : hf_(31), cam_(TestCamera()) {}
  Rigid3d Truth(double x, double y) const {
    return LookDown(x, y, 30, 0.05 * std::sin(x), 0.04 * std::cos(x), 0.02 * x);
  }
  // A view at `pose` with depth noise σ = noise_mm.
  TrackResult Feed(Tracker* t, const Rigid3d& pose, uint32_t seed, double noise_mm = 0.004) {
    const auto v = RenderHeightField(hf_, cam_, pose, noise_mm, seed);
    return t->Track(v.points, v.normals, v.quality, v.texture);
  }
  // The same at the fixture's field of view with 4× fewer pixels (small_cam_; use
  // min_view_samples / 4).
  TrackResult FeedSmall(Tracker* t, const Rigid3d& pose, uint32_t seed) {
    const auto v = RenderHeightField(hf_, small_cam_, pose, 0.004, seed);
    return t->Track(v.points, v.normals, v.quality, v.texture);
  }
  HeightField hf_;
  PinholeBrownConrady cam_;
  PinholeBrownConrady small_cam_ = TestCamera(160, 120, 500);
  // Feed at Truth(x, 0) with *seed (then incremented); an accepted view's index and true pose go
  // to *accepted.
  TrackResult FeedAndKeep(Tracker* t, double x, uint32_t* seed,
                          std::vector<std::pair<int64_t, Rigid3d>>* accepted) {
    const Rigid3d pose = Truth(x, 0);
    const int64_t view = t->views();
    const TrackResult r = Feed(t, pose, (*seed)++);
    if (r.accepted) accepted->emplace_back(view, pose);
    return r;
  }
  void LostScanStartsASegmentThatJoins(const TrackerOptions& o, const std::string& joined_by);
  // Every accepted view in the main frame, at its true pose (the first view's camera as the
  // model's frame) within 0.05 mm / 0.1°.
  static void ExpectViewsAtTheirTruePoses(const Tracker& tracker,
                                          const std::vector<std::pair<int64_t, Rigid3d>>& truth) {
    const Rigid3d first_inv = truth.front().second.inverse();
    for (const auto& [view, pose] : truth) {
      Rigid3d p;
      ASSERT_TRUE(tracker.ViewPose(view, &p));
      EXPECT_TRUE(tracker.SegmentInMain(tracker.ViewSegment(view))) << "view " << view;
      const Rigid3d want = first_inv * pose;
      EXPECT_LT(TranslationDistanceMm(p, want), 0.05) << "view " << view;
      EXPECT_LT(RotationAngleRad(p, want) * 180 / M_PI, 0.1) << "view " << view;
    }
  }
};

TEST_F(TrackerScan, TracksAStripRefusesABadViewAndRelocalises) {
  TrackerOptions o;
  o.keyframes.features.max_features = 800;
  Tracker tracker(cam_, o);
  std::vector<Rigid3d> truth;
  uint32_t seed = 1;
  for (double x = -6; x <= 6.01; x += 1.0) {  // 1 mm steps over a 9.6 mm wide view
    truth.push_back(Truth(x, 0));
    const TrackResult r = Feed(&tracker, truth.back(), seed++);
    ASSERT_TRUE(r.accepted) << "x = " << x << ": " << r.reason;
    EXPECT_EQ(r.state, TrackingState::kTracking);
  }
  // Every accepted pose matches the truth expressed in the first camera's frame.
  const Rigid3d first_inv = truth[0].inverse();
  for (int64_t i = 0; i < tracker.views(); ++i) {
    Rigid3d p;
    ASSERT_TRUE(tracker.ViewPose(i, &p));
    const Rigid3d want = first_inv * truth[static_cast<size_t>(i)];
    // Drift over the 12-mm strip (translation at the camera centre, 30 mm from the surface).
    EXPECT_LT(TranslationDistanceMm(p, want), 0.02) << "view " << i;
    EXPECT_LT(RotationAngleRad(p, want) * 180 / M_PI, 0.04) << "view " << i;
  }
  EXPECT_GT(tracker.keyframes().size(), 3u);
  // A view of nothing: refused (not fused), the state is kept.
  cv::Mat empty(cam_.height, cam_.width, CV_32FC3, cv::Scalar::all(std::nanf("")));
  const TrackResult none = tracker.Track(empty, empty, cv::Mat(), cv::Mat());
  EXPECT_FALSE(none.accepted);
  EXPECT_NE(none.reason.find("too few points"), std::string::npos);
  // A view off the model: refused, lost.
  const TrackResult bad = Feed(&tracker, Truth(25, 0), 77);
  EXPECT_FALSE(bad.accepted);
  EXPECT_EQ(bad.state, TrackingState::kLost);
  EXPECT_FALSE(bad.reason.empty());
  // The probe comes back somewhere else over the scanned strip: placed by features, a re-entry
  // candidate that the next view confirms.
  const Rigid3d back = Truth(-3.1, 0.4);
  const TrackResult candidate = Feed(&tracker, back, 999);
  EXPECT_FALSE(candidate.accepted);
  EXPECT_EQ(candidate.state, TrackingState::kLost);
  EXPECT_NE(candidate.reason.find("re-entry candidate"), std::string::npos) << candidate.reason;
  const Rigid3d back2 = Truth(-2.9, 0.4);
  const TrackResult re = Feed(&tracker, back2, 1000);
  ASSERT_TRUE(re.accepted) << re.reason;
  EXPECT_EQ(re.state, TrackingState::kRelocalised);
  EXPECT_NE(re.reason.find("confirmed"), std::string::npos) << re.reason;
  EXPECT_LT(TranslationDistanceMm(re.world_from_cam, first_inv * back2), 0.02);
  // And keeps tracking from there.
  const TrackResult next = Feed(&tracker, Truth(-2.6, 0.4), 1001);
  ASSERT_TRUE(next.accepted) << next.reason;
  EXPECT_EQ(next.state, TrackingState::kTracking);
  EXPECT_EQ(tracker.state(), TrackingState::kTracking);
}

// A loss taken back (Tracker::RetractLoss, for a live host's gap bridge): after a view off the
// model, the state is what it was before it, so a view from between is tracked from the prediction
// and the track goes on; without one placed, ReinstateLoss leaves the tracker lost again. Neither
// applies twice, nor after a view that was not a loss of a held track.
TEST_F(TrackerScan, ALossTakenBackLetsAViewFromTheGapBeTrackedOrIsReinstated) {
  Tracker tracker(cam_, TrackerOptions{});
  uint32_t seed = 1;
  for (double x = -6; x <= 0.01; x += 1.0)
    ASSERT_TRUE(Feed(&tracker, Truth(x, 0), seed++).accepted);
  EXPECT_FALSE(tracker.RetractLoss()) << "the last view was placed";
  const TrackResult bad = Feed(&tracker, Truth(25, 0), 77);
  ASSERT_FALSE(bad.accepted);
  ASSERT_EQ(tracker.state(), TrackingState::kLost);
  ASSERT_TRUE(tracker.RetractLoss());
  EXPECT_EQ(tracker.state(), TrackingState::kTracking);
  EXPECT_FALSE(tracker.RetractLoss()) << "once";
  const TrackResult bridge = Feed(&tracker, Truth(1, 0), seed++);
  ASSERT_TRUE(bridge.accepted) << bridge.reason;
  EXPECT_EQ(bridge.state, TrackingState::kTracking) << "tracked, not a re-entry";
  EXPECT_TRUE(tracker.ReinstateLoss()) << "a retracted loss";
  EXPECT_EQ(tracker.state(), TrackingState::kTracking)
      << "a view was placed since: the loss stays taken back";
  EXPECT_FALSE(tracker.ReinstateLoss());
  // Nothing placed after the retraction: lost again, and what comes next is a re-entry.
  ASSERT_FALSE(Feed(&tracker, Truth(30, 0), 78).accepted);
  ASSERT_TRUE(tracker.RetractLoss());
  EXPECT_EQ(tracker.state(), TrackingState::kTracking);
  ASSERT_TRUE(tracker.ReinstateLoss());
  EXPECT_EQ(tracker.state(), TrackingState::kLost);
  // While lost, a refused view is no loss of a held track.
  ASSERT_FALSE(Feed(&tracker, Truth(35, 0), 79).accepted);
  EXPECT_FALSE(tracker.RetractLoss());
  EXPECT_EQ(tracker.state(), TrackingState::kLost);
}

// A re-entry after a loss is accepted only when two views in a row agree on it: a candidate that
// the next view contradicts (here the next view is 6 mm away, as when the first was fitted onto a
// similar part of the model elsewhere) is dropped and nothing is fused at it; that next view
// becomes the candidate in its turn. With confirm_reentry off, the first view re-enters at once.
TEST_F(TrackerScan, AReentryTheNextViewContradictsIsDropped) {
  for (const bool confirm : {true, false}) {
    TrackerOptions o;
    o.relocaliser.confirm_reentry = confirm;
    o.odometry.min_view_samples /= 4;
    Tracker tracker(small_cam_, o);
    std::vector<Rigid3d> truth;
    uint32_t seed = 1;
    for (double x = -4; x <= 4.01; x += 1.0) {
      truth.push_back(Truth(x, 0));
      ASSERT_TRUE(FeedSmall(&tracker, truth.back(), seed++).accepted) << "x = " << x;
    }
    const Rigid3d first_inv = truth[0].inverse();
    ASSERT_FALSE(FeedSmall(&tracker, Truth(25, 0), 77).accepted);  // off the model: lost
    ASSERT_EQ(tracker.state(), TrackingState::kLost);
    const TrackResult a = FeedSmall(&tracker, Truth(-3.1, 0.3), 100);
    if (!confirm) {
      ASSERT_TRUE(a.accepted) << a.reason;
      EXPECT_EQ(a.state, TrackingState::kRelocalised);
      continue;
    }
    EXPECT_FALSE(a.accepted) << a.reason;
    ASSERT_NE(a.reason.find("re-entry candidate"), std::string::npos) << a.reason;
    const Rigid3d far = Truth(2.9, 0.3);  // 6 mm from the candidate, one view later
    const TrackResult b = FeedSmall(&tracker, far, 101);
    EXPECT_FALSE(b.accepted) << b.reason;
    EXPECT_EQ(b.state, TrackingState::kLost);
    EXPECT_NE(b.reason.find("not confirmed"), std::string::npos) << b.reason;
    EXPECT_NE(b.reason.find("re-entry candidate"), std::string::npos) << b.reason;  // b in its turn
    const Rigid3d c_pose = Truth(3.1, 0.3);
    const TrackResult c = FeedSmall(&tracker, c_pose, 102);
    ASSERT_TRUE(c.accepted) << c.reason;
    EXPECT_EQ(c.state, TrackingState::kRelocalised);
    EXPECT_LT(TranslationDistanceMm(c.world_from_cam, first_inv * c_pose), 0.02);
    Rigid3d p;
    EXPECT_FALSE(tracker.ViewPose(tracker.views() - 3, &p));  // a: never accepted
    EXPECT_FALSE(tracker.ViewPose(tracker.views() - 2, &p));  // b: never accepted
  }
}

// "Undo last seconds": the views taken back leave the tracker as one that never saw them (the
// model sample for sample, keyframes, pose graph, kept poses), and the scan goes on from there.
TEST_F(TrackerScan, UndoLeavesTheTrackerAsIfTheViewsHadNeverComeAndTheScanGoesOn) {
  using Timing = KeyframeGraphOptions::FeatureTiming;
  for (const Timing timing : {Timing::kInTrack, Timing::kWorker, Timing::kOnDemand}) {
    SCOPED_TRACE(timing == Timing::kInTrack  ? "features in Track"
                 : timing == Timing::kWorker ? "features on the worker"
                                             : "features on demand");
    TrackerOptions o;
    o.odometry.min_view_samples /= 4;
    o.odometry.map.undo_inserts = 20;
    o.keyframes.feature_timing = timing;
    o.keyframes.max_views = 3;  // keyframes among the views taken back too
    Tracker all(small_cam_, o), kept(small_cam_, o);
    std::vector<Rigid3d> truth;
    uint32_t seed = 1;
    constexpr int kKept = 8, kViews = 14;
    for (int i = 0; i < kViews; ++i) {
      truth.push_back(Truth(-6 + 0.8 * i, 0.1 * i));
      ASSERT_TRUE(FeedSmall(&all, truth.back(), seed).accepted) << "view " << i;
      if (i < kKept) {
        ASSERT_TRUE(FeedSmall(&kept, truth.back(), seed).accepted) << "view " << i;
      }
      ++seed;
    }
    ASSERT_EQ(all.first_undoable_view(), 0);
    const int kf_before = static_cast<int>(all.keyframes().size());
    ASSERT_GT(kf_before, static_cast<int>(kept.keyframes().size()));
    const Tracker::UndoResult u = all.UndoFrom(kKept);
    ASSERT_TRUE(u.ok) << u.reason;
    EXPECT_EQ(u.views_undone, kViews - kKept);
    EXPECT_EQ(u.keyframes_undone, kf_before - static_cast<int>(kept.keyframes().size()));
    // The model: the same samples in the same order, bit for bit.
    ASSERT_EQ(all.model().size(), kept.model().size());
    EXPECT_TRUE(all.model().points() == kept.model().points());
    EXPECT_TRUE(all.model().normals() == kept.model().normals());
    EXPECT_TRUE(all.model().weights() == kept.model().weights());
    // Keyframes and pose graph.
    ASSERT_EQ(all.keyframes().size(), kept.keyframes().size());
    for (size_t k = 0; k < kept.keyframes().size(); ++k)
      EXPECT_EQ(all.keyframes()[k].view, kept.keyframes()[k].view);
    ASSERT_EQ(all.graph().num_nodes(), kept.graph().num_nodes());
    ASSERT_EQ(all.graph().edges().size(), kept.graph().edges().size());
    for (size_t e = 0; e < kept.graph().edges().size(); ++e) {
      EXPECT_EQ(all.graph().edges()[e].from, kept.graph().edges()[e].from);
      EXPECT_EQ(all.graph().edges()[e].to, kept.graph().edges()[e].to);
    }
    for (int64_t v = 0; v < kViews; ++v) {
      Rigid3d a, b;
      const bool have = all.ViewPose(v, &a);
      EXPECT_EQ(have, v < kKept) << "view " << v;
      if (have && kept.ViewPose(v, &b)) {
        EXPECT_TRUE(a.matrix() == b.matrix()) << "view " << v;
      }
    }
    EXPECT_EQ(all.state(), TrackingState::kLost);
    // The probe is back over the kept part: a re-entry, confirmed by the next view, then tracking.
    const Rigid3d first_inv = truth[0].inverse();
    int accepted = 0;
    for (int i = 0; i < 6; ++i) {
      const Rigid3d pose = Truth(-0.6 + 0.5 * i, 0.4);
      const TrackResult r = FeedSmall(&all, pose, 200 + i);
      if (i == 0) {
        EXPECT_FALSE(r.accepted);
        EXPECT_NE(r.reason.find("re-entry candidate"), std::string::npos) << r.reason;
        continue;
      }
      ASSERT_TRUE(r.accepted) << "view " << i << ": " << r.reason;
      EXPECT_EQ(r.state, i == 1 ? TrackingState::kRelocalised : TrackingState::kTracking);
      EXPECT_LT(TranslationDistanceMm(r.world_from_cam, first_inv * pose), 0.02) << "view " << i;
      ++accepted;
    }
    EXPECT_EQ(accepted, 5);
    PoseGraphSummary summary;
    EXPECT_TRUE(all.Optimize({}, &summary).ok());
  }
}

TEST_F(TrackerScan, UndoReachesAsFarAsTheJournalAndEverythingMeansANewStart) {
  TrackerOptions o;
  o.odometry.min_view_samples /= 4;
  o.odometry.map.undo_inserts = 3;
  Tracker tracker(small_cam_, o);
  uint32_t seed = 1;
  for (int i = 0; i < 6; ++i)
    ASSERT_TRUE(FeedSmall(&tracker, Truth(-3 + 0.8 * i, 0), seed++).accepted);
  EXPECT_EQ(tracker.first_undoable_view(), 3);
  const size_t samples = tracker.model().size();
  const Tracker::UndoResult beyond = tracker.UndoFrom(2);
  EXPECT_FALSE(beyond.ok);
  EXPECT_FALSE(beyond.reason.empty());
  EXPECT_EQ(tracker.model().size(), samples);  // nothing changed
  EXPECT_EQ(tracker.state(), TrackingState::kTracking);
  EXPECT_FALSE(tracker.UndoFrom(7).ok);
  // All of a scan's views (its journal reaches the first): an empty model, and the next view
  // starts a new one.
  TrackerOptions deep = o;
  deep.odometry.map.undo_inserts = 10;
  Tracker fresh(small_cam_, deep);
  for (int i = 0; i < 4; ++i)
    ASSERT_TRUE(FeedSmall(&fresh, Truth(-3 + 0.8 * i, 0), seed++).accepted);
  const Tracker::UndoResult all = fresh.UndoFrom(0);
  ASSERT_TRUE(all.ok) << all.reason;
  EXPECT_EQ(all.views_undone, 4);
  EXPECT_TRUE(fresh.model().empty());
  EXPECT_TRUE(fresh.keyframes().empty());
  EXPECT_EQ(fresh.graph().num_nodes(), 0);
  EXPECT_EQ(fresh.state(), TrackingState::kInitialising);
  const TrackResult r = FeedSmall(&fresh, Truth(2, 0), seed++);
  ASSERT_TRUE(r.accepted) << r.reason;
  EXPECT_TRUE(r.world_from_cam.matrix().isApprox(Rigid3d::Identity().matrix()));
  EXPECT_EQ(fresh.views(), 5);
}

// One bad view in a track that never left (reentry_direct_max_views): the next view, found by ICP
// from the motion prediction, resumes the track at once; with the rule off it is only a candidate.
TEST_F(TrackerScan, AfterOneBadViewTheTrackResumesFromThePrediction) {
  for (const double direct : {2.0, 0.0}) {
    SCOPED_TRACE(direct);
    TrackerOptions o;
    o.odometry.min_view_samples /= 4;
    o.relocaliser.direct_max_views = direct;
    Tracker tracker(small_cam_, o);
    uint32_t seed = 1;
    std::vector<Rigid3d> truth;
    for (int i = 0; i < 8; ++i) {
      truth.push_back(Truth(-4 + 0.8 * i, 0));
      ASSERT_TRUE(FeedSmall(&tracker, truth.back(), seed++).accepted) << i;
    }
    ASSERT_FALSE(FeedSmall(&tracker, Truth(25, 0), 77).accepted);  // a bad view: lost
    ASSERT_EQ(tracker.state(), TrackingState::kLost);
    const Rigid3d next = Truth(-4 + 0.8 * 9, 0);  // where the probe was going
    const TrackResult r = FeedSmall(&tracker, next, seed++);
    if (direct == 0) {
      EXPECT_FALSE(r.accepted);
      EXPECT_NE(r.reason.find("re-entry candidate (icp from the predicted pose)"),
                std::string::npos)
          << r.reason;
      continue;
    }
    ASSERT_TRUE(r.accepted) << r.reason;
    EXPECT_EQ(r.state, TrackingState::kRelocalised);
    EXPECT_NE(r.reason.find("icp from the predicted pose"), std::string::npos) << r.reason;
    EXPECT_LT(TranslationDistanceMm(r.world_from_cam, truth[0].inverse() * next), 0.02);
    // Two bad views: more than 2 views since the last accepted one, a candidate again.
    ASSERT_FALSE(FeedSmall(&tracker, Truth(25, 0), 78).accepted);
    ASSERT_FALSE(FeedSmall(&tracker, Truth(26, 0), 79).accepted);
    const TrackResult c = FeedSmall(&tracker, Truth(-4 + 0.8 * 12, 0), seed++);
    EXPECT_FALSE(c.accepted) << c.reason;
    EXPECT_NE(c.reason.find("re-entry candidate"), std::string::npos) << c.reason;
  }
}

TEST_F(TrackerScan, ADeferredModelInsertGivesTheSameScan) {
  // defer_model_insert: Track leaves the accepted view's insert pending; CommitView runs it (the
  // host, once the view has gone to the preview), else the next Track or UndoFrom does. The same
  // views, with an undo and a view lost off the model among them, give the same poses, model and
  // undo as inserting at once, whether each view is committed or left to the next Track.
  TrackerOptions o;
  o.odometry.map.undo_inserts = 10;
  o.odometry.min_view_samples /= 4;
  TrackerOptions od = o;
  od.odometry.defer_model_insert = true;
  Tracker now(small_cam_, o), committed(small_cam_, od), left(small_cam_, od);
  std::vector<Rigid3d> path;
  for (double x = -3; x <= 3.01; x += 0.5) path.push_back(Truth(x, 0.1 * x));
  path.push_back(Truth(25, 0));  // off the model: refused, nothing pending
  path.push_back(Truth(3.2, 0.3));
  const size_t undo_after = 8;
  for (size_t i = 0; i < path.size(); ++i) {
    const auto v = RenderHeightField(hf_, small_cam_, path[i], 0.004, static_cast<uint32_t>(i + 1));
    const TrackResult a = now.Track(v.points, v.normals, v.quality, v.texture);
    const size_t before = committed.model().size();
    const TrackResult b = committed.Track(v.points, v.normals, v.quality, v.texture);
    EXPECT_EQ(committed.insert_pending(), b.accepted && b.in_model) << "view " << i;
    EXPECT_EQ(committed.model().size(), before)
        << "view " << i << ": the insert waits for CommitView";
    committed.CommitView();
    EXPECT_FALSE(committed.insert_pending());
    const TrackResult c = left.Track(v.points, v.normals, v.quality, v.texture);
    for (const TrackResult* r : {&b, &c}) {
      EXPECT_EQ(a.accepted, r->accepted) << "view " << i;
      EXPECT_EQ(a.state, r->state) << "view " << i;
      EXPECT_EQ(a.new_keyframe, r->new_keyframe) << "view " << i;
      EXPECT_TRUE(a.world_from_cam.matrix() == r->world_from_cam.matrix()) << "view " << i;
    }
    EXPECT_EQ(now.model().points(), committed.model().points()) << "view " << i;
    if (i == undo_after) {
      ASSERT_TRUE(left.insert_pending());
      const Tracker::UndoResult ua = now.UndoFrom(now.views() - 3),
                                uc = left.UndoFrom(left.views() - 3);
      ASSERT_TRUE(ua.ok && uc.ok) << ua.reason << " / " << uc.reason;
      (void)committed.UndoFrom(committed.views() - 3);
      EXPECT_EQ(now.model().points(), left.model().points())
          << "the pending insert ran before the undo";
    }
  }
  left.CommitView();
  EXPECT_EQ(now.model().points(), left.model().points());
  EXPECT_EQ(now.model().normals(), left.model().normals());
  EXPECT_EQ(now.model().inserts(), left.model().inserts());
  EXPECT_EQ(now.keyframes().size(), left.keyframes().size());
  EXPECT_GT(now.model().size(), 0u);
}

TEST_F(TrackerScan, UnevenlySpacedViewsAreTrackedByCaptureTime) {
  // A live host takes the newest burst whenever it is free: here the probe moves 1 mm per 33 ms
  // and the views come 1 or 4 bursts apart. By capture time (view_period_ns) the motion prediction
  // is exact and a 4 mm step is 4 views' worth of motion; counted in views it is neither.
  TrackerOptions o;
  o.relocaliser.by_features = false;
  o.keyframes.detect_loops = false;
  const PinholeBrownConrady cam =
      TestCamera(160, 120, 500);  // the fixture's field of view, 4× fewer pixels
  o.odometry.min_view_samples /= 4;
  const int64_t burst_ns = 33'333'333;
  TrackerOptions timed = o;
  timed.motion.view_period_ns = burst_ns;
  Tracker by_views(cam, o), by_time(cam, timed);
  const std::vector<int> bursts = {0, 1, 2, 6, 7, 11, 12, 13};
  auto truth = [](int burst) {
    return LookDown(-6.0 + burst, 0, 30, 0.05, 0.04, 0.1 + 0.01 * burst);
  };  // constant velocity
  int not_tracked_by_views = 0;
  for (size_t i = 0; i < bursts.size(); ++i) {
    const auto v =
        RenderHeightField(hf_, cam, truth(bursts[i]), 0.004, static_cast<uint32_t>(i + 1));
    const int64_t capture_ns = 1'000'000'000 + bursts[i] * burst_ns;
    const TrackResult t = by_time.Track(v.points, v.normals, v.quality, v.texture, {}, capture_ns);
    EXPECT_TRUE(t.accepted) << "burst " << bursts[i] << ": " << t.reason;
    EXPECT_EQ(t.state, TrackingState::kTracking) << "burst " << bursts[i] << ": " << t.reason;
    const TrackResult n = by_views.Track(v.points, v.normals, v.quality, v.texture, {}, capture_ns);
    not_tracked_by_views += !(n.accepted && n.state == TrackingState::kTracking);
  }
  EXPECT_GT(not_tracked_by_views, 0);
  Rigid3d p;
  ASSERT_TRUE(by_time.ViewPose(by_time.views() - 1, &p));
  EXPECT_LT(TranslationDistanceMm(p, truth(0).inverse() * truth(bursts.back())), 0.02);
}

TEST_F(TrackerScan, ProjectiveAssociationTracksToo) {
  TrackerOptions o;
  o.odometry.association = Association::kProjective;
  o.relocaliser.by_features = false;
  o.keyframes.detect_loops = false;
  o.odometry.min_view_samples /= 4;
  Tracker tracker(small_cam_, o);
  std::vector<Rigid3d> truth;
  uint32_t seed = 1;
  for (double x = -3; x <= 3.01; x += 0.5) {
    truth.push_back(Truth(x, 0.2));
    const TrackResult r = FeedSmall(&tracker, truth.back(), seed++);
    ASSERT_TRUE(r.accepted) << r.reason;
  }
  Rigid3d p;
  ASSERT_TRUE(tracker.ViewPose(tracker.views() - 1, &p));
  EXPECT_LT(TranslationDistanceMm(p, truth[0].inverse() * truth.back()), 0.02);
}

TEST_F(TrackerScan, AJumpBeyondTheModelIsRefused) {
  TrackerOptions o;
  Tracker tracker(cam_, o);
  for (double x = 0; x <= 1.01; x += 0.5) ASSERT_TRUE(Feed(&tracker, Truth(x, 0), 1).accepted);
  const TrackResult r = Feed(&tracker, Truth(20, 0), 2);  // nothing of the model in view
  EXPECT_FALSE(r.accepted);
  EXPECT_EQ(r.state, TrackingState::kLost);
  EXPECT_NE(r.reason.find("icp"), std::string::npos) << r.reason;
}

TEST_F(TrackerScan, ALostTrackReentersOnlyAtTheRelocalisationResidual) {
  // A noisy view (σ 55–65 µm: ICP residual between the relocalisation limit, 40 µm, and tracking's)
  // continues a track from the predicted pose, but does not re-enter the model through the local
  // search once the track is lost; a clean view at the same place does.
  TrackerOptions o;
  o.relocaliser.by_features = false;  // the local search only
  Tracker tracker(cam_, o);
  for (double x = 0; x <= 2.01; x += 0.5) ASSERT_TRUE(Feed(&tracker, Truth(x, 0), 1).accepted);
  const TrackResult tracked = Feed(&tracker, Truth(2.2, 0), 2, 0.055);
  ASSERT_TRUE(tracked.accepted) << tracked.reason;
  EXPECT_GT(tracked.icp.rmse_mm, o.relocaliser.max_rmse_mm);
  EXPECT_LT(tracked.icp.rmse_mm, o.odometry.icp.max_rmse_mm);
  ASSERT_FALSE(Feed(&tracker, Truth(20, 0), 3).accepted);  // off the model: lost
  ASSERT_EQ(tracker.state(), TrackingState::kLost);
  const TrackResult refused = Feed(&tracker, Truth(2.3, 0), 4, 0.065);
  EXPECT_FALSE(refused.accepted) << refused.reason << " rmse " << refused.icp.rmse_mm;
  EXPECT_EQ(refused.state, TrackingState::kLost);
  // Refused for its residual, which tracking's limit would have let through.
  const std::string high = "high residual (rmse ";
  const size_t at = refused.reason.find(high);
  ASSERT_NE(at, std::string::npos) << refused.reason;
  const double rmse_um = std::stod(refused.reason.substr(at + high.size()));
  EXPECT_GT(rmse_um, 1000 * o.relocaliser.max_rmse_mm);
  EXPECT_LT(rmse_um, 1000 * o.odometry.icp.max_rmse_mm);
  const TrackResult candidate = Feed(&tracker, Truth(2.3, 0), 5);
  EXPECT_FALSE(candidate.accepted);
  EXPECT_NE(candidate.reason.find("re-entry candidate (icp from"), std::string::npos)
      << candidate.reason;
  const TrackResult back = Feed(&tracker, Truth(2.4, 0), 6);  // confirms it
  ASSERT_TRUE(back.accepted) << back.reason;
  EXPECT_EQ(back.state, TrackingState::kRelocalised);
}

// Segments: a probe put down over ground the model has not seen (a lift-out) starts a segment of
// its own after segment_after_views views that cannot be placed; once its model overlaps the main
// one, it is joined (`joined_by`: the join's account starts "joined by <joined_by>"), and every
// view ends where it belongs.
void TrackerScan::LostScanStartsASegmentThatJoins(const TrackerOptions& o,
                                                  const std::string& joined_by) {
  Tracker tracker(cam_, o);
  std::vector<std::pair<int64_t, Rigid3d>> truth;  // accepted views
  uint32_t seed = 1;
  auto feed = [&](double x) { return FeedAndKeep(&tracker, x, &seed, &truth); };
  for (double x = -20; x <= -12.99; x += 1.0) ASSERT_TRUE(feed(x).accepted);
  // Put down 17 mm further on: no view there overlaps the model.
  int refused = 0, started = 0;
  for (double x = 5; x >= -0.01; x -= 1.0) {
    const TrackResult r = feed(x);
    refused += !r.accepted;
    if (started > 0 && !r.new_segment) {
      // Tracked from the segment's own motion: no velocity carried from the main frame, 2 m away
      // (the local search would recover such a view, as a re-entry).
      EXPECT_EQ(r.state, TrackingState::kTracking) << "x = " << x << ": " << r.reason;
    }
    if (r.new_segment) {
      ++started;
      EXPECT_TRUE(r.accepted);
      EXPECT_EQ(r.segment, 1);
      EXPECT_FALSE(r.in_main);
    }
  }
  EXPECT_EQ(refused, o.segments.after_views);
  EXPECT_EQ(started, 1);
  ASSERT_EQ(tracker.segments(), 2);
  EXPECT_EQ(tracker.segments_joined(), 0);
  // Back over the main model's ground: the segment joins, and its views are the main model's.
  bool joined = false;
  for (double x = -1; x >= -18.01; x -= 1.0) {
    const TrackResult r = feed(x);
    ASSERT_TRUE(r.accepted) << "x = " << x << ": " << r.reason;
    if (r.segment_joined) {
      EXPECT_EQ(r.join_attempt.rfind("joined by " + joined_by, 0), 0u) << r.join_attempt;
    }
    joined = joined || r.segment_joined;
    if (joined) {
      EXPECT_TRUE(r.in_main);
    }
  }
  EXPECT_TRUE(joined);
  EXPECT_EQ(tracker.segments_joined(), 1);
  PoseGraphSummary summary;
  ASSERT_TRUE(tracker.Optimize({}, &summary).ok());
  ExpectViewsAtTheirTruePoses(tracker, truth);
}

TrackerOptions SegmentTestOptions() {
  TrackerOptions o;
  o.keyframes.features.max_features = 800;
  o.segments.after_views = 3;
  o.segments.join.min_correspondences = 300;  // the test's views are 9.6 × 7.2 mm
  return o;
}

TEST_F(TrackerScan, ALostScanStartsASegmentThatJoinsWhenItOverlaps) {
  TrackerOptions o = SegmentTestOptions();
  o.segments.join_feature_keyframes = 0;  // FPFH alone
  LostScanStartsASegmentThatJoins(o, "fpfh");
}

TEST_F(TrackerScan, ASegmentFpfhCannotPlaceJoinsByKeyframeFeatures) {
  TrackerOptions o = SegmentTestOptions();
  o.segments.join.fpfh.min_overlap =
      1.0;  // FPFH's verification never passes: the features must join
  LostScanStartsASegmentThatJoins(o, "features");
}

// A segment after 2 views that cannot be placed.
TrackerOptions QuickSegmentOptions() {
  TrackerOptions o;
  o.keyframes.features.max_features = 800;
  o.segments.after_views = 2;
  return o;
}

TEST_F(TrackerScan, UndoneRefusedViewsDoNotCountTowardASegment) {
  TrackerOptions o = QuickSegmentOptions();
  o.odometry.map.undo_inserts = 16;
  Tracker tracker(cam_, o);
  uint32_t seed = 1;
  for (double x = -24; x <= -19.99; x += 1.0)
    ASSERT_TRUE(Feed(&tracker, Truth(x, 0), seed++).accepted);
  const int64_t first_off = tracker.views();
  for (double x = 10; x <= 11.01; x += 1.0)
    EXPECT_FALSE(Feed(&tracker, Truth(x, 0), seed++).accepted);
  ASSERT_TRUE(tracker.UndoFrom(first_off).ok);
  // As if the two had never come: two more refused views, and only the third starts a segment.
  for (double x = 12; x <= 13.01; x += 1.0)
    EXPECT_FALSE(Feed(&tracker, Truth(x, 0), seed++).accepted);
  EXPECT_EQ(tracker.segments(), 1);
  const TrackResult third = Feed(&tracker, Truth(14, 0), seed++);
  EXPECT_TRUE(third.new_segment);
  EXPECT_EQ(tracker.segments(), 2);
}

// The probe put back over the ground the scan began on, far from where it was lifted, and moved
// on from there over new ground (a quadrant started again from the incisors): the relocaliser looks
// near the lift, FPFH and the features find nothing here, so the segment grows apart. At the end of
// the scan its first keyframe, put where each main keyframe's camera was, is held by ICP and the
// segment joins, at the true poses.
TEST_F(TrackerScan, ASegmentBackOnTheScansFirstGroundJoinsAtTheEndFromAKeyframeStart) {
  TrackerOptions o = SegmentTestOptions();
  o.segments.join.fpfh.min_overlap = 1.0;  // FPFH's verification never passes
  o.segments.join_feature_keyframes = 0;
  o.relocaliser.by_features = false;
  Tracker tracker(cam_, o);
  std::vector<std::pair<int64_t, Rigid3d>> truth;  // accepted views
  uint32_t seed = 1;
  auto feed = [&](double x) { return FeedAndKeep(&tracker, x, &seed, &truth); };
  for (double x = -20; x <= -12.99; x += 1.0) ASSERT_TRUE(feed(x).accepted);
  // Lifted at -13, put back at -20 and moved away from the model.
  for (double x = -20; x >= -30.01; x -= 1.0) feed(x);
  ASSERT_EQ(tracker.segments(), 2);
  ASSERT_FALSE(tracker.SegmentInMain(1));
  std::vector<std::string> attempts;
  EXPECT_EQ(tracker.JoinApartSegments(&attempts), 1);
  ASSERT_TRUE(tracker.SegmentInMain(1)) << ::testing::PrintToString(attempts);
  PoseGraphSummary summary;
  ASSERT_TRUE(tracker.Optimize({}, &summary).ok());
  ExpectViewsAtTheirTruePoses(tracker, truth);
  int segment_views = 0;
  for (const auto& [view, pose] : truth) segment_views += tracker.ViewSegment(view) == 1;
  EXPECT_GE(segment_views, 5);
}

// Two segments apart at the end (no join tried while scanning): the first, put down 17 mm beyond
// the model, meets only the second, put back on the model and moved on over the first's ground.
// The last try joins the second, then tries the first again, which now meets ground in the main
// model and joins: every view at its true pose.
TEST_F(TrackerScan, ASegmentThatMeetsOnlyAnotherJoinsOnTheEndsNextRound) {
  TrackerOptions o = SegmentTestOptions();
  o.segments.join_every = 1000;  // no join while scanning
  o.segments.join_feature_keyframes = 0;
  o.relocaliser.by_features = false;
  Tracker tracker(cam_, o);
  std::vector<std::pair<int64_t, Rigid3d>> truth;  // accepted views
  uint32_t seed = 1;
  auto feed = [&](double x) { return FeedAndKeep(&tracker, x, &seed, &truth); };
  for (double x = -20; x <= -12.99; x += 1.0) ASSERT_TRUE(feed(x).accepted);
  for (double x = 10; x <= 16.01; x += 1.0) feed(x);   // segment 1
  for (double x = -16; x <= 13.01; x += 1.0) feed(x);  // segment 2
  ASSERT_EQ(tracker.segments(), 3);
  ASSERT_FALSE(tracker.SegmentInMain(1));
  ASSERT_FALSE(tracker.SegmentInMain(2));
  std::vector<std::string> attempts;
  EXPECT_EQ(tracker.JoinApartSegments(&attempts), 2) << ::testing::PrintToString(attempts);
  ASSERT_TRUE(tracker.SegmentInMain(1) && tracker.SegmentInMain(2))
      << ::testing::PrintToString(attempts);
  ASSERT_EQ(attempts.size(), 3u) << ::testing::PrintToString(attempts);
  EXPECT_EQ(attempts[2].rfind("segment 1, again: joined", 0), 0u) << attempts[2];
  PoseGraphSummary summary;
  ASSERT_TRUE(tracker.Optimize({}, &summary).ok());
  ExpectViewsAtTheirTruePoses(tracker, truth);
}

TEST_F(TrackerScan, ASegmentThatNeverOverlapsStaysApart) {
  Tracker tracker(cam_, QuickSegmentOptions());
  uint32_t seed = 1;
  for (double x = -24; x <= -19.99; x += 1.0)
    ASSERT_TRUE(Feed(&tracker, Truth(x, 0), seed++).accepted);
  const int64_t first_apart = tracker.views();
  for (double x = 10; x <= 16.01; x += 1.0) Feed(&tracker, Truth(x, 0), seed++);
  ASSERT_EQ(tracker.segments(), 2);
  EXPECT_EQ(tracker.JoinApartSegments(), 0);
  EXPECT_FALSE(tracker.SegmentInMain(1));
  int apart = 0;
  for (int64_t v = first_apart; v < tracker.views(); ++v) {
    Rigid3d p;
    if (!tracker.ViewPose(v, &p)) continue;
    EXPECT_EQ(tracker.ViewSegment(v), 1);
    EXPECT_GT(p.translation().x(), 1000.0);  // in the segment's own frame, far from the main model
    ++apart;
  }
  EXPECT_EQ(apart, 5);  // 7 views, the first 2 refused
  // Undo cannot reach back into the segment's start.
  EXPECT_GE(tracker.first_undoable_view(), first_apart + 3);
  // Lost again, over ground neither has seen: a second segment, in a frame of its own too (2 m
  // per segment from the main one, whichever segment the track left).
  const int64_t first_second = tracker.views();
  for (double x = -6; x <= -3.99; x += 1.0) Feed(&tracker, Truth(x, 0), seed++);
  ASSERT_EQ(tracker.segments(), 3);
  int second = 0;
  for (int64_t v = first_second; v < tracker.views(); ++v) {
    Rigid3d p;
    if (!tracker.ViewPose(v, &p)) continue;
    EXPECT_EQ(tracker.ViewSegment(v), 2);
    EXPECT_NEAR(p.translation().x(), 4000.0, 100.0);
    ++second;
  }
  EXPECT_GE(second, 1);
  PoseGraphSummary summary;
  EXPECT_TRUE(tracker.Optimize({}, &summary).ok());
}

// A new segment's views are compared with each other by the map gate (map_max_rmse_ratio), not
// with the residuals of the model the track left: here the segment's views are noisier (σ 12 µm
// against 4) and fit their young model worse than the main model's views fitted theirs; compared
// with those, two of every three stayed out of the model and it stopped growing where the probe
// went.
TEST_F(TrackerScan, ANewSegmentsViewsAreGatedAgainstTheirOwnResiduals) {
  Tracker tracker(cam_, QuickSegmentOptions());
  uint32_t seed = 1;
  for (double x = -26; x <= -16.99; x += 1.0)
    ASSERT_TRUE(Feed(&tracker, Truth(x, 0), seed++).accepted);
  int segment_views = 0, out_of_model = 0;
  bool started = false;
  for (double x = 10; x <= 14.01; x += 0.5) {
    const TrackResult r = Feed(&tracker, Truth(x, 0), seed++, 0.012);
    started = started || r.new_segment;
    if (!started || !r.accepted) continue;
    ++segment_views;
    out_of_model += !r.in_model;
  }
  ASSERT_EQ(tracker.segments(), 2);
  EXPECT_GE(segment_views, 6);
  EXPECT_EQ(out_of_model, 0);
}

// Keyframe odometry measured by ICP between the keyframes' own samples, not taken from the
// drifting tracked poses: a chain of views with an injected drift (every step turns 0.05° and
// advances 11 µm too far, as a biased frame-to-model registration would) is straightened by the
// pose graph of measured edges (consecutive and second neighbours).
TEST_F(TrackerScan, NearLoopsCarryTheirFactorOfTheInformation) {
  // The same views through trackers with near_loop_information_factor 1 and 0.25: the same edges,
  // and only the loops to recent keyframes (fewer than loop_min_separation back) weigh a quarter.
  TrackerOptions o;
  o.odometry.min_view_samples /= 4;
  o.keyframes.overlap = 0.85;           // a keyframe every ~1.5 mm
  o.keyframes.loop_min_separation = 3;  // a short strip there and back has both kinds of loop
  o.keyframes.near_loop_information_factor = 1;
  TrackerOptions oq = o;
  oq.keyframes.near_loop_information_factor = 0.25;
  Tracker full(small_cam_, o), quarter(small_cam_, oq);
  std::vector<Rigid3d> path;
  for (double x = -4; x <= 4.01; x += 0.5) path.push_back(Truth(x, 0));
  for (double x = 4; x >= -4.01; x -= 0.5) path.push_back(Truth(x, 1.5));
  for (size_t i = 0; i < path.size(); ++i) {
    const auto v = RenderHeightField(hf_, small_cam_, path[i], 0.004, static_cast<uint32_t>(i + 1));
    ASSERT_TRUE(full.Track(v.points, v.normals, v.quality, v.texture).accepted) << "view " << i;
    ASSERT_TRUE(quarter.Track(v.points, v.normals, v.quality, v.texture).accepted) << "view " << i;
  }
  const auto& a = full.graph().edges();
  const auto& b = quarter.graph().edges();
  ASSERT_EQ(a.size(), b.size());
  int near = 0, far = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a[i].from, b[i].from);
    ASSERT_EQ(a[i].to, b[i].to);
    ASSERT_EQ(a[i].loop, b[i].loop);
    EXPECT_TRUE(a[i].from_from_to.matrix() == b[i].from_from_to.matrix()) << "edge " << i;
    const bool is_near = a[i].loop && a[i].to - a[i].from < o.keyframes.loop_min_separation;
    near += is_near;
    far += a[i].loop && !is_near;
    const double f = is_near ? 0.25 : 1.0;
    EXPECT_LE((b[i].information - f * a[i].information).norm(), 1e-9 * a[i].information.norm())
        << "edge " << i;
    // An odometry edge whose keyframe ICP failed is on σs (no information).
    EXPECT_NEAR(b[i].sigma_translation_mm, a[i].sigma_translation_mm / std::sqrt(f), 1e-12)
        << "edge " << i;
    EXPECT_NEAR(b[i].sigma_rotation_rad, a[i].sigma_rotation_rad / std::sqrt(f), 1e-12)
        << "edge " << i;
    if (a[i].loop) {
      EXPECT_GT(a[i].information.norm(), 0) << "edge " << i;
    }
  }
  std::printf("[ loops    ] %zu keyframes, %d near and %d far loops\n", full.keyframes().size(),
              near, far);
  EXPECT_GT(near, 0) << "the strip must make near loops";
  EXPECT_GT(far, 0) << "the strip must make far loops";
  EXPECT_THROW(
      [] {
        TrackerOptions bad;
        bad.keyframes.near_loop_information_factor = 0;
        bad.Check();
      }(),
      std::invalid_argument);
}

// Loop correction (TrackerOptions::loop_correction) with every optimisation moving the model
// (min_shift_mm 0): a strip there and back closes loops on the way back, each moves the tracking
// model's samples with their keyframes, and the scan goes on as without it: every view placed, the
// final poses as true, and the model's samples still on the surface in the frame of the poses.
// With the keyframes' edges measured as they come and deferred to Optimize (the live profile).
TEST_F(TrackerScan, ALoopCorrectedDuringTheScanMovesTheModelWithItsKeyframes) {
  TrackerOptions o;
  o.odometry.min_view_samples /= 4;
  o.keyframes.overlap = 0.85;
  o.keyframes.loop_min_separation = 3;
  std::vector<Rigid3d> path;
  for (double x = -4; x <= 4.01; x += 0.5) path.push_back(Truth(x, 0));
  for (double x = 4; x >= -4.01; x -= 0.5) path.push_back(Truth(x, 1.5));
  // The worst final pose error (camera centre, mm) after Optimize, the first view's pose as
  // truth's.
  const auto worst_pose_mm = [&](Tracker* t) {
    EXPECT_TRUE(t->Optimize({}, nullptr).ok());
    double worst = 0;
    Rigid3d e0, e;
    if (!t->ViewPose(0, &e0)) return 1e9;
    for (size_t i = 0; i < path.size(); ++i) {
      if (!t->ViewPose(static_cast<int64_t>(i), &e)) return 1e9;
      worst = std::max(worst, TranslationDistanceMm(path[0] * e0.inverse() * e, path[i]));
    }
    return worst;
  };
  Tracker plain(small_cam_, o);
  for (size_t i = 0; i < path.size(); ++i) {
    const auto v = RenderHeightField(hf_, small_cam_, path[i], 0.004, static_cast<uint32_t>(i + 1));
    ASSERT_TRUE(plain.Track(v.points, v.normals, v.quality, v.texture).accepted) << "view " << i;
  }
  EXPECT_EQ(plain.loop_corrections(), 0);
  const double worst_plain = worst_pose_mm(&plain);
  for (const bool defer : {false, true}) {
    SCOPED_TRACE(defer ? "edges deferred" : "edges as they come");
    TrackerOptions oc = o;
    oc.keyframes.defer_edges = defer;
    oc.loop_correction.enabled = true;
    oc.loop_correction.min_shift_mm = 0;
    oc.loop_correction.every_keyframes = 1;
    Tracker corrected(small_cam_, oc);
    int shifted = 0;
    for (size_t i = 0; i < path.size(); ++i) {
      const auto v =
          RenderHeightField(hf_, small_cam_, path[i], 0.004, static_cast<uint32_t>(i + 1));
      const TrackResult r = corrected.Track(v.points, v.normals, v.quality, v.texture);
      ASSERT_TRUE(r.accepted) << "view " << i << ": " << r.reason;
      shifted += r.loop_corrected;
      if (r.loop_corrected) {
        EXPECT_GT(r.loop_shift_mm, 0) << "view " << i;
      }
    }
    EXPECT_GT(corrected.loop_corrections(), 0);
    EXPECT_EQ(corrected.loop_corrections(), shifted);
    EXPECT_GE(corrected.loop_optimisations(), corrected.loop_corrections());
    // The model: every sample on the height field, in the frame the first view's pose defines.
    Rigid3d est0;
    ASSERT_TRUE(corrected.ViewPose(0, &est0));
    const Rigid3d truth_from_est = path[0] * est0.inverse();
    double worst_model_mm = 0;
    const PointMap& model = corrected.model();
    ASSERT_EQ(model.tags().size(), model.size());
    for (size_t i = 0; i < model.size(); ++i) {
      EXPECT_GE(model.tags()[i], 0);
      const Eigen::Vector3d p = truth_from_est * model.points()[i].cast<double>();
      worst_model_mm = std::max(worst_model_mm, std::abs(p.z() - hf_.Height(p.x(), p.y())));
    }
    EXPECT_LT(worst_model_mm, 0.05);
    // The model was rebuilt: no view before the last correction can be undone.
    EXPECT_GT(corrected.first_undoable_view(), 0);
    // The final poses, after the whole graph: as true as without the correction.
    const double worst_corrected = worst_pose_mm(&corrected);
    std::printf(
        "[ loops    ] %s: %d corrections (largest %.1f um); worst model sample %.1f um; worst "
        "pose %.1f um (without: %.1f um)\n",
        defer ? "deferred" : "as they come", corrected.loop_corrections(),
        corrected.max_loop_shift_mm() * 1000, worst_model_mm * 1000, worst_corrected * 1000,
        worst_plain * 1000);
    EXPECT_LT(worst_corrected, std::max(0.015, 1.5 * worst_plain));
  }
  EXPECT_THROW(
      [] {
        TrackerOptions bad;
        bad.loop_correction.every_keyframes = 0;
        bad.Check();
      }(),
      std::invalid_argument);
}

// Each keyframe whose ICP odometry edge was measured gets a second odometry edge right after it:
// the relative pose the tracker gave the two, with that ICP edge's information times
// tracked_edge_information_factor. Nothing else in the graph changes.
TEST_F(TrackerScan, KeyframesGetTheTrackedRelativePoseAsASecondOdometryEdge) {
  TrackerOptions o;
  o.odometry.min_view_samples /= 4;
  o.keyframes.overlap = 0.85;  // a keyframe every ~1.5 mm
  o.keyframes.loop_min_separation = 3;
  TrackerOptions o0 = o, o_half = o;
  EXPECT_EQ(o0.keyframes.tracked_edge_information_factor, 0.0) << "off by default";
  o.keyframes.tracked_edge_information_factor = 1;
  o_half.keyframes.tracked_edge_information_factor = 0.5;
  Tracker one(small_cam_, o), none(small_cam_, o0), half(small_cam_, o_half);
  std::vector<Rigid3d> path;
  for (double x = -4; x <= 4.01; x += 0.5) path.push_back(Truth(x, 0));
  for (double x = 4; x >= -4.01; x -= 0.5) path.push_back(Truth(x, 1.5));
  for (size_t i = 0; i < path.size(); ++i) {
    const auto v = RenderHeightField(hf_, small_cam_, path[i], 0.004, static_cast<uint32_t>(i + 1));
    for (Tracker* t : {&one, &none, &half})
      ASSERT_TRUE(t->Track(v.points, v.normals, v.quality, v.texture).accepted) << "view " << i;
  }
  const auto check = [&](const Tracker& t, double factor) {
    const auto& with = t.graph().edges();
    const auto& without = none.graph().edges();
    ASSERT_EQ(t.keyframes().size(), none.keyframes().size());
    size_t j = 0;
    int tracked = 0;
    for (size_t i = 0; i < with.size(); ++i, ++j) {
      ASSERT_LT(j, without.size()) << "edge " << i;
      ASSERT_EQ(with[i].from, without[j].from);
      ASSERT_EQ(with[i].to, without[j].to);
      ASSERT_EQ(with[i].loop, without[j].loop);
      EXPECT_TRUE(with[i].from_from_to.matrix() == without[j].from_from_to.matrix())
          << "edge " << i;
      EXPECT_TRUE(with[i].information == without[j].information) << "edge " << i;
      if (with[i].loop || with[i].information.isZero(0)) continue;
      // A measured odometry edge: the tracked one follows.
      ASSERT_LT(i + 1, with.size());
      const PoseGraphEdge& e = with[++i];
      EXPECT_EQ(e.from, with[i - 1].from);
      EXPECT_EQ(e.to, with[i - 1].to);
      EXPECT_FALSE(e.loop);
      // The graph's poses are still the tracked ones (before Optimize).
      const Rigid3d tracked_from_to = t.graph().pose(e.from).inverse() * t.graph().pose(e.to);
      EXPECT_LT((e.from_from_to.matrix() - tracked_from_to.matrix()).norm(), 1e-12) << "edge " << i;
      EXPECT_LE((e.information - factor * with[i - 1].information).norm(),
                1e-12 * with[i - 1].information.norm())
          << "edge " << i;
      // Not the ICP's measurement: the tracker registered against the model, not the parent alone.
      EXPECT_FALSE(e.from_from_to.matrix() == with[i - 1].from_from_to.matrix()) << "edge " << i;
      ++tracked;
    }
    EXPECT_EQ(j, without.size());
    // An odometry edge on σs (its keyframe ICP failed) gets no companion: the walk above would
    // have matched it to the next edge. Most keyframes have a measured one.
    int measured = 0;
    for (const PoseGraphEdge& e : without) measured += !e.loop && !e.information.isZero(0);
    EXPECT_EQ(tracked, measured);
    EXPECT_GT(2 * tracked, static_cast<int>(t.keyframes().size()));
  };
  check(one, 1.0);
  check(half, 0.5);
  EXPECT_THROW(
      [] {
        TrackerOptions bad;
        bad.keyframes.tracked_edge_information_factor = -0.1;
        bad.Check();
      }(),
      std::invalid_argument);
}

// A probe that turns in place or lingers over one spot keeps a high overlap with its last
// keyframe, so the overlap rule alone makes no new keyframe however far the tracked poses wander
// from it; keyframe_max_rotation_deg and keyframe_max_views make one anyway.
TEST_F(TrackerScan, AProbeThatTurnsOrLingersMakesKeyframesAnyway) {
  TrackerOptions o;
  o.relocaliser.by_features = false;  // no keyframe features needed
  o.odometry.min_view_samples /= 4;
  o.keyframes.max_rotation_deg = 0;  // overlap only
  o.keyframes.max_views = 0;
  o.keyframes.reuse_radius_mm = 0;  // every trigger makes a keyframe (reuse: next test)
  std::vector<Rigid3d> path;
  for (int i = 0; i <= 12; ++i)
    path.push_back(Truth(0, 0) *
                   Rigid3d(Eigen::AngleAxisd(i * M_PI / 180, Eigen::Vector3d::UnitZ())));
  auto keyframe_views = [&](const TrackerOptions& options) {
    Tracker t(small_cam_, options);
    std::vector<int64_t> views;
    for (size_t i = 0; i < path.size(); ++i) {
      const auto v =
          RenderHeightField(hf_, small_cam_, path[i], 0.004, static_cast<uint32_t>(i + 1));
      const TrackResult r = t.Track(v.points, v.normals, v.quality, v.texture);
      EXPECT_TRUE(r.accepted) << "view " << i << ": " << r.reason;
      if (r.new_keyframe) views.push_back(static_cast<int64_t>(i));
    }
    return views;
  };
  EXPECT_EQ(keyframe_views(o), (std::vector<int64_t>{0}));  // 1° per view about the optical axis
  TrackerOptions turn = o;
  turn.keyframes.max_rotation_deg = 4.5;
  EXPECT_EQ(keyframe_views(turn), (std::vector<int64_t>{0, 5, 10}));
  TrackerOptions linger = o;
  linger.keyframes.max_views = 4;
  EXPECT_EQ(keyframe_views(linger), (std::vector<int64_t>{0, 4, 8, 12}));
  EXPECT_THROW(
      [] {
        TrackerOptions bad;
        bad.keyframes.max_views = -1;
        bad.Check();
      }(),
      std::invalid_argument);
}

TEST_F(TrackerScan, AProbeCirclingOneSpotReusesItsKeyframes) {
  // The probe circles one spot (1 mm radius) while rocking ±6°, for four rounds of 24 views: the
  // first round makes the keyframes, the next ones find them again.
  std::vector<Rigid3d> path;
  constexpr int kRound = 16, kRounds = 3;
  for (int i = 0; i < kRound * kRounds; ++i) {
    const double a = 2 * M_PI * i / kRound;
    path.push_back(
        Truth(std::cos(a), std::sin(a)) *
        Rigid3d(Eigen::AngleAxisd(6 * M_PI / 180 * std::sin(a), Eigen::Vector3d::UnitX())));
  }
  struct Run {
    std::vector<int> keyframes_after_round;
    int reused = 0;
    double worst_mm = 0;  // optimised view poses against the truth
  };
  auto scan = [&](const TrackerOptions& options) {
    Tracker t(small_cam_, options);
    Run run;
    for (size_t i = 0; i < path.size(); ++i) {
      const TrackResult r = FeedSmall(&t, path[i], static_cast<uint32_t>(i + 1));
      EXPECT_TRUE(r.accepted) << "view " << i << ": " << r.reason;
      EXPECT_FALSE(r.new_keyframe && r.keyframe_reused) << "view " << i;
      if ((i + 1) % kRound == 0)
        run.keyframes_after_round.push_back(static_cast<int>(t.keyframes().size()));
    }
    run.reused = t.keyframes_reused();
    for (size_t k = 1; k < t.keyframes().size(); ++k) EXPECT_GE(t.keyframes()[k].parent, 0);
    PoseGraphSummary summary;
    EXPECT_TRUE(t.Optimize({}, &summary).ok());
    const Rigid3d first_inv = path[0].inverse();
    for (size_t i = 0; i < path.size(); ++i) {
      Rigid3d pose;
      EXPECT_TRUE(t.ViewPose(static_cast<int64_t>(i), &pose));
      run.worst_mm = std::max(run.worst_mm, TranslationDistanceMm(pose, first_inv * path[i]));
    }
    return run;
  };
  TrackerOptions o;
  o.relocaliser.by_features = false;
  o.odometry.min_view_samples /= 4;
  o.keyframes.max_views = 12;
  o.keyframes.reuse_radius_mm = 2.0;  // as d3d-scan
  TrackerOptions never = o;
  never.keyframes.reuse_radius_mm = 0;
  const Run without = scan(never), with = scan(o);
  // Without reuse every round adds keyframes (the aged rule alone makes 2 a round); with it the
  // later rounds add at most one.
  EXPECT_GE(without.keyframes_after_round.back() - without.keyframes_after_round.front(),
            2 * (kRounds - 1));
  EXPECT_EQ(without.reused, 0);
  EXPECT_LE(with.keyframes_after_round.back() - with.keyframes_after_round.front(), 1);
  EXPECT_GE(with.reused, kRounds - 1);
  // The price of fewer keyframes: fewer loop edges to average (measured: worst view 9 µm without
  // reuse, 19 µm with; 15 µm as tracked, before Optimize, either way).
  EXPECT_LT(without.worst_mm, 0.015);
  EXPECT_LT(with.worst_mm, 0.025);

  // Undo across reuses: the current keyframe comes back as the kept views left it. Taken back from
  // a view in the last round whose current keyframe was a reused one (not the newest).
  TrackerOptions u = o;
  u.odometry.map.undo_inserts = 2 * kRound;
  Tracker all(small_cam_, u);
  std::vector<int> current;
  std::vector<size_t> made, edges;
  for (size_t i = 0; i < path.size(); ++i) {
    ASSERT_TRUE(FeedSmall(&all, path[i], static_cast<uint32_t>(i + 1)).accepted) << "view " << i;
    current.push_back(all.current_keyframe());
    made.push_back(all.keyframes().size());
    edges.push_back(all.graph().edges().size());
  }
  int keep = -1;  // views kept: 0 … keep − 1
  for (size_t i = 2 * kRound; i + 2 < path.size() && keep < 0; ++i)
    if (current[i] != static_cast<int>(made[i]) - 1 && current[i] != current.back())
      keep = static_cast<int>(i) + 1;
  ASSERT_GT(keep, 0) << "no view of the last round anchored to a reused keyframe";
  ASSERT_TRUE(all.UndoFrom(keep).ok);
  EXPECT_EQ(all.keyframes().size(), made[static_cast<size_t>(keep - 1)]);
  EXPECT_EQ(all.current_keyframe(), current[static_cast<size_t>(keep - 1)]);
  EXPECT_EQ(all.graph().edges().size(), edges[static_cast<size_t>(keep - 1)]);
  EXPECT_THROW(
      [] {
        TrackerOptions bad;
        bad.keyframes.reuse_radius_mm = -1;
        bad.Check();
      }(),
      std::invalid_argument);
}

TEST_F(TrackerScan, KeyframeIcpEdgesRemoveAnInjectedDrift) {
  const int n = 8;
  std::vector<Rigid3d> truth;
  std::vector<SurfacePoints> samples;
  for (int i = 0; i < n; ++i) {
    truth.push_back(Truth(-4 + 1.0 * i, 0.1 * std::sin(i)));
    const auto v =
        RenderHeightField(hf_, cam_, truth.back(), 0.004, 100 + static_cast<uint32_t>(i));
    samples.push_back(SampleOrganised(v.points, v.normals, v.quality, 4));
  }
  Rigid3d bias = Rigid3d::Identity();
  bias.linear() = Eigen::AngleAxisd(0.05 * M_PI / 180, Eigen::Vector3d(0.3, 1, 0.2).normalized())
                      .toRotationMatrix();
  bias.translation() = Eigen::Vector3d(0.01, -0.004, 0.002);
  PoseGraph g;
  Rigid3d pose = truth[0];
  g.AddNode(pose);
  for (int i = 1; i < n; ++i) {
    pose =
        pose * truth[static_cast<size_t>(i - 1)].inverse() * truth[static_cast<size_t>(i)] * bias;
    g.AddNode(pose);
  }
  double drift_before = 0;
  for (int i = 0; i < n; ++i)
    drift_before =
        std::max(drift_before, TranslationDistanceMm(g.pose(i), truth[static_cast<size_t>(i)]));
  ASSERT_GT(drift_before, 0.06);
  int edges = 0;
  for (int i = 1; i < n; ++i)
    for (int back = 1; back <= 2 && back <= i; ++back) {
      PoseGraphEdge e;
      e.from = i - back;
      e.to = i;
      e.loop = back > 1;
      const Rigid3d guess = g.pose(e.from).inverse() * g.pose(e.to);
      IcpResult r;
      ASSERT_TRUE(MeasureKeyframeEdge(samples[static_cast<size_t>(e.from)],
                                      samples[static_cast<size_t>(i)], guess, KeyframeIcp(), 1e-3,
                                      &e, &r))
          << i << " from " << e.from << ": " << r.reason;
      g.AddEdge(e);
      ++edges;
    }
  PoseGraphSummary s;
  ASSERT_TRUE(g.Optimize({}, &s).ok());
  double worst = 0, worst_deg = 0;
  for (int i = 0; i < n; ++i) {
    worst = std::max(worst, TranslationDistanceMm(g.pose(i), truth[static_cast<size_t>(i)]));
    worst_deg = std::max(worst_deg,
                         RotationAngleRad(g.pose(i), truth[static_cast<size_t>(i)]) * 180 / M_PI);
  }
  std::printf("[ drift    ] %d edges: worst %.1f um before, %.1f um / %.4f deg after\n", edges,
              drift_before * 1000, worst * 1000, worst_deg);
  EXPECT_LT(worst, std::min(0.015, drift_before / 4));
  EXPECT_LT(worst_deg, 0.02);
  EXPECT_TRUE(s.disagreeing_edges.empty());
}

TEST_F(TrackerScan, AViewThatFitsMuchWorseThanTheRecentOnesStaysOutOfTheModel) {
  TrackerOptions o;
  o.relocaliser.by_features =
      false;  // neither is needed here: no keyframe features, no loop search
  o.keyframes.detect_loops = false;
  const PinholeBrownConrady cam =
      TestCamera(160, 120, 500);  // the fixture's field of view, 4× fewer pixels
  o.odometry.min_view_samples /= 4;
  ASSERT_EQ(o.odometry.map_gate_max_run, 2);
  Tracker tracker(cam, o);
  auto feed = [&](double x_mm, uint32_t seed, double noise_mm) {
    const auto v = RenderHeightField(hf_, cam, Truth(x_mm, 0), noise_mm, seed);
    return tracker.Track(v.points, v.normals, v.quality, v.texture);
  };
  uint32_t seed = 1;
  double x = -4;
  for (; x <= 4.01; x += 1.0) {  // 9 views: 8 ICP residuals, the history the test needs
    const TrackResult r = feed(x, seed++, 0.004);
    ASSERT_TRUE(r.accepted) << r.reason;
    EXPECT_TRUE(r.in_model) << "x = " << x;
  }
  // A view three times as noisy: its pose is good and stands, but its samples stay out.
  const size_t before = tracker.model().size();
  const TrackResult noisy = feed(x, seed++, 0.012);
  ASSERT_TRUE(noisy.accepted) << noisy.reason;
  EXPECT_FALSE(noisy.in_model);
  EXPECT_EQ(tracker.model().size(), before);
  Rigid3d p;
  ASSERT_TRUE(tracker.ViewPose(tracker.views() - 1, &p));
  EXPECT_LT(TranslationDistanceMm(p, Truth(-4, 0).inverse() * Truth(x, 0)), 0.03);
  // At most map_gate_max_run (2) views in a row stay out: the model must keep growing.
  EXPECT_FALSE(feed(x, seed++, 0.012).in_model);
  EXPECT_TRUE(feed(x, seed++, 0.012).in_model);
  const TrackResult next = feed(x + 1, seed++, 0.004);
  EXPECT_TRUE(next.accepted && next.in_model);
  o.odometry.map_max_rmse_ratio = 0.5;
  EXPECT_THROW(o.Check(), std::invalid_argument);
}

TEST_F(TrackerScan, AnAugmentedViewIsRegisteredAgainWithItsNewPoints) {
  // Each view reaches the tracker with its right 60 % hidden; the augmenter (as model anchoring
  // does) writes the hidden part into the same buffers once the pose is known. The view is then
  // registered again with all its points and enters the model whole.
  TrackerOptions o;
  Tracker plain(cam_, o), augmented(cam_, o), declined(cam_, o);
  const int cut = cam_.width * 2 / 5;
  int calls = 0, declined_calls = 0;
  uint32_t seed = 1;
  for (double x = -2; x <= 2.01;
       x += 1.0, ++seed) {  // 5 views: enough for a model and 4 augmented views
    const Rigid3d pose = Truth(x, 0);
    const auto full = RenderHeightField(hf_, cam_, pose, 0.004, seed);
    auto masked = [&](cv::Mat* points, cv::Mat* normals) {
      *points = full.points.clone();
      *normals = full.normals.clone();
      points->colRange(cut, cam_.width).setTo(cv::Scalar::all(std::nanf("")));
      normals->colRange(cut, cam_.width).setTo(cv::Scalar::all(std::nanf("")));
    };
    cv::Mat p0, n0, p1, n1, p2, n2;
    masked(&p0, &n0);
    masked(&p1, &n1);
    masked(&p2, &n2);
    ASSERT_TRUE(plain.Track(p0, n0, full.quality, full.texture).accepted);
    const TrackResult r = augmented.Track(
        p1, n1, full.quality, full.texture, [&](const Rigid3d&, const PointMap& model) {
          EXPECT_FALSE(model.empty());
          ++calls;
          full.points.colRange(cut, cam_.width).copyTo(p1.colRange(cut, cam_.width));
          full.normals.colRange(cut, cam_.width).copyTo(n1.colRange(cut, cam_.width));
          return true;
        });
    ASSERT_TRUE(r.accepted) << r.reason;
    const TrackResult d =
        declined.Track(p2, n2, full.quality, full.texture, [&](const Rigid3d&, const PointMap&) {
          ++declined_calls;
          return false;
        });
    ASSERT_TRUE(d.accepted) << d.reason;
  }
  EXPECT_EQ(calls, 4);  // every accepted view but the first (no model yet)
  EXPECT_EQ(declined_calls, 4);
  EXPECT_GT(augmented.model().size(),
            plain.model().size() * 13 / 10);  // the revealed parts are in the model (1.8×)
  const Rigid3d first_inv = Truth(-2, 0).inverse();
  for (int64_t i = 0; i < augmented.views(); ++i) {
    Rigid3d a, p, d;
    ASSERT_TRUE(augmented.ViewPose(i, &a) && plain.ViewPose(i, &p) && declined.ViewPose(i, &d));
    const Rigid3d want = first_inv * Truth(-2 + static_cast<double>(i), 0);
    EXPECT_LT(TranslationDistanceMm(a, want), 0.02) << "view " << i;
    EXPECT_LT(RotationAngleRad(a, want) * 180 / M_PI, 0.04) << "view " << i;
    EXPECT_EQ(d.matrix(), p.matrix())
        << "view " << i;  // an augmenter that adds nothing changes nothing
  }
}

// A smooth stretch (here 13.6 mm of the surface without relief, only the gentle wave): the views
// over its middle slide along it (ICP degenerate). They are coasted: not fused, but tracked along
// what they do constrain, the rest from the motion model, so the track is never lost and the relief
// beyond is tracked on. Without coasting the track is lost in the stretch.
TEST_F(TrackerScan, ASmoothStretchIsCoastedThroughNotLost) {
  std::erase_if(hf_.bumps, [](const HeightField::Bump& b) { return std::abs(b.x) < 6.8; });
  hf_.Bin(hf_.bumps, &hf_.bump_cells);
  for (const int coast : {3, 0}) {
    SCOPED_TRACE(coast);
    TrackerOptions o;
    o.odometry.max_coast_views = coast;
    Tracker tracker(cam_, o);
    uint32_t seed = 1;
    // A steady hand (the motion model predicts it): level flight at a constant tilt.
    auto truth = [](double x) { return LookDown(x, 0.2, 30, 0.03, -0.02, 0.01); };
    const Rigid3d first_inv = truth(-10).inverse();
    int coasted = 0, lost = 0;
    double worst_after_mm = 0;
    for (double x = -10; x <= 12.01; x += 0.8) {
      const TrackResult r = Feed(&tracker, truth(x), seed++);
      lost += r.state == TrackingState::kLost;
      if (r.reason.find("coasting") != std::string::npos) {
        ++coasted;
        EXPECT_FALSE(r.accepted) << "x = " << x;  // a coasted view is never fused
        continue;
      }
      if (x >= 5) {  // the relief again
        ASSERT_TRUE(r.accepted) << "x = " << x << ": " << r.reason;
        worst_after_mm =
            std::max(worst_after_mm, TranslationDistanceMm(r.world_from_cam, first_inv * truth(x)));
      }
      if (coast == 0 && lost > 0) break;
    }
    if (coast == 0) {
      EXPECT_GT(lost, 0);
      continue;
    }
    EXPECT_EQ(lost, 0);
    EXPECT_GE(coasted, 1);
    EXPECT_LE(coasted, 3);
    EXPECT_LT(worst_after_mm, 0.05);
  }
}

// A view whose pose jumps from the motion prediction (here the probe really jerked 1.2 mm) is
// made a keyframe of its own, however much it overlaps the current one: its pose then rests on the
// pose graph's edges rather than on a tracked step from the keyframe before. Off (0), it is not.
TEST_F(TrackerScan, AViewThatJumpsFromThePredictionBecomesAKeyframe) {
  for (const double jump_mm : {0.7, 0.0}) {
    SCOPED_TRACE(jump_mm);
    TrackerOptions o;
    o.keyframes.jump_mm = jump_mm;
    o.keyframes.jump_deg = 0;
    Tracker tracker(cam_, o);
    uint32_t seed = 1;
    double x = -4;
    for (int i = 0; i < 6; ++i, x += 0.3) {
      const TrackResult r = Feed(&tracker, Truth(x, 0), seed++);
      ASSERT_TRUE(r.accepted) << r.reason;
      if (i >= 2) {
        EXPECT_LT(r.prediction_offset_mm, 0.1) << i;
      }
    }
    const TrackResult r =
        Feed(&tracker, Truth(x + 1.2, 0), seed++);  // 1.5 mm where 0.3 were predicted
    ASSERT_TRUE(r.accepted) << r.reason;
    EXPECT_NEAR(r.prediction_offset_mm, 1.2, 0.1);
    EXPECT_EQ(r.new_keyframe, jump_mm > 0);
  }
}

// A tracked view that lands far from the motion prediction (the probe jerked 1.2 mm where 0.3 were
// predicted) must meet a re-entry's standard (RelocaliserOptions::jump_check_mm): a clean view does
// and is tracked; a noisy one (ICP residual between the re-entry limit, 40 µm, and tracking's 60)
// is refused, as a fit that ran off to a wrong place would be. With the check off, it is tracked.
TEST_F(TrackerScan, ATrackedViewThatJumpsMeetsTheReentryStandard) {
  struct Case {
    double jump_check_mm, noise_mm;
    bool accepted;
  };
  for (const Case c : {Case{1.0, 0.004, true}, Case{1.0, 0.055, false}, Case{0.0, 0.055, true}}) {
    SCOPED_TRACE(std::to_string(c.jump_check_mm) + " mm check, noise " +
                 std::to_string(c.noise_mm));
    TrackerOptions o;
    o.relocaliser.jump_check_mm = c.jump_check_mm;
    o.relocaliser.jump_check_deg = 0;
    o.relocaliser.by_features = false;  // the local search only
    Tracker tracker(cam_, o);
    uint32_t seed = 1;
    double x = -4;
    for (int i = 0; i < 6; ++i, x += 0.3)
      ASSERT_TRUE(Feed(&tracker, Truth(x, 0), seed++).accepted) << i;
    const TrackResult r = Feed(&tracker, Truth(x + 1.2, 0), seed++, c.noise_mm);
    EXPECT_EQ(r.accepted, c.accepted) << r.reason << " (rmse " << r.icp.rmse_mm << " mm)";
    if (!c.accepted) {
      EXPECT_NE(r.reason.find("icp jumped from the prediction"), std::string::npos) << r.reason;
    } else if (c.noise_mm > o.relocaliser.max_rmse_mm) {
      EXPECT_GT(r.icp.rmse_mm, o.relocaliser.max_rmse_mm);  // the case the check refuses
    }
  }
}

TEST_F(TrackerScan, AProbeBackFromALiftIsAReentryNotTracked) {
  // A track, then views with nothing to register (the probe lifted out of the mouth), then the
  // probe back: after one such view it is tracked from the prediction; after more than
  // relocaliser.direct_max_views views since the last placed one it is a re-entry, held to the
  // re-entry residual and confirmed by the next view.
  struct Case {
    int empty_views;
    double noise_mm;
    bool tracked;
  };
  for (const Case c : {Case{1, 0.004, true}, Case{5, 0.004, false}, Case{5, 0.055, false}}) {
    SCOPED_TRACE(std::to_string(c.empty_views) + " empty views, noise " +
                 std::to_string(c.noise_mm));
    TrackerOptions o;
    o.odometry.min_view_samples /= 4;
    o.relocaliser.by_features = false;  // the local search only
    Tracker tracker(small_cam_, o);
    uint32_t seed = 1;
    for (int i = 0; i < 8; ++i)
      ASSERT_TRUE(FeedSmall(&tracker, Truth(-4 + 0.8 * i, 0), seed++).accepted) << i;
    const cv::Mat nothing(small_cam_.height, small_cam_.width, CV_32FC3,
                          cv::Scalar::all(std::nan("")));
    for (int i = 0; i < c.empty_views; ++i) {
      const TrackResult e = tracker.Track(nothing, nothing, cv::Mat(), cv::Mat());
      ASSERT_FALSE(e.accepted);
      ASSERT_EQ(e.state, TrackingState::kTracking);  // a view without points keeps the state
    }
    const auto v = RenderHeightField(hf_, small_cam_, Truth(-4 + 0.8 * 7.5, 0), c.noise_mm, seed++);
    const TrackResult r = tracker.Track(v.points, v.normals, v.quality, v.texture);
    if (c.tracked) {
      EXPECT_TRUE(r.accepted) << r.reason;
      EXPECT_EQ(r.state, TrackingState::kTracking);
      continue;
    }
    EXPECT_FALSE(r.accepted) << r.reason;
    EXPECT_NE(
        r.reason.find("back after " + std::to_string(c.empty_views) + " views without points"),
        std::string::npos)
        << r.reason;
    const TrackResult next = FeedSmall(&tracker, Truth(-4 + 0.8 * 7.8, 0), seed++);
    if (c.noise_mm < o.relocaliser.max_rmse_mm) {
      EXPECT_NE(r.reason.find("re-entry candidate"), std::string::npos) << r.reason;
      EXPECT_TRUE(next.accepted) << next.reason;
      EXPECT_EQ(next.state, TrackingState::kRelocalised);
    } else {
      EXPECT_EQ(r.reason.find("re-entry candidate"), std::string::npos) << r.reason;
    }
  }
}

}  // namespace
}  // namespace d3d
