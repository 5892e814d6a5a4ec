// Frame ↔ pattern synchronisation: pairs each camera frame with the projector trigger that lit it
// and assembles bursts of patterns 0..N−1. A frame is paired by the trigger counter it latched
// (CapturedFrame::trigger_seq) and must lie within `tolerance_ns` of that trigger's time; the
// frames of a burst must be consecutive in both the trigger and the camera frame counters. A burst
// that is incomplete (a frame missing: counter gap, or a new pattern 0 before the end), torn (a
// frame exposed away from its trigger) or out of order (a frame latched a trigger that is not the
// next one) is dropped whole and counted; it is never published.
//
// Threads: one thread (the capture loop) calls OnTrigger/OnFrame; counters() may be read from any
// thread (atomics).
#pragma once

#include <atomic>
#include <cstdint>
#include <deque>
#include <vector>

#include "firmware/probe/capture_backend.h"

namespace d3d {

struct FrameSyncOptions {
  int patterns_per_burst = 4;
  int64_t tolerance_ns = 500'000;  // |frame time − trigger time| allowed (default 0.5 ms)
  void Check() const;              // throws std::invalid_argument
};

struct FrameSyncCounters {
  std::atomic<uint64_t> bursts_complete{0};
  std::atomic<uint64_t> dropped_incomplete{0};
  std::atomic<uint64_t> dropped_torn{0};
  std::atomic<uint64_t> dropped_out_of_order{0};
  std::atomic<uint64_t> frames_lost{0};  // camera frame counter gaps (frames the sensor dropped)
  uint64_t dropped_total() const {
    return dropped_incomplete + dropped_torn + dropped_out_of_order;
  }
};

class FrameSync {
 public:
  explicit FrameSync(const FrameSyncOptions& options);
  void OnTrigger(int pattern_index, uint64_t trigger_seq, int64_t t_ns);
  // True when `frame` completes a burst: *burst then holds its frames in pattern order.
  bool OnFrame(const CapturedFrame& frame, std::vector<CapturedFrame>* burst);
  const FrameSyncCounters& counters() const { return counters_; }

 private:
  struct Trigger {
    int pattern_index;
    uint64_t seq;
    int64_t t_ns;
  };
  enum class Drop { kIncomplete, kTorn, kOutOfOrder };
  void DropPartial(Drop why);
  FrameSyncOptions options_;
  std::deque<Trigger> triggers_;  // the last few triggers
  std::vector<CapturedFrame> partial_;
  uint64_t last_camera_seq_ = 0;
  bool have_camera_seq_ = false;
  bool skip_until_pattern0_ =
      false;  // the current burst was dropped: ignore frames until pattern 0
  FrameSyncCounters counters_;
};

}  // namespace d3d
