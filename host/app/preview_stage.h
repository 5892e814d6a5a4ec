// The host graph's preview stage (preview thread): adds each view to the preview's decimated model
// (or cuts undone views out), fills the next snapshot (the model, the current view highlighted at
// its pose, the cue, the pace advice) and publishes it through a triple buffer the render thread
// reads; keeps the rolling latency percentiles of the status line.
// Threads: Run and AddLatency on the preview thread; Latest on the render thread; the figures from
// any thread.
#pragma once

#include <atomic>
#include <cstdint>
#include <vector>

#include "host/app/pace_monitor.h"
#include "host/app/preview_model.h"
#include "host/app/scan_item.h"
#include "host/app/undo_log.h"
#include "host/graph/edges.h"
#include "host/graph/stage_graph.h"
#include "viewer/preview.h"

namespace d3d {

class PreviewStage {
 public:
  // view_calibration: the views' (binned; outlives the stage). view_stride_px: pixels sampled for
  // the highlighted current view. `undo` is borrowed.
  PreviewStage(const ProbeCalibration& view_calibration, const PreviewModelOptions& model,
               int view_stride_px, const UndoLog* undo);

  bool Run(ScanItem& item);
  // The graph's latency of the last burst (ms): into the status line's rolling window of 64.
  void AddLatency(double latency_ms);

  const PreviewSnapshot* Latest() { return snapshots_.Latest(); }  // nullptr before the first
  double latency_ms_p50() const { return recent_p50_.load(std::memory_order_relaxed); }
  double latency_ms_p95() const { return recent_p95_.load(std::memory_order_relaxed); }
  int64_t slow_down_cues() const {
    return pace_advices_.load();
  }                                  // times it told the dentist to slow down
  void Memory(ScanMemory* m) const;  // preview_points

 private:
  const ProbeCalibration& calibration_;
  const int view_stride_px_;
  const UndoLog* undo_;
  uint64_t epoch_ = 0, undo_gen_ = 0;
  PreviewModel model_;
  PaceMonitor pace_;  // the "slow down" cue (pace_monitor.h)
  uint64_t last_burst_seq_ = 0;
  TripleBuffer<PreviewSnapshot> snapshots_;
  std::vector<double> recent_latency_ms_;  // the rolling window
  size_t recent_next_ = 0;
  std::atomic<double> recent_p50_{0}, recent_p95_{0};
  std::atomic<int64_t> pace_advices_{0};
  std::atomic<uint64_t> mem_preview_points_{0};
};

}  // namespace d3d
