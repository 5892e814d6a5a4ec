#include "firmware/probe/frame_sync.h"

#include <gtest/gtest.h>

namespace d3d {
namespace {

// A camera + projector pair driven through bursts; `fault(burst, pattern, &frame)` may damage a
// frame or return false to lose it.
struct Rig {
  FrameSync sync{FrameSyncOptions{}};
  uint64_t trigger_seq = 0, camera_seq = 0;
  int64_t t = 1'000'000'000;
  std::vector<std::vector<CapturedFrame>> bursts;
  template <typename Fault>
  void Run(int n, Fault fault) {
    for (int b = 0; b < n; ++b) {
      for (int p = 0; p < 4; ++p) {
        ++trigger_seq;
        t += 2'500'000;
        sync.OnTrigger(p, trigger_seq, t);
        CapturedFrame f;
        f.pattern_index = p;
        f.trigger_seq = trigger_seq;
        f.camera_frame_seq = ++camera_seq;
        f.timestamp_ns = t + 100'000;  // small latency, within tolerance
        f.pixels = std::make_shared<const std::vector<uint8_t>>(1, static_cast<uint8_t>(b));
        if (!fault(b, p, &f)) continue;
        std::vector<CapturedFrame> out;
        if (sync.OnFrame(f, &out)) bursts.push_back(out);
      }
      t += 30'000'000;
    }
  }
};

void ExpectIntact(const std::vector<CapturedFrame>& burst) {
  ASSERT_EQ(burst.size(), 4u);
  for (int p = 0; p < 4; ++p) {
    EXPECT_EQ(burst[p].pattern_index, p);
    EXPECT_EQ((*burst[p].pixels)[0], (*burst[0].pixels)[0]) << "frames of one burst";
  }
}

TEST(FrameSync, CleanStreamGivesEveryBurst) {
  Rig rig;
  rig.Run(10, [](int, int, CapturedFrame*) { return true; });
  ASSERT_EQ(rig.bursts.size(), 10u);
  for (const auto& b : rig.bursts) ExpectIntact(b);
  EXPECT_EQ(rig.sync.counters().dropped_total(), 0u);
}

TEST(FrameSync, LostFrameDropsThatBurstOnly) {
  Rig rig;
  rig.Run(6, [&](int b, int p, CapturedFrame*) {
    return !(b == 2 && p == 1);  // lost: its camera_frame_seq is never seen
  });
  ASSERT_EQ(rig.bursts.size(), 5u);
  for (const auto& b : rig.bursts) ExpectIntact(b);
  EXPECT_EQ((*rig.bursts[2][0].pixels)[0], 3) << "burst 2 dropped, burst 3 follows";
  EXPECT_EQ(rig.sync.counters().dropped_incomplete, 1u);
  EXPECT_EQ(rig.sync.counters().frames_lost, 1u);
}

TEST(FrameSync, LostFirstFrameDropsThatBurst) {
  Rig rig;
  rig.Run(4, [](int b, int p, CapturedFrame*) { return !(b == 1 && p == 0); });
  ASSERT_EQ(rig.bursts.size(), 3u);
  EXPECT_EQ(rig.sync.counters().dropped_total(), 1u);
}

TEST(FrameSync, TornFrameDropsThatBurst) {
  Rig rig;
  rig.Run(5, [](int b, int p, CapturedFrame* f) {
    if (b == 3 && p == 2) f->timestamp_ns += 1'250'000;  // exposed across the pattern switch
    return true;
  });
  ASSERT_EQ(rig.bursts.size(), 4u);
  EXPECT_EQ(rig.sync.counters().dropped_torn, 1u);
  EXPECT_EQ(rig.sync.counters().dropped_total(), 1u);
}

TEST(FrameSync, OutOfOrderFrameDropsThatBurst) {
  Rig rig;
  rig.Run(5, [](int b, int p, CapturedFrame* f) {
    if (b == 1 && p == 3) f->trigger_seq -= 1;  // latched the previous trigger
    return true;
  });
  ASSERT_EQ(rig.bursts.size(), 4u);
  EXPECT_EQ(rig.sync.counters().dropped_out_of_order, 1u);
  EXPECT_EQ(rig.sync.counters().dropped_total(), 1u);
  for (const auto& b : rig.bursts) ExpectIntact(b);
}

TEST(FrameSync, ManyFaultsNeverEmitADamagedBurst) {
  Rig rig;
  uint32_t x = 12345;
  auto rnd = [&] { return (x = x * 1664525u + 1013904223u) >> 8; };
  int damaged_bursts = 0, last_damaged = -1;
  rig.Run(400, [&](int b, int, CapturedFrame* f) {
    const uint32_t r = rnd() % 40;
    if (r < 3) {
      if (last_damaged != b) ++damaged_bursts;
      last_damaged = b;
    }
    if (r == 0) f->timestamp_ns += 2'000'000;
    if (r == 1) f->trigger_seq += 1;
    return r != 2;
  });
  for (const auto& b : rig.bursts) ExpectIntact(b);
  EXPECT_GT(damaged_bursts, 20);
  EXPECT_EQ(rig.bursts.size(), 400u - static_cast<size_t>(damaged_bursts));
  // Each burst is delivered or counted once (a damaged last burst is never closed: at most one
  // less).
  EXPECT_GE(rig.bursts.size() + rig.sync.counters().dropped_total(), 399u);
  EXPECT_LE(rig.bursts.size() + rig.sync.counters().dropped_total(), 400u);
}

}  // namespace
}  // namespace d3d
