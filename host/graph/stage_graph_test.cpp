// The stage graph under random, seeded stage delays: order kept, every drop counted, and in
// lossless mode no burst lost or duplicated. Built and run under ThreadSanitizer by tools/test.sh.
#include "host/graph/stage_graph.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <condition_variable>
#include <cstdio>
#include <mutex>
#include <random>
#include <string>
#include <thread>

namespace d3d {
namespace {

struct TestItem {
  uint64_t value = 0;
  std::vector<uint64_t> stamp;  // one entry per stage: the value each stage saw (aliasing check)
};

struct Delays {
  explicit Delays(uint32_t seed, int max_us) : rng(seed), max_us(max_us) {}
  void Sleep() {
    const int us = std::uniform_int_distribution<int>(0, max_us)(rng);
    if (us > max_us / 2) std::this_thread::sleep_for(std::chrono::microseconds(us));
  }
  std::mt19937 rng;
  int max_us;
};

struct RunResult {
  std::vector<uint64_t> sunk;  // values leaving the last stage, in order
  uint64_t ingested = 0, dropped = 0, rejected = 0, order_violations = 0, completed = 0;
  std::vector<uint64_t> processed, dropped_at;
  bool stamps_ok = true;
};

// n items through 3 stages; stage 1 rejects values ≡ 3 (mod 7).
RunResult RunGraph(EdgePolicy policy, uint64_t n, uint32_t seed, int source_us,
                   std::vector<int> stage_us, bool demand_driven = true) {
  RunResult r;
  StageGraphOptions o;
  o.policy = policy;
  o.live_demand_driven = demand_driven;
  o.lossless_capacity = 3;
  uint64_t next = 0;
  Delays src_delay(seed, source_us);
  std::vector<Delays> delays;
  for (size_t i = 0; i < stage_us.size(); ++i)
    delays.emplace_back(seed * 31 + static_cast<uint32_t>(i) + 1, stage_us[i]);
  const size_t n_stages = stage_us.size();
  std::vector<StageGraph<TestItem>::Stage> stages;
  for (size_t i = 0; i < n_stages; ++i) {
    std::string name = "s";
    name.append(std::to_string(i));
    stages.push_back({name, [&, i](TestItem& it, const ItemMeta& meta) {
                        delays[i].Sleep();
                        if (meta.seq != it.value)
                          r.stamps_ok = false;  // each stage's own thread; read after Join
                        it.stamp[i] = it.value;
                        for (size_t k = 0; k < i; ++k)
                          if (it.stamp[k] != it.value) r.stamps_ok = false;
                        if (i == 1 && it.value % 7 == 3) return false;
                        if (i + 1 == n_stages) r.sunk.push_back(it.value);
                        return true;
                      }});
  }
  StageGraph<TestItem> g(
      o,
      [&] {
        auto it = std::make_unique<TestItem>();
        it->stamp.assign(n_stages, ~0ull);
        return it;
      },
      [&](TestItem& it, ItemMeta*) {
        if (next == n) return StageGraph<TestItem>::SourceResult::kEnd;
        src_delay.Sleep();
        it.value = next++;
        std::fill(it.stamp.begin(), it.stamp.end(), ~0ull);
        return StageGraph<TestItem>::SourceResult::kItem;
      },
      stages);
  g.Start();
  g.Join();
  EXPECT_TRUE(g.finished());
  r.ingested = g.ingested();
  r.dropped = g.dropped();
  r.completed = g.completed();
  for (size_t i = 0; i < n_stages; ++i) {
    r.processed.push_back(g.stage(i).processed.load());
    r.dropped_at.push_back(g.dropped_at(i));
    r.rejected += g.stage(i).rejected.load();
    r.order_violations += g.stage(i).order_violations.load();
  }
  EXPECT_EQ(g.latency_count(), r.completed);
  return r;
}

TEST(StageGraph, LosslessKeepsEveryItemInOrderUnderRandomDelays) {
  for (uint32_t seed : {1u, 2u, 3u}) {
    const uint64_t n = 400;
    const RunResult r = RunGraph(EdgePolicy::kLossless, n, seed, 200, {300, 100, 250});
    std::vector<uint64_t> expected;
    for (uint64_t v = 0; v < n; ++v)
      if (v % 7 != 3) expected.push_back(v);
    EXPECT_EQ(r.sunk, expected) << "seed " << seed;  // nothing lost, nothing duplicated, in order
    EXPECT_EQ(r.ingested, n);
    EXPECT_EQ(r.dropped, 0u);
    EXPECT_EQ(r.rejected, n - expected.size());
    EXPECT_EQ(r.order_violations, 0u);
    EXPECT_EQ(r.completed, expected.size());
    EXPECT_EQ(r.processed[0], n);
    EXPECT_TRUE(r.stamps_ok);
  }
}

TEST(StageGraph, LiveDropsOldestCountsEveryDropAndKeepsOrder) {
  for (bool demand_driven : {false, true})
    for (uint32_t seed : {4u, 5u, 6u}) {
      SCOPED_TRACE(demand_driven ? "demand-driven" : "every edge latest-wins");
      const uint64_t n = 600;
      // A fast source and a slow middle stage: drops are certain.
      const RunResult r = RunGraph(EdgePolicy::kLive, n, seed, 40, {100, 800, 200}, demand_driven);
      EXPECT_EQ(r.ingested, n);
      if (demand_driven) {
        // Stage 0 never runs ahead of the slow stage 1: every drop happens at the source's edge, so
        // no stage spends time on an item that is dropped later.
        EXPECT_EQ(r.dropped_at[1], 0u) << "seed " << seed;
        EXPECT_EQ(r.dropped_at[2], 0u) << "seed " << seed;
      } else {
        EXPECT_GT(r.dropped_at[1], 0u)
            << "seed " << seed;  // stage 0 keeps pace with the source; stage 1 drops
      }
      EXPECT_GT(r.dropped, 0u) << "seed " << seed;
      EXPECT_EQ(r.order_violations, 0u);
      EXPECT_TRUE(r.stamps_ok);
      for (size_t i = 1; i < r.sunk.size(); ++i)
        ASSERT_LT(r.sunk[i - 1], r.sunk[i]) << "seed " << seed;  // no duplicate, in order
      // Conservation on every edge: pushed = popped + dropped.
      const uint64_t rejected_at_1 = r.rejected;  // only stage 1 rejects
      EXPECT_EQ(r.processed[0] + r.dropped_at[0], n);
      EXPECT_EQ(r.processed[1] + r.dropped_at[1], r.processed[0]);
      EXPECT_EQ(r.processed[2] + r.dropped_at[2], r.processed[1] - rejected_at_1);
      EXPECT_EQ(r.completed, r.processed[2]);
      EXPECT_EQ(r.completed + r.dropped + r.rejected, n);
      // The newest item always makes it through: the last one ingested leaves the graph.
      ASSERT_FALSE(r.sunk.empty());
      if ((n - 1) % 7 != 3) {
        EXPECT_EQ(r.sunk.back(), n - 1);
      }
    }
}

TEST(StageGraph, StopDrainsLosslessAndEndsLive) {
  for (EdgePolicy p : {EdgePolicy::kLossless, EdgePolicy::kLive}) {
    StageGraphOptions o;
    o.policy = p;
    std::atomic<uint64_t> made{0};
    uint64_t sunk = 0;
    StageGraph<TestItem> g(
        o, [] { return std::make_unique<TestItem>(); },
        [&](TestItem& it, ItemMeta*) {
          it.value = made.fetch_add(1);
          std::this_thread::sleep_for(std::chrono::microseconds(100));
          return StageGraph<TestItem>::SourceResult::kItem;
        },
        {{"a", [](TestItem&, const ItemMeta&) { return true; }},
         {"b", [&](TestItem&, const ItemMeta&) {
            std::this_thread::sleep_for(std::chrono::microseconds(500));
            ++sunk;
            return true;
          }}});
    g.Start();
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    g.RequestStop();
    g.Join();
    EXPECT_TRUE(g.finished());
    EXPECT_EQ(sunk + g.dropped(), g.ingested()) << EdgePolicyName(p);
    if (p == EdgePolicy::kLossless) {
      EXPECT_EQ(g.dropped(), 0u);
    }
  }
}

// n items (values 0 … n−1), one per source_period, through `stages` with options `o`; returns the
// graph after Join().
std::unique_ptr<StageGraph<TestItem>> RunCounting(
    const StageGraphOptions& o, uint64_t n, const std::vector<StageGraph<TestItem>::Stage>& stages,
    std::chrono::microseconds source_period = {}) {
  uint64_t next = 0;
  auto g = std::make_unique<StageGraph<TestItem>>(
      o, [] { return std::make_unique<TestItem>(); },
      [&next, n, source_period](TestItem& it, ItemMeta*) {
        if (next == n) return StageGraph<TestItem>::SourceResult::kEnd;
        if (source_period.count() > 0) std::this_thread::sleep_for(source_period);
        it.value = next++;
        return StageGraph<TestItem>::SourceResult::kItem;
      },
      stages);
  g->Start();
  g->Join();
  return g;
}

// A stage's after-hook runs once per item, rejected ones included, on the stage's thread, after
// the item has gone on and before the stage takes its next item: the next stage starts on item k
// while stage 0's hook for k still runs (the hook waits for that, with a timeout), in both
// policies. The hook's time counts in the stage's busy and CPU time.
TEST(StageGraph, AfterHookRunsOnceTheItemHasGoneOn) {
  for (EdgePolicy p : {EdgePolicy::kLossless, EdgePolicy::kLive}) {
    SCOPED_TRACE(EdgePolicyName(p));
    StageGraphOptions o;
    o.policy = p;
    std::mutex mu;
    std::condition_variable cv;
    int64_t started_1 = -1;           // the latest value stage 1 started on (under mu)
    std::vector<std::string> events;  // stage 0's thread only; read after Join
    uint64_t current = 0, hooks_seeing_next_stage = 0, taken = 0;
    bool rejected_now = false;  // stage 0's thread only
    const std::vector<StageGraph<TestItem>::Stage> stages = {
        {"a",
         [&](TestItem& it, const ItemMeta&) {
           current = it.value;
           events.push_back("fn " + std::to_string(it.value));
           // Every 3rd item stage 0 takes is rejected (counted as taken, not by value: the live
           // policy's drops depend on the machine's load), and its hook runs too.
           rejected_now = ++taken % 3 == 0;
           return !rejected_now;
         },
         [&] {
           events.push_back("after " + std::to_string(current));
           if (rejected_now) return;  // rejected: stage 1 never sees it
           const auto busy_until = std::chrono::steady_clock::now() + std::chrono::milliseconds(2);
           while (std::chrono::steady_clock::now() < busy_until) {
           }
           std::unique_lock<std::mutex> lock(mu);
           if (cv.wait_for(lock, std::chrono::seconds(5),
                           [&] { return started_1 >= static_cast<int64_t>(current); }))
             ++hooks_seeing_next_stage;
         }},
        {"b", [&](TestItem& it, const ItemMeta&) {
           {
             std::lock_guard<std::mutex> lock(mu);
             started_1 = static_cast<int64_t>(it.value);
           }
           cv.notify_all();
           return true;
         }}};
    // A burst every 3 ms (longer than stage 0's ~2 ms per item), so that live drops few and both
    // accepted and rejected items reach stage 0.
    const uint64_t n = 22;
    const auto graph = RunCounting(o, n, stages, std::chrono::milliseconds(3));
    const StageGraph<TestItem>& g = *graph;
    const uint64_t ran = g.stage(0).processed.load();
    ASSERT_EQ(events.size(), 2 * ran);
    for (size_t e = 0; e + 1 < events.size(); e += 2) {  // fn k, after k, fn k', after k', ...
      ASSERT_EQ(events[e].rfind("fn ", 0), 0u) << e;
      EXPECT_EQ(events[e + 1], "after " + events[e].substr(3)) << e;
    }
    EXPECT_EQ(hooks_seeing_next_stage,
              ran - g.stage(0).rejected.load());  // every accepted item had gone on
    EXPECT_GT(hooks_seeing_next_stage, 0u);
    EXPECT_GT(g.stage(0).rejected.load(), 0u);
    EXPECT_GE(static_cast<double>(g.stage(0).busy_ns.load()),
              2e6 * static_cast<double>(hooks_seeing_next_stage));
    EXPECT_GE(static_cast<double>(g.stage(0).cpu_ns.load()),
              1.5e6 * static_cast<double>(hooks_seeing_next_stage));
    if (p == EdgePolicy::kLossless) {
      EXPECT_EQ(ran, n);
    }
  }
}

TEST(StageGraph, LatencyEndsAtTheNamedStageAndTheLastStageIsKeptToo) {
  // Stage 1 is where a user sees the item (d3d-scan: the preview); stage 2 (the fuse) takes 8 ms
  // more. Latency samples: one per item at stage 1's end, and one per item at the last stage's.
  StageGraphOptions o;
  o.policy = EdgePolicy::kLossless;
  o.latency_stage = 1;
  const uint64_t n = 30;
  std::vector<StageGraph<TestItem>::Stage> stages = {
      {"a", [](TestItem&, const ItemMeta&) { return true; }},
      {"seen", [](TestItem&, const ItemMeta&) { return true; }},
      {"slow", [](TestItem&, const ItemMeta&) {
         std::this_thread::sleep_for(std::chrono::milliseconds(8));
         return true;
       }}};
  const auto graph = RunCounting(o, n, stages);
  const StageGraph<TestItem>& g = *graph;
  ASSERT_EQ(g.completed(), n);
  EXPECT_EQ(g.latency_count(), n);
  // Every item spends >= 8 ms in the last stage after it was seen: the done latency's median is
  // at least 8 ms above the seen latency's (queueing behind the slow stage only adds to it).
  EXPECT_GE(g.DoneLatencyPercentileMs(50), g.LatencyPercentileMs(50) + 8.0);
  EXPECT_GE(g.DoneLatencyPercentileMs(0), 8.0);
  o.latency_stage = 3;
  EXPECT_THROW(
      StageGraph<TestItem>(
          o, [] { return std::make_unique<TestItem>(); },
          [](TestItem&, ItemMeta*) { return StageGraph<TestItem>::SourceResult::kEnd; }, stages),
      std::invalid_argument);
}

// Just-in-time start: a source every 1 ms, a 2 ms first stage, a 20 ms second stage. Demand-driven,
// stage 0 starts as soon as stage 1 took its last output and its result then waits ~18 ms; just in
// time it holds back ~15 ms (20 − 2 − the 3 ms margin) and starts on a newer item, so the items
// stage 1 starts on are ~15 ms younger. Same drop accounting; lossless edges never hold back.
struct JustInTimeRun {
  double mean_age_ms = 0;  // item age (since ingest) when stage 1 starts on it
  uint64_t held_ns = 0, processed0 = 0, processed1 = 0, dropped0 = 0, dropped1 = 0,
           order_violations = 0;
};
JustInTimeRun RunJustInTime(EdgePolicy policy, bool just_in_time, uint64_t n = 700) {
  StageGraphOptions o;
  o.policy = policy;
  o.live_just_in_time = just_in_time;
  std::vector<double> ages;  // stage 1's thread; read after Join
  ages.reserve(n);
  std::vector<StageGraph<TestItem>::Stage> stages = {
      {"fast",
       [](TestItem&, const ItemMeta&) {
         std::this_thread::sleep_for(std::chrono::milliseconds(2));
         return true;
       }},
      {"slow", [&ages](TestItem&, const ItemMeta& meta) {
         ages.push_back(static_cast<double>(GraphNowNs() - meta.origin_ns) * 1e-6);
         std::this_thread::sleep_for(std::chrono::milliseconds(20));
         return true;
       }}};
  uint64_t next = 0;
  StageGraph<TestItem> g(
      o, [] { return std::make_unique<TestItem>(); },
      [&next, n](TestItem& it, ItemMeta*) {
        if (next == n) return StageGraph<TestItem>::SourceResult::kEnd;
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
        it.value = next++;
        return StageGraph<TestItem>::SourceResult::kItem;
      },
      stages);
  g.Start();
  g.Join();
  JustInTimeRun r;
  const size_t skip = 8;  // the first items: no timings yet, no hold
  double sum = 0;
  for (size_t i = skip; i < ages.size(); ++i) sum += ages[i];
  r.mean_age_ms = ages.size() > skip ? sum / static_cast<double>(ages.size() - skip) : 0;
  r.held_ns = g.stage(0).held_ns.load();
  r.processed0 = g.stage(0).processed.load();
  r.processed1 = g.stage(1).processed.load();
  r.dropped0 = g.dropped_at(0);
  r.dropped1 = g.dropped_at(1);
  r.order_violations = g.stage(0).order_violations.load() + g.stage(1).order_violations.load();
  EXPECT_EQ(g.completed(), r.processed1);
  return r;
}

TEST(StageGraph, JustInTimeStartTakesNewerItems) {
  const JustInTimeRun plain = RunJustInTime(EdgePolicy::kLive, false);
  const JustInTimeRun jit = RunJustInTime(EdgePolicy::kLive, true);
  EXPECT_EQ(plain.held_ns, 0u);
  EXPECT_GT(jit.held_ns, 0u);
  std::printf("mean age at stage 1's start: %.1f ms just in time, %.1f ms plain\n", jit.mean_age_ms,
              plain.mean_age_ms);
  EXPECT_LT(jit.mean_age_ms, plain.mean_age_ms - 6.0);
  for (const JustInTimeRun* r : {&plain, &jit}) {
    EXPECT_EQ(r->processed0 + r->dropped0, 700u);  // every drop counted, at the source's edge only
    EXPECT_EQ(r->dropped1, 0u);
    EXPECT_EQ(r->processed1, r->processed0);
    EXPECT_EQ(r->order_violations, 0u);
  }
  const JustInTimeRun lossless = RunJustInTime(EdgePolicy::kLossless, true, 30);
  EXPECT_EQ(lossless.held_ns, 0u);
  EXPECT_EQ(lossless.processed1, 30u);
}

// A real-time source with a backlog: item k is captured at start − backlog·period + k·period and
// handed over no earlier than that (those of the backlog at once); two stages of the given times.
struct CatchUpRun {
  std::vector<uint64_t> sunk;  // values leaving the last stage, in order
  uint64_t catch_up_items = 0, dropped = 0, ingested = 0;
  bool still_catching_up = true, thinned = false;
};
CatchUpRun RunCatchUp(double catch_up_max_s, uint64_t backlog, uint64_t n, int period_ms,
                      int stage0_ms, int stage1_ms, int window = 6) {
  StageGraphOptions o;
  o.policy = EdgePolicy::kLive;
  o.live_catch_up_max_s = catch_up_max_s;
  o.live_catch_up_window = window;
  o.live_catch_up_min_gain_ms = 2;  // the fast graph gains ~6 ms per item
  o.live_caught_up_age_ms =
      0;  // by the wait alone: the source sleeps for every item after the backlog
  o.live_caught_up_wait_ms = 1;
  CatchUpRun r;
  r.sunk.reserve(n);
  std::vector<StageGraph<TestItem>::Stage> stages = {
      {"s0",
       [stage0_ms](TestItem&, const ItemMeta&) {
         std::this_thread::sleep_for(std::chrono::milliseconds(stage0_ms));
         return true;
       }},
      {"s1", [stage1_ms, &r](TestItem& it, const ItemMeta&) {
         std::this_thread::sleep_for(std::chrono::milliseconds(stage1_ms));
         r.sunk.push_back(it.value);  // the last stage's thread; read after Join
         return true;
       }}};
  const int64_t period_ns = int64_t{period_ms} * 1'000'000;
  const int64_t t0 = GraphNowNs() - static_cast<int64_t>(backlog) * period_ns;
  uint64_t next = 0;
  StageGraph<TestItem> g(
      o, [] { return std::make_unique<TestItem>(); },
      [&](TestItem& it, ItemMeta* meta) {
        if (next == n) return StageGraph<TestItem>::SourceResult::kEnd;
        const int64_t capture = t0 + static_cast<int64_t>(next) * period_ns;
        if (const int64_t wait = capture - GraphNowNs(); wait > 0)
          std::this_thread::sleep_for(std::chrono::nanoseconds(wait));
        meta->origin_ns = capture;
        it.value = next++;
        return StageGraph<TestItem>::SourceResult::kItem;
      },
      stages);
  g.Start();
  g.Join();
  r.catch_up_items = g.catch_up_items();
  r.dropped = g.dropped();
  r.ingested = g.ingested();
  r.still_catching_up = g.catching_up();
  r.thinned = g.catch_up_thinned();
  EXPECT_EQ(g.stage(0).order_violations.load() + g.stage(1).order_violations.load(), 0u);
  EXPECT_EQ(g.completed() + r.dropped, r.ingested);  // every item processed or counted as dropped
  return r;
}

TEST(StageGraph, CatchUpStartProcessesTheBacklogThenLatestWins) {
  // 20 items queued before the start, then one per 10 ms; the stages take 2 and 4 ms: the graph
  // works off the backlog in order and goes live once the source has to wait for an item (~the
  // 35th). The trend check is off and the source runs 2 s: on a loaded machine (CTest -j2 beside
  // the scan tests) the stages lose the 2 ms per item they must gain, the trend check then thins
  // the backlog as it should (the next test), and catching up takes longer.
  const CatchUpRun on = RunCatchUp(2.0, 20, 200, 10, 2, 4, /*window=*/0);
  ASSERT_GE(on.sunk.size(), 20u);
  for (uint64_t k = 0; k < 20; ++k) EXPECT_EQ(on.sunk[k], k) << "backlog item " << k;
  EXPECT_GE(on.catch_up_items, 20u);
  EXPECT_LT(on.catch_up_items, 200u);  // caught up before the end: then latest wins
  EXPECT_FALSE(on.still_catching_up);
  // Off: the backlog arrives at once and the newest wins; most of it is dropped.
  const CatchUpRun off = RunCatchUp(0.0, 20, 100, 10, 2, 4);
  EXPECT_EQ(off.catch_up_items, 0u);
  uint64_t backlog_sunk = 0;
  for (uint64_t v : off.sunk) backlog_sunk += v < 20;
  EXPECT_LT(backlog_sunk, 10u);
  EXPECT_GE(off.dropped, 10u);
}

TEST(StageGraph, CatchUpStartThinsOutOnASlowGraph) {
  // The graph (8 ms per item) cannot keep up with one item per 5 ms. With the trend check off it
  // keeps every item until its 0.25 s limit (~30 items), then thins out. With it, it thins out
  // once an item is no younger than the one 6 before (the 9th): one of every 3 items (one per
  // 15 ms, or fewer where a loaded machine slows the stages) until it has caught up. Neither jumps
  // to the newest item: never more than max_thin + 1 = 6 apart.
  const CatchUpRun limit = RunCatchUp(0.25, 10, 120, 5, 2, 8, /*window=*/0);
  const CatchUpRun trend = RunCatchUp(2.0, 10, 120, 5, 2, 8, /*window=*/6);
  for (const CatchUpRun* r : {&limit, &trend}) {
    EXPECT_FALSE(r->still_catching_up);
    EXPECT_TRUE(r->thinned);
    ASSERT_GE(r->sunk.size(), 9u);
    for (uint64_t k = 0; k < 9; ++k) EXPECT_EQ(r->sunk[k], k);
    EXPECT_GT(r->dropped, 0u);
    ASSERT_GE(r->sunk.size(), r->catch_up_items);
    EXPECT_LT(r->catch_up_items, 80u);  // caught up, then latest wins
    for (uint64_t k = 9; k < r->catch_up_items; ++k) {
      EXPECT_GT(r->sunk[k], r->sunk[k - 1]);
      EXPECT_LE(r->sunk[k] - r->sunk[k - 1], 6u) << "catch-up item " << k;
    }
  }
  EXPECT_GE(limit.catch_up_items, 20u);
  EXPECT_GT(trend.catch_up_items, 9u);  // thinned items too
  EXPECT_THROW(
      {
        StageGraphOptions o;
        o.live_catch_up_max_s = -1;
        o.Check();
      },
      std::invalid_argument);
  EXPECT_THROW(
      {
        StageGraphOptions o;
        o.live_catch_up_max_thin = o.live_catch_up_thin - 1;
        o.Check();
      },
      std::invalid_argument);
}

TEST(StageGraph, CatchUpThinsFurtherWhileItDoesNotGainAndGivesUpWhenNothingHelps) {
  // 16 ms per item against one item per 5 ms: one of 3 (15 ms) does not gain, one of 4 (20 ms)
  // gains 1 ms per item ingested (the test asks 2), one of 5 (25 ms) gains 1.8 ms, one of 6 (30 ms)
  // 2.3 ms. It thins further while it does not gain, never beyond one of 6 (max_thin 5), and
  // catches up without a jump: the kept items stay a steady subset.
  const CatchUpRun slow = RunCatchUp(2.0, 10, 300, 5, 2, 16, /*window=*/4);
  EXPECT_TRUE(slow.thinned);
  EXPECT_FALSE(slow.still_catching_up);
  ASSERT_GE(slow.sunk.size(), slow.catch_up_items);
  uint64_t widest = 0;
  for (uint64_t k = 1; k < slow.catch_up_items; ++k) {
    EXPECT_GT(slow.sunk[k], slow.sunk[k - 1]);
    widest = std::max(widest, slow.sunk[k] - slow.sunk[k - 1]);
  }
  EXPECT_GE(widest, 4u) << "thinned further than one of 3";
  EXPECT_LE(widest, 6u) << "never more than max_thin + 1 apart while catching up";
  // 60 ms per item: one of 6 (30 ms) cannot gain either; the catch-up ends (latest wins) instead
  // of keeping every burst ever later.
  const CatchUpRun hopeless = RunCatchUp(2.0, 10, 200, 5, 2, 60, /*window=*/4);
  EXPECT_TRUE(hopeless.thinned);
  EXPECT_FALSE(hopeless.still_catching_up);
  EXPECT_LT(hopeless.catch_up_items, 40u);
}

TEST(StageGraph, CpuTimeCountsWorkNotWaiting) {
  // Stage "sleep" waits 5 ms per item, stage "spin" works until its thread has used 5 ms of CPU.
  // Both show ≥ 5 ms of wall time per item; only the spinning one shows the CPU time.
  StageGraphOptions o;
  o.policy = EdgePolicy::kLossless;
  const uint64_t n = 10;
  std::vector<StageGraph<TestItem>::Stage> stages = {
      {"sleep",
       [](TestItem&, const ItemMeta&) {
         std::this_thread::sleep_for(std::chrono::milliseconds(5));
         return true;
       }},
      {"spin", [](TestItem& it, const ItemMeta&) {
         const uint64_t until = ThreadCpuNs() + 5000000;
         while (ThreadCpuNs() < until) ++it.value;
         return true;
       }}};
  const auto graph = RunCounting(o, n, stages);
  const StageGraph<TestItem>& g = *graph;
  ASSERT_EQ(g.completed(), n);
  const StageCounters& sleep = g.stage(0);
  const StageCounters& spin = g.stage(1);
  EXPECT_GE(sleep.busy_ns.load(), n * 5000000);
  EXPECT_LT(sleep.cpu_ns.load(), n * 1000000);  // waking up costs microseconds, not the 5 ms
  EXPECT_GE(spin.cpu_ns.load(), n * 5000000);
  EXPECT_GE(spin.busy_ns.load(), spin.cpu_ns.load());
}

TEST(TripleBuffer, ReaderSeesOnlyWholePublishedValuesNewestLast) {
  TripleBuffer<std::vector<int>> tb;
  std::atomic<bool> done{false};
  std::thread writer([&] {
    for (int v = 1; v <= 20000; ++v) {
      auto& b = tb.Back();
      b.assign(16, v);
      tb.Publish();
    }
    done = true;
  });
  int last = 0;
  bool consistent = true, monotonic = true;
  while (!done.load()) {
    if (const auto* v = tb.Latest()) {
      for (int x : *v) consistent &= x == v->front();
      monotonic &= v->front() >= last;
      last = v->front();
    }
  }
  writer.join();
  const auto* v = tb.Latest();
  ASSERT_NE(v, nullptr);
  EXPECT_EQ(v->front(), 20000);
  EXPECT_TRUE(consistent);
  EXPECT_TRUE(monotonic);
}

TEST(Percentile, NearestRank) {
  EXPECT_EQ(PercentileOf({}, 50), 0);
  EXPECT_EQ(PercentileOf({5, 1, 3, 2, 4}, 50), 3);
  EXPECT_EQ(PercentileOf({5, 1, 3, 2, 4}, 100), 5);
  EXPECT_EQ(PercentileOf({5, 1, 3, 2, 4}, 0), 1);
}

}  // namespace
}  // namespace d3d
