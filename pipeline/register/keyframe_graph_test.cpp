#include "pipeline/register/keyframe_graph.h"

#include <gtest/gtest.h>

#include "pipeline/register/test_surfaces.h"

namespace d3d {
namespace {

using namespace d3d::testing;

class KeyframeGraphTest : public ::testing::Test {
 protected:
  KeyframeGraphTest() : hf_(31), cam_(TestCamera(160, 120, 500)) {}
  // Feeds view `view` at `pose` (its true pose: no tracking here); returns its TrackResult.
  TrackResult Feed(KeyframeGraph* g, const Rigid3d& pose, int64_t view, int segment = 0) const {
    const SyntheticView v =
        RenderHeightField(hf_, cam_, pose, 0.004, static_cast<uint32_t>(view + 1));
    TrackResult out;
    g->Update(v.points, v.normals, v.texture, pose, view, segment, &out);
    return out;
  }
  static KeyframeGraphOptions Plain() {
    KeyframeGraphOptions o;
    o.max_rotation_deg = 0;  // overlap only
    o.max_views = 0;
    o.detect_loops = false;
    return o;
  }
  HeightField hf_;
  PinholeBrownConrady cam_;
};

TEST(KeyframeGraphOptions, CheckRefusesWhatCannotWork) {
  EXPECT_NO_THROW(KeyframeGraphOptions().Check());
  KeyframeGraphOptions o;
  o.overlap = 0;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = KeyframeGraphOptions();
  o.near_loop_information_factor = 1.5;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = KeyframeGraphOptions();
  o.max_views = -1;
  EXPECT_THROW(KeyframeGraph(o, DefaultTrackerIcp(), false), std::invalid_argument);
}

// Along a strip a view becomes a keyframe when its overlap with the current one falls below
// `overlap` (the 9.6 mm wide view: every ~3 mm at 0.7), each new keyframe with an odometry edge
// measured by ICP from its parent; a lingering probe makes one every max_views views.
TEST_F(KeyframeGraphTest, MakesKeyframesByOverlapAndAgeWithOdometryEdges) {
  KeyframeGraph g(Plain(), DefaultTrackerIcp(), false);
  std::vector<int64_t> made;
  for (int64_t i = 0; i <= 20; ++i)
    if (Feed(&g, LookDown(-5 + 0.5 * static_cast<double>(i), 0, 30), i).new_keyframe)
      made.push_back(i);
  ASSERT_GE(made.size(), 3u);
  EXPECT_EQ(made.front(), 0);
  for (size_t k = 1; k < made.size(); ++k) {
    const int64_t apart = made[k] - made[k - 1];
    EXPECT_GE(apart, 4) << "keyframe " << k;  // 2–3.5 mm along a 9.6 mm view
    EXPECT_LE(apart, 7) << "keyframe " << k;
    EXPECT_EQ(g.keyframes()[k].parent, static_cast<int>(k) - 1);
  }
  EXPECT_EQ(g.current(), g.size() - 1);
  EXPECT_EQ(g.current_since(), made.back());
  ASSERT_EQ(g.graph().edges().size(), made.size() - 1);  // one odometry edge each, no loops
  for (const PoseGraphEdge& e : g.graph().edges()) {
    EXPECT_FALSE(e.loop);
    EXPECT_GT(e.information.trace(), 0);  // measured by ICP, not the σs
    // The measured relative pose is the true one (the views are at their true poses).
    const Rigid3d truth = g.graph().pose(e.from).inverse() * g.graph().pose(e.to);
    EXPECT_LT(TranslationDistanceMm(e.from_from_to, truth), 0.01);
  }
  KeyframeGraphOptions linger = Plain();
  linger.max_views = 4;
  KeyframeGraph h(linger, DefaultTrackerIcp(), false);
  made.clear();
  for (int64_t i = 0; i <= 12; ++i)
    if (Feed(&h, LookDown(0, 0, 30), i).new_keyframe) made.push_back(i);
  EXPECT_EQ(made, (std::vector<int64_t>{0, 4, 8, 12}));
}

// Back over ground it has keyframes of, the probe reuses an old keyframe (reuse_radius_mm) instead
// of making a new one. A reuse between keyframes an edge joins already adds none (AddReuseEdge);
// the pairs a reuse does join are measured by ICP like every other edge.
TEST_F(KeyframeGraphTest, ReusesAnOldKeyframeOnTheWayBack) {
  auto run = [&](KeyframeGraph* g) {
    int64_t view = 0;
    for (double x = -4; x <= 4.01; x += 0.5) Feed(g, LookDown(x, 0, 30), view++);
    for (double x = 4; x >= -4.01; x -= 0.5) Feed(g, LookDown(x, 0.1, 30), view++);
  };
  KeyframeGraphOptions o = Plain();
  KeyframeGraph without(o, DefaultTrackerIcp(), false);
  run(&without);
  o.reuse_radius_mm = 2;
  KeyframeGraph with(o, DefaultTrackerIcp(), false);
  run(&with);
  EXPECT_EQ(without.reused(), 0);
  EXPECT_GT(with.reused(), 0);
  EXPECT_LT(with.size(), without.size());
  EXPECT_EQ(with.current(), 0);  // back at the start: the first keyframe again
  EXPECT_EQ(with.edges(), static_cast<size_t>(with.size() - 1));  // the odometry edges only
  for (const PoseGraphEdge& e : with.graph().edges()) {
    const Rigid3d truth = with.graph().pose(e.from).inverse() * with.graph().pose(e.to);
    EXPECT_LT(TranslationDistanceMm(e.from_from_to, truth), 0.01) << e.from << " - " << e.to;
  }
}

// Edges deferred to Optimize are the edges Track() would have added, in the same order.
TEST_F(KeyframeGraphTest, DeferredEdgesAreTheSameEdges) {
  KeyframeGraphOptions o;
  o.reuse_radius_mm = 2;
  KeyframeGraph now(o, DefaultTrackerIcp(), false);
  o.defer_edges = true;
  KeyframeGraph later(o, DefaultTrackerIcp(), false);
  int64_t view = 0;
  for (KeyframeGraph* g : {&now, &later}) {
    view = 0;
    for (double x = -6; x <= 6.01; x += 0.75) Feed(g, LookDown(x, 0, 30), view++);
    for (double x = 6; x >= -6.01; x -= 0.75) Feed(g, LookDown(x, 0.2, 30, 0, 0, 0.05), view++);
  }
  EXPECT_EQ(later.edges(), 0u);
  EXPECT_GT(later.deferred_edges(), 0u);
  PoseGraphSummary a, b;
  ASSERT_TRUE(now.Optimize({}, &a).ok());
  ASSERT_TRUE(later.Optimize({}, &b).ok());
  ASSERT_EQ(now.edges(), later.edges());
  for (size_t i = 0; i < now.edges(); ++i) {
    EXPECT_EQ(now.graph().edges()[i].from, later.graph().edges()[i].from);
    EXPECT_EQ(now.graph().edges()[i].to, later.graph().edges()[i].to);
    EXPECT_TRUE(
        now.graph().edges()[i].from_from_to.isApprox(later.graph().edges()[i].from_from_to, 1e-12));
  }
}

// Undo: the keyframes made from a view on go with their nodes and the edges added since.
TEST_F(KeyframeGraphTest, DropFromTakesBackKeyframesAndTheirEdges) {
  KeyframeGraph g(Plain(), DefaultTrackerIcp(), false);
  std::vector<size_t> edges_before;
  std::vector<int64_t> made;
  for (int64_t i = 0; i <= 20; ++i) {
    edges_before.push_back(g.edges());
    if (Feed(&g, LookDown(-5 + 0.5 * static_cast<double>(i), 0, 30), i).new_keyframe)
      made.push_back(i);
  }
  ASSERT_GE(made.size(), 3u);
  const int64_t from = made[2];
  const int before = g.size();
  EXPECT_EQ(g.DropFrom(from, true, edges_before[static_cast<size_t>(from)], 0), before - 2);
  EXPECT_EQ(g.size(), 2);
  EXPECT_EQ(g.graph().num_nodes(), 2);
  EXPECT_EQ(g.edges(), edges_before[static_cast<size_t>(from)]);
  g.SetCurrent(1, made[1]);
  EXPECT_EQ(g.current(), 1);
  // The scan goes on from there as if the dropped views had never come.
  EXPECT_FALSE(
      Feed(&g, LookDown(-5 + 0.5 * static_cast<double>(from - 1), 0, 30), from).new_keyframe);
  EXPECT_THROW(g.SetCurrent(2, 0), std::invalid_argument);
}

// Keyframe features: extracted in Track(), on the worker or on demand, the same features.
TEST_F(KeyframeGraphTest, FeaturesAreTheSameWhenEverTheyAreExtracted) {
  using Timing = KeyframeGraphOptions::FeatureTiming;
  std::vector<size_t> counts;
  for (const Timing timing : {Timing::kInTrack, Timing::kWorker, Timing::kOnDemand}) {
    KeyframeGraphOptions o = Plain();
    o.feature_timing = timing;
    o.features.max_features = 300;
    KeyframeGraph g(o, DefaultTrackerIcp(), true);
    Feed(&g, LookDown(0, 0, 30), 0);
    EXPECT_EQ(g.keyframes()[0].features_pending(), timing == Timing::kOnDemand);
    g.CollectFeatures();
    counts.push_back(g.Features(0).size());
    EXPECT_FALSE(g.keyframes()[0].features_pending());
  }
  ASSERT_GT(counts[0], 0u);
  EXPECT_EQ(counts[1], counts[0]);
  EXPECT_EQ(counts[2], counts[0]);
}

}  // namespace
}  // namespace d3d
