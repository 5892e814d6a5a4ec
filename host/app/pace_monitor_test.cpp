#include "host/app/pace_monitor.h"

#include <gtest/gtest.h>

namespace d3d {
namespace {

constexpr int64_t kBurstNs = 33'333'333;  // a 30 Hz probe

// The probe moving along x at speed_mm_s; the host keeps every `keep`-th burst, for `seconds`.
// Returns whether the monitor advised slowing down at the end, and how often it came on.
bool Probe(PaceMonitor* m, double speed_mm_s, int keep, double seconds, uint64_t first_seq = 0) {
  const int bursts = static_cast<int>(seconds * 30);
  bool advice = false;
  for (int i = 0; i < bursts; i += keep) {
    const uint64_t seq = first_seq + static_cast<uint64_t>(i);
    const int64_t t = static_cast<int64_t>(seq) * kBurstNs;
    Rigid3d pose = Rigid3d::Identity();
    pose.translation().x() = speed_mm_s * static_cast<double>(t) * 1e-9;
    advice = m->Add(seq, t, &pose);
  }
  return advice;
}

TEST(PaceMonitor, AHostThatKeepsUpNeverAdvises) {
  PaceMonitor m;
  EXPECT_FALSE(Probe(&m, 10.0, 1, 3.0)) << "every burst kept at 10 mm/s: 0.33 mm steps";
  EXPECT_FALSE(Probe(&m, 40.0, 1, 3.0, 90))
      << "fast hands, but the host keeps every burst: not the host's advice";
  EXPECT_EQ(m.advices(), 0);
  EXPECT_NEAR(m.kept_share(), 1.0, 1e-9);
}

TEST(PaceMonitor, AHostThatKeepsFewBurstsOfAFastProbeAdvisesThenClearsAfterTheHold) {
  PaceMonitor m;
  EXPECT_TRUE(Probe(&m, 10.0, 5, 2.0)) << "1 burst in 5 at 10 mm/s: 1.67 mm steps";
  EXPECT_NEAR(m.kept_share(), 0.2, 0.03);
  EXPECT_NEAR(m.step_mm(), 1.667, 0.01);
  EXPECT_EQ(m.advices(), 1);
  // The hand slows to 2 mm/s (0.33 mm steps): the advice stays for hold_s after the rule last held,
  // then goes.
  bool advice = true;
  int views_until_clear = 0;
  const uint64_t seq0 = 60;
  Rigid3d pose = Rigid3d::Identity();
  const double x0 = 10.0 * static_cast<double>(seq0 - 5) * kBurstNs * 1e-9;
  for (int i = 0; i < 90 && advice; i += 5, ++views_until_clear) {
    const uint64_t seq = seq0 + static_cast<uint64_t>(i);
    pose.translation().x() = x0 + 2.0 * (i + 5) * kBurstNs * 1e-9;
    advice = m.Add(seq, static_cast<int64_t>(seq) * kBurstNs, &pose);
  }
  EXPECT_FALSE(advice);
  // The window (1 s) must forget the fast steps, then the hold (1 s) run out: ~2 s of views at 6
  // Hz.
  EXPECT_GE(views_until_clear, 6);
  EXPECT_LE(views_until_clear, 14);
  EXPECT_EQ(m.advices(), 1) << "one episode, no flicker";
}

TEST(PaceMonitor, FewBurstsKeptOfAProbeHeldStillIsNoReasonToSlowDown) {
  PaceMonitor m;
  EXPECT_FALSE(Probe(&m, 1.0, 6, 3.0)) << "1 burst in 6 at 1 mm/s: 0.2 mm steps";
  EXPECT_LT(m.kept_share(), 0.2);
}

TEST(PaceMonitor, ViewsThatWereNotTrackedGiveNoStepAndARestartedProbeStartsAgain) {
  PaceMonitor m;
  for (uint64_t seq = 0; seq < 60; seq += 5)
    EXPECT_FALSE(m.Add(seq, static_cast<int64_t>(seq) * kBurstNs, nullptr));
  EXPECT_DOUBLE_EQ(m.step_mm(), 0.0);
  EXPECT_TRUE(Probe(&m, 10.0, 5, 2.0, 100));
  // The probe restarts its numbering: the window starts again, no advice from the old views.
  Rigid3d pose = Rigid3d::Identity();
  m.Add(0, 0, &pose);
  EXPECT_NEAR(m.kept_share(), 1.0, 1e-9);
  EXPECT_THROW(PaceMonitor(PaceOptions{.window_s = 0}), std::invalid_argument);
}

// A host that falls far behind (1 burst in 15 on a slow machine at one core's quota) keeps views
// too far apart to track: the tracker refuses them while lost, there is no step to measure, and the
// dentist must still be told. A lifted probe (views without points) is no such sign, nor are lost
// views of a host that keeps up.
TEST(PaceMonitor, AHostSoFarBehindThatTheTrackFailsAdvises) {
  PaceMonitor behind;
  bool advice = false;
  for (uint64_t seq = 0; seq < 90; seq += 15)
    advice = behind.Add(seq, static_cast<int64_t>(seq) * kBurstNs, nullptr, true);
  EXPECT_TRUE(advice) << "lost views 15 bursts apart";
  EXPECT_GE(behind.lost_views(), 2);
  EXPECT_EQ(behind.advices(), 1);

  PaceMonitor lifted;
  for (uint64_t seq = 0; seq < 90; seq += 15)
    EXPECT_FALSE(lifted.Add(seq, static_cast<int64_t>(seq) * kBurstNs, nullptr, false));

  PaceMonitor keeping_up;
  for (uint64_t seq = 0; seq < 90; ++seq)
    EXPECT_FALSE(keeping_up.Add(seq, static_cast<int64_t>(seq) * kBurstNs, nullptr, true));
  EXPECT_EQ(keeping_up.advices(), 0);

  // Lost now and then among tracked views of a slow hand: fewer than half lost, no advice.
  PaceMonitor mostly_tracked;
  Rigid3d pose = Rigid3d::Identity();
  for (uint64_t seq = 0; seq < 90; seq += 5) {
    const bool lost = seq % 15 == 0;
    pose.translation().x() = 2.0 * static_cast<double>(seq) * kBurstNs * 1e-9;
    EXPECT_FALSE(
        mostly_tracked.Add(seq, static_cast<int64_t>(seq) * kBurstNs, lost ? nullptr : &pose, lost))
        << seq;
  }
  EXPECT_THROW(PaceMonitor(PaceOptions{.min_lost_views = 0}), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
