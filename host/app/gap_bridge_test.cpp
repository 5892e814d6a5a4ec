#include "host/app/gap_bridge.h"

#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <vector>

#include "host/app/ingest_stage.h"
#include "pipeline/recon/reconstruct.h"
#include "sim/session/sim_session.h"

namespace d3d {
namespace {

constexpr int64_t kPeriodNs = 33'333'333;  // a 30 Hz probe

IngestedBurst BurstAt(uint64_t seq, int w = 8, int h = 6) {
  IngestedBurst b;
  b.burst_seq = seq;
  b.capture_ns = static_cast<int64_t>(seq) * kPeriodNs;
  for (int k = 0; k < 4; ++k)
    b.frames.push_back(cv::Mat(h, w, CV_8U, cv::Scalar(static_cast<int>(seq % 200) + k)));
  return b;
}

TEST(BurstRing, KeepsTheNewestBurstsAndCopiesThem) {
  BurstRing ring(4, 8, 6);
  for (uint64_t s = 0; s < 10; ++s) ring.Put(BurstAt(s));
  EXPECT_EQ(ring.size(), 4u);
  IngestedBurst out;
  // Bursts 6..9 are kept: nothing older, and the frames are the burst's own.
  EXPECT_FALSE(ring.TakeNearest(-1, 6 * kPeriodNs, 2 * kPeriodNs, {}, &out));
  ASSERT_TRUE(ring.TakeNearest(-1, 100 * kPeriodNs, 7 * kPeriodNs, {}, &out));
  EXPECT_EQ(out.burst_seq, 7u);
  ASSERT_EQ(out.frames.size(), 4u);
  EXPECT_EQ(out.frames[2].at<uint8_t>(3, 3), 7 + 2);
}

TEST(BurstRing, KeepsBurstsBinnedAsTheReconstructionBinsThem) {
  BurstRing ring(2, 8, 6, 4, 2);
  IngestedBurst b = BurstAt(5);
  b.frames[0].at<uint8_t>(0, 0) = 0;
  b.frames[0].at<uint8_t>(0, 1) = 10;
  b.frames[0].at<uint8_t>(1, 0) = 20;
  b.frames[0].at<uint8_t>(1, 1) = 30;
  ring.Put(b);
  IngestedBurst out;
  ASSERT_TRUE(ring.TakeNearest(0, 100 * kPeriodNs, 5 * kPeriodNs, {}, &out));
  ASSERT_EQ(out.frames.size(), 4u);
  EXPECT_EQ(out.frames[0].cols, 4);
  EXPECT_EQ(out.frames[0].rows, 3);
  cv::Mat binned;
  ASSERT_TRUE(BinFrame(b.frames[0], 2, &binned).ok());
  EXPECT_EQ(cv::norm(out.frames[0], binned, cv::NORM_INF), 0.0)
      << "the reconstruct stage's binning, bit for bit";
  EXPECT_EQ(out.frames[0].at<uint8_t>(0, 0), binned.at<uint8_t>(0, 0));
  // A burst of another size cannot be binned into the ring's slots: not kept.
  IngestedBurst odd = BurstAt(6, 9, 6);
  ring.Put(odd);
  EXPECT_FALSE(ring.TakeNearest(5 * kPeriodNs, 100 * kPeriodNs, 6 * kPeriodNs, {}, &out));
}

TEST(BurstRing, TakesTheBurstNearestTheTargetStrictlyInsideTheGapAndSkipsTriedOnes) {
  BurstRing ring(32, 8, 6);
  for (uint64_t s = 200; s < 230; ++s) ring.Put(BurstAt(s));
  IngestedBurst out;
  const int64_t after = 212 * kPeriodNs, before = 220 * kPeriodNs;
  ASSERT_TRUE(ring.TakeNearest(after, before, after + (before - after) / 2, {}, &out));
  EXPECT_EQ(out.burst_seq, 216u);
  // 216 tried: its two neighbours are as near; the later one is taken.
  ASSERT_TRUE(ring.TakeNearest(after, before, 216 * kPeriodNs, {216}, &out));
  EXPECT_EQ(out.burst_seq, 217u);
  // Never an end of the gap itself.
  ASSERT_TRUE(ring.TakeNearest(after, before, 0, {}, &out));
  EXPECT_EQ(out.burst_seq, 213u);
  EXPECT_FALSE(ring.TakeNearest(212 * kPeriodNs, 213 * kPeriodNs, 212 * kPeriodNs, {}, &out));
  EXPECT_FALSE(ring.TakeNearest(after, before, after, {213, 214, 215, 216, 217, 218, 219}, &out));
}

// A source that delivers every other burst and leaves the rest out, as a replay of chosen views
// (--replay-views) does.
class EveryOtherSource final : public BurstSource {
 public:
  Result Next(IngestedBurst* out) override {
    for (;;) {
      if (next_ >= 10) return Result::kEnd;
      *out = BurstAt(next_++);
      if (out->burst_seq % 2 == 0) return Result::kBurst;
      if (skipped_sink_) skipped_sink_(*out);
    }
  }

 private:
  uint64_t next_ = 0;
};

TEST(BurstRing, AReplaysLeftOutBurstsReachTheRingAsALiveGraphsDroppedOnesDo) {
  EveryOtherSource source;
  UndoLog undo(false);
  BurstRing ring(32, 8, 6);
  IngestStage ingest(&source, &undo, &ring, {});
  ScanItem item;
  ItemMeta meta;
  int items = 0;
  while (ingest.Run(item, &meta) == StageGraph<ScanItem>::SourceResult::kItem) ++items;
  EXPECT_EQ(items, 5);
  EXPECT_EQ(ring.size(), 10u) << "the delivered bursts and the left-out ones";
  IngestedBurst out;
  ASSERT_TRUE(ring.TakeNearest(2 * kPeriodNs, 4 * kPeriodNs, 3 * kPeriodNs, {}, &out));
  EXPECT_EQ(out.burst_seq, 3u) << "a left-out burst bridges the gap between two delivered ones";
}

TEST(GapBridge, AppliesOnlyToAViewRefusedWhileTheTrackWasHeldAfterAGap) {
  const GapBridgeOptions o;
  TrackResult refused;
  refused.accepted = false;
  const int64_t last = 1'000'000'000, view = last + 4 * kPeriodNs;
  EXPECT_TRUE(BridgeApplies(o, TrackingState::kTracking, refused, view, last));
  EXPECT_TRUE(BridgeApplies(o, TrackingState::kRelocalised, refused, view, last));
  EXPECT_FALSE(BridgeApplies(o, TrackingState::kLost, refused, view, last))
      << "already lost: the relocaliser's case";
  EXPECT_FALSE(BridgeApplies(o, TrackingState::kTracking, refused, last + kPeriodNs, last))
      << "no burst between";
  EXPECT_FALSE(BridgeApplies(o, TrackingState::kTracking, refused, view, 0))
      << "nothing placed yet";
  TrackResult lifted = refused;
  lifted.too_few_points = true;
  EXPECT_FALSE(BridgeApplies(o, TrackingState::kTracking, lifted, view, last))
      << "a lifted probe: no gap to bridge";
  TrackResult placed = refused;
  placed.accepted = true;
  EXPECT_FALSE(BridgeApplies(o, TrackingState::kTracking, placed, view, last));
  GapBridgeOptions off = o;
  off.ring_bursts = 0;
  EXPECT_FALSE(BridgeApplies(off, TrackingState::kTracking, refused, view, last));
  GapBridgeOptions bad = o;
  bad.max_attempts = 0;
  EXPECT_THROW(bad.Check(), std::invalid_argument);
  bad.max_attempts = 5;  // more fits than bursts
  EXPECT_THROW(bad.Check(), std::invalid_argument);
  EXPECT_THROW(BurstRing(0, 8, 6), std::invalid_argument);
  EXPECT_THROW(BurstRing(4, 9, 6, 4, 2), std::invalid_argument);
}

// The full-arch path's fast turn (seed 1, bursts 204–222: ~32°/s, docs/decisions/0014), tracked as
// a live host at one core would: views 4 bursts apart, and then one 8 bursts after the last, the
// tracker configured as d3d-scan's live host (step 6, bin 2, the live profile). That view is
// refused; with a burst from the gap placed first, it is placed again, at its true pose.
TEST(GapBridge, PlacesABurstFromTheGapAndThenTheRefusedViewAtATurn) {
  SimSessionOptions so;
  std::unique_ptr<SimSession> session;
  ASSERT_TRUE(SimSession::Create(so, &session).ok());
  constexpr int kBin = 2;
  ScanOptions o;
  o.tracker = TrackerOptionsForStep(o.tracker, 6);
  o = LiveScanProfile(o);
  o = ScanOptionsForBin(o, kBin);
  o.tracker.motion.view_period_ns = 6 * kPeriodNs;
  ScanReconstructor recon(session->calibration(), o.recon, kBin);
  ScanRegistrar registrar(recon.calibration(), o.tracker, o.anchor, o.recon.normal_max_gap_mm);
  BurstRing ring(16, session->calibration().camera.width, session->calibration().camera.height, 4,
                 kBin);
  auto ingest = [&](int64_t i, IngestedBurst* b) {
    const Burst burst = session->RenderBurst(i, false);
    b->burst_seq = static_cast<uint64_t>(i);
    b->capture_ns = burst.reference_ns;
    b->frames.resize(burst.frames.size());
    for (size_t k = 0; k < burst.frames.size(); ++k) burst.frames[k].image.copyTo(b->frames[k]);
  };
  IngestedBurst b;
  ReconstructedView view;
  std::vector<Rigid3d> tracked;
  std::vector<int64_t> capture;
  for (int64_t i = 188; i <= 212; i += 4) {
    ingest(i, &b);
    ASSERT_TRUE(recon.Reconstruct(b.frames, &view).ok());
    const TrackResult r = registrar.Register(view, b.burst_seq, b.capture_ns);
    ASSERT_TRUE(r.accepted) << "burst " << i << ": " << r.reason;
    tracked.push_back(r.world_from_cam);
    capture.push_back(b.capture_ns);
  }
  for (int64_t i = 213; i < 220; ++i) {  // the bursts the live graph dropped
    ingest(i, &b);
    ring.Put(b);
  }
  ingest(220, &b);
  ASSERT_TRUE(recon.Reconstruct(b.frames, &view).ok());
  const TrackingState before = registrar.tracker().state();
  const TrackResult first = registrar.Register(view, b.burst_seq, b.capture_ns);
  ASSERT_FALSE(first.accepted)
      << "the premise: 8 bursts after the last view, at this turn, the view is lost";
  GapBridgeOptions go;
  ASSERT_TRUE(BridgeApplies(go, before, first, b.capture_ns, capture.back()));
  GapBridge bridge(go, &ring, recon.calibration(), o.recon);
  int64_t placed_ns = 0;
  ASSERT_TRUE(bridge.Bridge(&registrar, capture.back(), b.capture_ns, &placed_ns));
  EXPECT_GT(placed_ns, capture.back());
  EXPECT_LT(placed_ns, b.capture_ns);
  EXPECT_GE(bridge.stats().placed, 1u);
  EXPECT_LE(bridge.stats().attempts, static_cast<uint64_t>(go.max_bursts));
  // The bridging views helped the track but are not the scan's: no group, so no pose in the result.
  int bridges = 0;
  for (size_t k = 0; k < registrar.views().size(); ++k)
    if (registrar.views()[k].bridge) {
      ++bridges;
      EXPECT_EQ(registrar.ViewGroup(static_cast<int64_t>(k)), -1);
    }
  EXPECT_EQ(bridges, static_cast<int>(bridge.stats().attempts));
  EXPECT_EQ(registrar.accepted() + registrar.rejected() + bridges,
            static_cast<int64_t>(registrar.views().size()))
      << "a bridge counts as neither";
  // The view again (its points as reconstructed: the refused attempt did not anchor them).
  ASSERT_TRUE(recon.Reconstruct(b.frames, &view).ok());
  const TrackResult again = registrar.Register(view, b.burst_seq, b.capture_ns);
  ASSERT_TRUE(again.accepted) << again.reason;
  // At its true pose relative to the first view (the tracker's world is that view's camera).
  const Trajectory& truth = session->trajectory();
  const Rigid3d true_rel =
      truth.WorldFromProbe(capture.front()).inverse() * truth.WorldFromProbe(b.capture_ns);
  const Rigid3d rel = tracked.front().inverse() * again.world_from_cam;
  EXPECT_LT((rel.translation() - true_rel.translation()).norm(), 0.2) << "mm";
  EXPECT_LT(Eigen::AngleAxisd((rel.linear().transpose() * true_rel.linear())).angle() * 180 / M_PI,
            1.0)
      << "deg";
}

}  // namespace
}  // namespace d3d
