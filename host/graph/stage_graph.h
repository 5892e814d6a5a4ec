// A small, explicit stage graph: one source (ingest) thread and a linear chain of stages, each on
// its own dedicated thread, joined by bounded, preallocated SPSC edges (edges.h) of one policy per
// run: live (latest wins, the oldest waiting item dropped and counted) or lossless (blocking).
//
//   source ──edge0──▶ stage 0 ──edge1──▶ stage 1 ── … ──▶ stage N−1 ──▶ (item back to the pool)
//
// Items: the graph preallocates a pool of Items (made once by the factory; each Item owns its
// buffers, e.g. the burst's frames and the reconstructed maps, so that a warm run allocates
// nothing). An item is owned by exactly one thread at a time: the pool, the source while it fills
// it, an edge while it waits, a stage while it runs, the pool again after the last stage. Dropped
// items (live edges) are returned to the pool by the producer that dropped them.
// Pool size = 1 (source) + N (one per stage) + edge capacity × N (1 per live edge) + extra, so in
// live mode the source never waits for an item; in lossless mode it waits (back-pressure).
//
// Demand-driven live mode (StageGraphOptions::live_demand_driven, default on): a stage does not
// take its next item before the next stage has taken its previous output. The source's edge stays
// latest-wins (the source never waits, and every drop happens there), while no CPU goes to items
// that a slower stage downstream would drop anyway: on a machine with fewer cores than stages, the
// stages that run are the ones whose output is used, and each stage starts on the newest burst.
//
// Just-in-time start (StageGraphOptions::live_just_in_time, live demand-driven only): the first
// stage, fed by the source, does not start on a burst as soon as the second stage took its last
// output, but when it will finish about as the second stage becomes free: at that take +
// (the second stage's recent time per item, median of the last 16) − (its own median) −
// just_in_time_margin_ms. Its output then waits less for the second stage, and the burst it
// starts on is newer by the time held back: the latency falls by that time on average (a burst's
// age at any instant is uniform over the source's period), the work is the same (figures:
// docs/decisions/0016). Only the first stage: a later stage holding back would keep the stage
// before it waiting (it waits for its output to be taken before it takes its next input).
//
// Catch-up start (StageGraphOptions::live_catch_up_max_s, live only): a live scan's first items
// are not dropped. Until the graph has caught up with the backlog that queued while the host set
// up, and for at most live_catch_up_max_s after the first item, the source waits until stage 0 has
// taken its previous item instead of replacing it: the back-pressure goes into the source's own
// queue (d3d-scan: the DDS receiver's, which must hold the backlog), and with the demand-driven
// stages the whole chain runs losslessly, in order. Caught up: live_caught_up_items items in a row
// that the source had to wait at least live_caught_up_wait_ms for (nothing queued) while stage 0
// had already taken the previous one, or whose origin was at most live_caught_up_age_ms old when
// handed over; in a row, so that the later stages have worked off theirs too.
// A graph that does not gain on the backlog fast enough (the items' age when handed over fell less
// than live_catch_up_min_gain_ms per item over the last live_catch_up_window items) would keep
// every burst late for long: the source then keeps one item of every live_catch_up_thin + 1 (the
// others dropped, counted at edge 0) until it has caught up. Latest wins would jump over the whole
// backlog at once, too far for a tracker to follow (docs/decisions/0014, 0016). Thinned, the same
// trend check runs per item ingested (kept or dropped): a graph that still does not gain drops one
// more item of each run, up to live_catch_up_max_thin, so that the kept items stay a steady subset
// a few bursts apart. The time limit live_catch_up_max_s ends only the every-item phase: a thinned
// catch-up ends when caught up, after live_catch_up_thinned_max_s, or when it does not gain at the
// widest thinning (a graph that slow could not follow any subset). After the catch-up, latest wins
// as before.
// Why: without it a live scan starts with the first burst after the host's set-up, not the
// probe's first, a different start from a lossless replay of the same recording (figures:
// docs/decisions/0016).
//
// Per item the graph keeps an ItemMeta: `seq` (ingest order, 0, 1, …), `origin_ns` (the time the
// item's latency is measured from, set by the source: capture or receive time, Unix epoch ns) and
// whether a stage rejected it. A stage function returns false to reject an item: it is not passed
// on (counted per stage). Latency = wall clock (Unix epoch) when the latency stage finished −
// origin_ns: by default the last stage; a graph whose user sees an item before its last stage ends
// (d3d-scan: the preview, before the fuse stage) names that stage
// (StageGraphOptions::latency_stage), and the latency to the last stage's end is kept as well
// (DoneLatencyPercentileMs).
//
// Threads: Start() spawns the source thread and one thread per stage; RequestStop() (any thread)
// makes the source end at its next call; every edge is then closed in order and drained (lossless:
// every item already ingested is processed). Join() (the thread that called Start) waits for all.
// Counters are atomics readable from any thread at any time; the latency samples are written by
// the latency stage's and the last stage's threads and read by LatencyPercentileMs() and
// DoneLatencyPercentileMs() only after Join().
#pragma once

#include <pthread.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "host/graph/edges.h"

namespace d3d {

inline int64_t GraphNowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

struct StageGraphOptions {
  EdgePolicy policy = EdgePolicy::kLossless;
  size_t lossless_capacity = 4;      // items per lossless edge
  size_t extra_items = 1;            // pool items beyond the minimum
  size_t latency_samples = 1 << 16;  // kept for the percentiles (the latest ones, ring)
  bool live_demand_driven = true;    // live: see the file comment (false: every edge latest-wins)
  int latency_stage = -1;            // the stage whose end is an item's latency (-1: the last)
  bool live_just_in_time =
      false;  // live, demand-driven: the first stage starts just in time (file comment)
  double just_in_time_margin_ms =
      3;  // ... finishing this much before the second stage is expected free
  double live_catch_up_max_s = 0;  // live: catch-up start, every item for at most this long after
                                   // the first (file comment; 0 = off)
  double live_caught_up_wait_ms =
      5;  // ... caught up once the source waited this long for an item, stage 0 free
  double live_caught_up_age_ms =
      50;  // ... or an item's origin is at most this old when the source hands it over
  int live_caught_up_items = 3;  // ... for this many items in a row
  int live_catch_up_window = 6;  // ... not gaining: over this many items (0 = never; ≤ 64) ...
  double live_catch_up_min_gain_ms = 8;  // ... the items' age fell less than this per item ingested
  int live_catch_up_thin = 2;  // ... then it keeps 1 of every thin + 1 items (dropping the others)
                               // until caught up (0 = latest wins)
  int live_catch_up_max_thin =
      5;  // ... one more dropped each time it still does not gain, up to this; then latest wins
  double live_catch_up_thinned_max_s = 5;  // ... thinned for at most this long (then latest wins)
  void Check() const {
    if (lossless_capacity < 1 || latency_samples < 1)
      throw std::invalid_argument("StageGraphOptions: capacities must be >= 1");
    if (!(just_in_time_margin_ms >= 0))
      throw std::invalid_argument("StageGraphOptions: just_in_time_margin_ms must be >= 0");
    if (!(live_catch_up_max_s >= 0) || !(live_caught_up_wait_ms > 0) ||
        !(live_caught_up_age_ms >= 0) || live_caught_up_items < 1 || live_catch_up_window < 0 ||
        live_catch_up_window > 64 || live_catch_up_thin < 0 ||
        live_catch_up_max_thin < live_catch_up_thin || !(live_catch_up_min_gain_ms >= 0) ||
        !(live_catch_up_thinned_max_s >= 0))
      throw std::invalid_argument(
          "StageGraphOptions: live_catch_up_max_s >= 0, live_caught_up_wait_ms > 0, "
          "live_caught_up_age_ms >= 0, live_caught_up_items >= 1, "
          "live_catch_up_window in [0, 64], 0 <= live_catch_up_thin <= live_catch_up_max_thin, "
          "live_catch_up_min_gain_ms >= 0, "
          "live_catch_up_thinned_max_s >= 0");
    if (latency_stage < -1)
      throw std::invalid_argument(
          "StageGraphOptions: latency_stage must be -1 (the last) or a stage index");
  }
};

struct ItemMeta {
  uint64_t seq = 0;  // ingest order
  int64_t origin_ns =
      0;  // latency origin (Unix epoch ns), set by the source (default: ingest time)
};

struct StageCounters {
  std::atomic<uint64_t> processed{0};  // items the stage ran on
  std::atomic<uint64_t> rejected{0};   // ... of which it rejected
  std::atomic<uint64_t> busy_ns{0};    // time inside the stage function (wall clock)
  // CPU time of the stage's thread inside the stage function (CLOCK_THREAD_CPUTIME_ID): unlike
  // busy_ns, not inflated while the thread waits for a core on a loaded machine; work the stage
  // hands to a thread pool (TBB, OpenCV) is not in it.
  std::atomic<uint64_t> cpu_ns{0};
  std::atomic<uint64_t> max_ns{0};
  std::atomic<uint64_t> order_violations{0};  // seq not above the previous one (must stay 0)
  std::atomic<uint64_t> held_ns{0};  // time held back before taking an item (just-in-time start)
};

// CPU time of the calling thread (ns, CLOCK_THREAD_CPUTIME_ID).
uint64_t ThreadCpuNs();

// Percentile (0..100) of `v` by nearest rank on a sorted copy; 0 for an empty vector.
double PercentileOf(std::vector<double> v, double pct);

template <class Item>
class StageGraph {
 public:
  enum class SourceResult { kItem, kSkip, kEnd };  // kSkip: nothing this time (the item is kept)
  // Source thread: fills the item (reusing its buffers) and may set meta->origin_ns.
  using SourceFn = std::function<SourceResult(Item& item, ItemMeta* meta)>;
  // Stage thread: processes the item; false rejects it.
  using StageFn = std::function<bool(Item& item, const ItemMeta& meta)>;
  // Stage thread, optional: runs after each item has left the stage (passed on, rejected or
  // dropped), before the stage takes its next one: work whose result the next stages do not need
  // (d3d-scan: the tracker's model insert, after the register stage has handed the burst to the
  // preview). Its time counts in the stage's busy, CPU and just-in-time figures.
  using AfterFn = std::function<void()>;
  struct Stage {
    std::string name;
    StageFn fn;
    AfterFn after = {};
  };

  StageGraph(const StageGraphOptions& options,
             const std::function<std::unique_ptr<Item>()>& factory, SourceFn source,
             std::vector<Stage> stages)
      : o_(options),
        source_(std::move(source)),
        stages_(std::move(stages)),
        counters_(stages_.size()) {
    o_.Check();
    if (stages_.empty()) throw std::invalid_argument("StageGraph: no stage");
    just_in_time_ = o_.policy == EdgePolicy::kLive && o_.live_demand_driven &&
                    o_.live_just_in_time && stages_.size() >= 2;
    catching_up_.store(o_.policy == EdgePolicy::kLive && o_.live_catch_up_max_s > 0,
                       std::memory_order_relaxed);
    if (o_.latency_stage >= static_cast<int>(stages_.size()))
      throw std::invalid_argument("StageGraph: latency_stage beyond the stages");
    latency_stage_ =
        o_.latency_stage < 0 ? stages_.size() - 1 : static_cast<size_t>(o_.latency_stage);
    const size_t per_edge = o_.policy == EdgePolicy::kLive ? 1 : o_.lossless_capacity;
    const size_t n_items = 1 + stages_.size() * (1 + per_edge) + o_.extra_items;
    for (size_t i = 0; i < n_items; ++i) {
      nodes_.push_back(std::make_unique<Node>());
      nodes_.back()->item = factory();
      free_.push_back(nodes_.back().get());
    }
    for (size_t i = 0; i < stages_.size(); ++i)
      edges_.push_back(MakeEdge<Node>(o_.policy, o_.lossless_capacity));
    latency_ms_.reserve(o_.latency_samples);
    done_latency_ms_.reserve(o_.latency_samples);
  }
  ~StageGraph() {
    RequestStop();
    Join();
  }
  StageGraph(const StageGraph&) = delete;
  StageGraph& operator=(const StageGraph&) = delete;

  size_t pool_size() const { return nodes_.size(); }
  // Every item of the pool (set-up only, before Start: e.g. to preallocate their buffers).
  template <class F>
  void ForEachItem(F&& f) {
    for (auto& n : nodes_) f(*n->item);
  }

  void Start() {
    t_start_ns_ = GraphNowNs();
    threads_.emplace_back([this] { SourceLoop(); });
    for (size_t i = 0; i < stages_.size(); ++i) threads_.emplace_back([this, i] { StageLoop(i); });
  }
  void RequestStop() {
    stop_.store(true, std::memory_order_release);
    pool_cv_.notify_all();
  }
  void Join() {
    for (auto& t : threads_)
      if (t.joinable()) t.join();
    threads_.clear();
  }
  bool finished() const { return finished_.load(std::memory_order_acquire); }  // last stage drained

  // Counters (any thread).
  uint64_t ingested() const { return ingested_.load(std::memory_order_relaxed); }
  uint64_t completed() const {
    return completed_.load(std::memory_order_relaxed);
  }  // left the last stage
  uint64_t dropped() const {
    uint64_t d = source_dropped_.load(std::memory_order_relaxed);
    for (const auto& e : edges_) d += e->dropped();
    return d;
  }
  // Edge i feeds stage i; edge 0's count includes the items the source dropped while catching up
  // thinned.
  uint64_t dropped_at(size_t edge) const {
    return edges_[edge]->dropped() +
           (edge == 0 ? source_dropped_.load(std::memory_order_relaxed) : 0);
  }
  const StageCounters& stage(size_t i) const { return counters_[i]; }
  const std::string& stage_name(size_t i) const { return stages_[i].name; }
  size_t num_stages() const { return stages_.size(); }
  double last_latency_ms() const { return last_latency_ms_.load(std::memory_order_relaxed); }
  int64_t first_done_ns() const { return first_done_ns_.load(std::memory_order_relaxed); }
  int64_t last_done_ns() const { return last_done_ns_.load(std::memory_order_relaxed); }
  int64_t start_ns() const { return t_start_ns_; }
  // Catch-up start (file comment): items the source held back for, and whether it is still on.
  uint64_t catch_up_items() const { return catch_up_items_.load(std::memory_order_relaxed); }
  bool catching_up() const { return catching_up_.load(std::memory_order_relaxed); }
  bool catch_up_thinned() const {
    return thinned_.load(std::memory_order_relaxed);
  }  // it fell behind and thinned out

  // After Join(): latency percentile over the kept samples (ms): to the latency stage's end, and
  // to the last stage's end (the same unless latency_stage names an earlier stage).
  double LatencyPercentileMs(double pct) const { return PercentileOf(latency_ms_, pct); }
  double DoneLatencyPercentileMs(double pct) const { return PercentileOf(done_latency_ms_, pct); }
  size_t latency_count() const { return latency_ms_.size(); }

 private:
  struct Node {
    std::unique_ptr<Item> item;
    ItemMeta meta;
  };

  static constexpr size_t kMaxCatchUpWindow = 64;  // StageGraphOptions::live_catch_up_window
  Node* TakeFree() {                               // source thread
    std::unique_lock<std::mutex> lock(pool_mu_);
    pool_cv_.wait(lock, [this] { return !free_.empty() || stop_.load(std::memory_order_acquire); });
    if (free_.empty()) return nullptr;
    Node* n = free_.back();
    free_.pop_back();
    return n;
  }
  void GiveBack(Node* n) {  // any producer / the last stage
    {
      std::lock_guard<std::mutex> lock(pool_mu_);
      free_.push_back(n);
    }
    pool_cv_.notify_one();
  }

  // Names the calling thread "g:<name>" (at most 15 characters, the kernel's limit), so that
  // top -H and perf show each stage's share of the cores.
  static void NameThisThread(const std::string& name) {
    pthread_setname_np(pthread_self(), ("g:" + name).substr(0, 15).c_str());
  }

  void SourceLoop() {
    NameThisThread("source");
    uint64_t seq = 0;
    Node* n = nullptr;
    // Catch-up start (file comment): every item, then (falling behind) one of every
    // live_catch_up_thin + 1, then latest wins.
    enum class CatchUp { kOff, kEvery, kThinned };
    CatchUp catch_up =
        catching_up_.load(std::memory_order_relaxed) ? CatchUp::kEvery : CatchUp::kOff;
    int64_t first_ns = 0;              // steady clock: the first catch-up item handed over
    int64_t thinned_ns = 0;            // steady clock: thinned since
    int caught_up_run = 0;             // consecutive items that found the graph caught up
    uint64_t kept = 0, thinned = 0;    // items handed over (catch_up_items_) / seen while thinned
    int thin = o_.live_catch_up_thin;  // thinned: items dropped after each one kept
    uint64_t judged = 0;  // kept items the trend check has seen at the current thinning
    // Ring: the ages (ns) of the latest catch-up items and the items ingested when they were handed
    // over.
    std::array<int64_t, kMaxCatchUpWindow> ages{};
    std::array<uint64_t, kMaxCatchUpWindow> ingested_at{};
    while (!stop_.load(std::memory_order_acquire)) {
      if (n == nullptr && (n = TakeFree()) == nullptr) break;
      n->meta = ItemMeta{seq, GraphNowNs()};
      const int64_t asked_ns = catch_up != CatchUp::kOff ? SteadyNowNs() : 0;
      const SourceResult r = source_(*n->item, &n->meta);
      if (r == SourceResult::kEnd) break;
      if (r == SourceResult::kSkip) continue;
      ++seq;
      ingested_.fetch_add(1, std::memory_order_relaxed);
      if (catch_up == CatchUp::kThinned && thinned++ % static_cast<uint64_t>(thin + 1) != 0) {
        source_dropped_.fetch_add(
            1, std::memory_order_relaxed);  // counted with edge 0's drops; n is reused
        continue;
      }
      if (catch_up != CatchUp::kOff) {
        // Wait for stage 0 to take the previous item rather than replace it.
        const int64_t got_ns = SteadyNowNs();
        edges_[0]->AwaitTaken();
        const int64_t taken_ns = SteadyNowNs();
        // Caught up: the source waited for this item and stage 0 had taken the previous one; or
        // the item is fresh once handed over.
        const bool waited =
            got_ns - asked_ns >= static_cast<int64_t>(o_.live_caught_up_wait_ms * 1e6) &&
            taken_ns - got_ns < static_cast<int64_t>(o_.live_caught_up_wait_ms * 1e6);
        if (first_ns == 0) first_ns = taken_ns;
        const int64_t age = GraphNowNs() - n->meta.origin_ns;  // origin: Unix epoch
        caught_up_run = waited || age <= static_cast<int64_t>(o_.live_caught_up_age_ms * 1e6)
                            ? caught_up_run + 1
                            : 0;
        // Not gaining: an item handed over less than live_catch_up_min_gain_ms per item ingested
        // since younger than the one live_catch_up_window kept items before it (the first two, slow
        // while the stages warm up, are not compared; after a change of thinning, a whole window).
        const size_t w = static_cast<size_t>(o_.live_catch_up_window);
        bool behind = false;
        if (w > 0) {
          const uint64_t first_judged = catch_up == CatchUp::kEvery ? 2 : 0;
          if (judged >= first_judged + w) {
            const double items = static_cast<double>(seq - ingested_at[judged % w]);
            behind = age > ages[judged % w] -
                               static_cast<int64_t>(items * o_.live_catch_up_min_gain_ms * 1e6);
          }
          ages[judged % w] = age;
          ingested_at[judged % w] = seq;
          ++judged;
        }
        catch_up_items_.store(++kept, std::memory_order_relaxed);
        const bool every_timed_out =
            catch_up == CatchUp::kEvery &&
            taken_ns - first_ns >= static_cast<int64_t>(o_.live_catch_up_max_s * 1e9);
        const bool thinned_timed_out =
            catch_up == CatchUp::kThinned &&
            taken_ns - thinned_ns >= static_cast<int64_t>(o_.live_catch_up_thinned_max_s * 1e9);
        const int next_thin = catch_up == CatchUp::kEvery ? o_.live_catch_up_thin : thin + 1;
        if (caught_up_run >= o_.live_caught_up_items || thinned_timed_out ||
            ((behind || every_timed_out) &&
             (next_thin < 1 || next_thin > o_.live_catch_up_max_thin))) {
          catch_up =
              CatchUp::kOff;  // caught up, out of time, or too slow for any thinning: latest wins
          catching_up_.store(false, std::memory_order_relaxed);
        } else if (behind || every_timed_out) {
          if (catch_up == CatchUp::kEvery) thinned_ns = taken_ns;
          catch_up = CatchUp::kThinned;
          thin = next_thin;
          judged = 0;
          thinned_.store(true, std::memory_order_relaxed);
          thinned = 1;  // the next item is the first of the `thin` dropped
        }
      }
      Node* dropped = edges_[0]->Push(n);
      n = dropped;  // live: the older item dropped from the slot is reused at once
    }
    if (n != nullptr) GiveBack(n);
    edges_[0]->Close();
  }

  void StageLoop(size_t i) {
    NameThisThread(stages_[i].name);
    StageCounters& c = counters_[i];
    const bool last = i + 1 == stages_.size();
    bool have_prev = false;
    uint64_t prev_seq = 0;
    Node* n = nullptr;
    const bool await_taken = !last && o_.live_demand_driven;
    // Just in time: stage 0 holds back by its own and stage 1's recent median times per item.
    const bool timed = just_in_time_ && i <= 1;
    RecentTimes own;  // this stage's wall time per item, recent (timed stages only)
    for (;;) {
      if (await_taken) edges_[i + 1]->AwaitTaken();
      if (timed && i == 0) HoldUntilJustInTime(own.Median(), &c);
      if (!edges_[i]->Pop(&n)) break;
      if (have_prev && n->meta.seq <= prev_seq)
        c.order_violations.fetch_add(1, std::memory_order_relaxed);
      have_prev = true;
      prev_seq = n->meta.seq;
      const auto t0 = std::chrono::steady_clock::now();
      const uint64_t cpu0 = ThreadCpuNs();
      const bool ok = stages_[i].fn(*n->item, n->meta);
      uint64_t ns = static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                              std::chrono::steady_clock::now() - t0)
                                              .count());
      uint64_t cpu = ThreadCpuNs() - cpu0;
      c.processed.fetch_add(1, std::memory_order_relaxed);
      if (!ok) {
        c.rejected.fetch_add(1, std::memory_order_relaxed);
        GiveBack(n);
      } else {
        if (i == latency_stage_) {
          const double ms = static_cast<double>(GraphNowNs() - n->meta.origin_ns) * 1e-6;
          KeepLatency(ms, &latency_ms_, &latency_next_);
          last_latency_ms_.store(ms, std::memory_order_relaxed);
        }
        if (last) {
          const int64_t now = GraphNowNs();
          KeepLatency(static_cast<double>(now - n->meta.origin_ns) * 1e-6, &done_latency_ms_,
                      &done_latency_next_);
          if (completed_.fetch_add(1, std::memory_order_relaxed) == 0)
            first_done_ns_.store(now, std::memory_order_relaxed);
          last_done_ns_.store(now, std::memory_order_relaxed);
          GiveBack(n);
        } else if (Node* dropped = edges_[i + 1]->Push(n); dropped != nullptr) {
          GiveBack(dropped);
        }
      }
      n = nullptr;             // no longer this stage's
      if (stages_[i].after) {  // its time counts; a blocking Push's wait before it does not
        const auto a0 = std::chrono::steady_clock::now();
        const uint64_t acpu0 = ThreadCpuNs();
        stages_[i].after();
        ns += static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::steady_clock::now() - a0)
                                        .count());
        cpu += ThreadCpuNs() - acpu0;
      }
      c.busy_ns.fetch_add(ns, std::memory_order_relaxed);
      c.cpu_ns.fetch_add(cpu, std::memory_order_relaxed);
      if (ns > c.max_ns.load(std::memory_order_relaxed))
        c.max_ns.store(ns, std::memory_order_relaxed);
      if (timed) {
        own.Add(static_cast<int64_t>(ns));
        if (i == 1) second_median_ns_.store(own.Median(), std::memory_order_relaxed);
      }
    }
    if (!last)
      edges_[i + 1]->Close();
    else
      finished_.store(true, std::memory_order_release);
  }

  // The latest kN wall times per item of one stage (its own thread). Its median, unlike
  // PercentileOf, allocates nothing: it runs once per item.
  class RecentTimes {
   public:
    void Add(int64_t ns) { ring_[count_++ % kN] = ns; }
    // Nearest-rank median of the kept times; 0 until kMin were added.
    int64_t Median() const {
      const size_t n = std::min<size_t>(count_, kN);
      if (n < kMin) return 0;
      std::array<int64_t, kN> v = ring_;
      const size_t k = (n + 1) / 2 - 1;
      std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k),
                       v.begin() + static_cast<std::ptrdiff_t>(n));
      return v[k];
    }

   private:
    static constexpr size_t kN = 16, kMin = 4;
    std::array<int64_t, kN> ring_{};
    size_t count_ = 0;
  };

  // Stage 0's thread, before it takes its next burst: sleeps until the second stage took its
  // last output + (its median time per item) − own_ns (stage 0's median) − margin (file comment).
  // No hold before both stages have timings, or once a stop was requested.
  void HoldUntilJustInTime(int64_t own_ns, StageCounters* c) {
    const int64_t next_ns = second_median_ns_.load(std::memory_order_relaxed);
    const int64_t taken = edges_[1]->last_taken_ns();
    if (own_ns <= 0 || next_ns <= 0 || taken <= 0 || stop_.load(std::memory_order_acquire)) return;
    const int64_t start =
        taken + next_ns - own_ns - static_cast<int64_t>(o_.just_in_time_margin_ms * 1e6);
    const int64_t now = SteadyNowNs();
    if (start <= now) return;
    std::this_thread::sleep_for(std::chrono::nanoseconds(start - now));
    c->held_ns.fetch_add(static_cast<uint64_t>(SteadyNowNs() - now), std::memory_order_relaxed);
  }

  StageGraphOptions o_;
  SourceFn source_;
  std::vector<Stage> stages_;
  std::vector<StageCounters> counters_;
  bool just_in_time_ = false;  // the options ask for it and the graph can do it (set-up)
  std::atomic<int64_t> second_median_ns_{
      0};  // stage 1's recent median time per item (its thread writes)
  std::vector<std::unique_ptr<Node>> nodes_;
  std::vector<std::unique_ptr<Edge<Node>>> edges_;
  std::mutex pool_mu_;
  std::condition_variable pool_cv_;
  std::vector<Node*> free_;  // guarded by pool_mu_ (capacity = pool size: no allocation)
  std::vector<std::thread> threads_;
  std::atomic<bool> stop_{false}, finished_{false};
  std::atomic<uint64_t> ingested_{0}, completed_{0};
  std::atomic<uint64_t> catch_up_items_{0};  // the source thread writes
  std::atomic<bool> catching_up_{
      false};                         // set up in the constructor; then the source thread writes
  std::atomic<bool> thinned_{false};  // the source thread writes
  std::atomic<uint64_t> source_dropped_{0};  // the source thread writes (thinned catch-up)
  std::atomic<double> last_latency_ms_{0};
  std::atomic<int64_t> first_done_ns_{0}, last_done_ns_{0};
  int64_t t_start_ns_ = 0;
  // Appends ms to a ring of the latest o_.latency_samples samples (*next: the slot to overwrite).
  void KeepLatency(double ms, std::vector<double>* ring, size_t* next) const {
    if (ring->size() < o_.latency_samples)
      ring->push_back(ms);
    else
      (*ring)[(*next)++ % o_.latency_samples] = ms;
  }
  size_t latency_stage_ = 0;
  std::vector<double> latency_ms_;  // the latency stage's thread; read after Join
  size_t latency_next_ = 0;
  std::vector<double> done_latency_ms_;  // the last stage's thread; read after Join
  size_t done_latency_next_ = 0;
};

}  // namespace d3d
