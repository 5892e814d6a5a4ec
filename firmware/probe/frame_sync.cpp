#include "firmware/probe/frame_sync.h"

#include <cstdlib>

namespace d3d {

void FrameSyncOptions::Check() const {
  D3D_CHECK_MSG(patterns_per_burst >= 1 && patterns_per_burst <= 8,
                "patterns_per_burst must be in 1..8, got " << patterns_per_burst);
  D3D_CHECK_MSG(tolerance_ns > 0, "tolerance_ns must be positive");
}

FrameSync::FrameSync(const FrameSyncOptions& options) : options_(options) { options.Check(); }

void FrameSync::OnTrigger(int pattern_index, uint64_t trigger_seq, int64_t t_ns) {
  triggers_.push_back({pattern_index, trigger_seq, t_ns});
  if (pattern_index == 0) {
    // A new burst begins: the previous one, if unfinished, lost frames.
    if (!partial_.empty()) DropPartial(Drop::kIncomplete);
    skip_until_pattern0_ = false;
  }
  while (triggers_.size() > 16) triggers_.pop_front();
}

void FrameSync::DropPartial(Drop why) {
  // Count a burst once: not again for the remaining frames of a burst already dropped.
  if (!skip_until_pattern0_ || !partial_.empty()) {
    switch (why) {
      case Drop::kIncomplete:
        ++counters_.dropped_incomplete;
        break;
      case Drop::kTorn:
        ++counters_.dropped_torn;
        break;
      case Drop::kOutOfOrder:
        ++counters_.dropped_out_of_order;
        break;
    }
  }
  partial_.clear();
  skip_until_pattern0_ = true;
}

bool FrameSync::OnFrame(const CapturedFrame& frame, std::vector<CapturedFrame>* burst) {
  // Camera frame counter: a gap means the sensor lost frames in between.
  const bool camera_gap = have_camera_seq_ && frame.camera_frame_seq != last_camera_seq_ + 1;
  if (have_camera_seq_ && frame.camera_frame_seq > last_camera_seq_ + 1)
    counters_.frames_lost += frame.camera_frame_seq - last_camera_seq_ - 1;
  last_camera_seq_ = frame.camera_frame_seq;
  have_camera_seq_ = true;
  if (camera_gap && !partial_.empty()) DropPartial(Drop::kIncomplete);

  // The frame must have latched the latest trigger (the one it was captured under).
  if (triggers_.empty() || frame.trigger_seq != triggers_.back().seq) {
    DropPartial(Drop::kOutOfOrder);
    return false;
  }
  const Trigger& trig = triggers_.back();
  if (std::llabs(frame.timestamp_ns - trig.t_ns) > options_.tolerance_ns) {
    DropPartial(Drop::kTorn);
    return false;
  }
  if (skip_until_pattern0_) {
    return false;  // the rest of a burst already dropped and counted
  } else if (trig.pattern_index != static_cast<int>(partial_.size()) ||
             (!partial_.empty() && trig.seq != partial_.back().trigger_seq + 1)) {
    DropPartial(Drop::kIncomplete);  // frames of this burst went missing before this one
    return false;
  }
  partial_.push_back(frame);
  partial_.back().pattern_index = trig.pattern_index;
  if (static_cast<int>(partial_.size()) < options_.patterns_per_burst) return false;
  burst->swap(partial_);
  partial_.clear();
  ++counters_.bursts_complete;
  return true;
}

}  // namespace d3d
