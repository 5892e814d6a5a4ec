// The host graph's source (ingest thread): takes the next burst from the BurstSource into a pool
// item, or sends a pending undo request down the graph as a control item; drops bursts while
// paused; keeps each burst in the gap bridge's ring; sets the item's latency origin.
// Threads: Run on the ingest thread only; the control calls (SetPaused, Reset) and the counters
// from any thread.
#pragma once

#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "host/app/burst_source.h"
#include "host/app/gap_bridge.h"
#include "host/app/scan_item.h"
#include "host/app/undo_log.h"
#include "host/graph/stage_graph.h"

namespace d3d {

class IngestStage {
 public:
  // `source`, `undo` and `ring` (null: no bridging) are borrowed and outlive the stage.
  // undo_after_bursts: a scripted undo request right after each of these bursts (counted from 1).
  IngestStage(BurstSource* source, UndoLog* undo, BurstRing* ring,
              std::vector<uint64_t> undo_after_bursts);

  // Ingest thread: the graph's source function.
  StageGraph<ScanItem>::SourceResult Run(ScanItem& item, ItemMeta* meta);

  void SetPaused(bool paused) { paused_.store(paused); }
  bool paused() const { return paused_.load(); }
  void Reset() { epoch_.fetch_add(1); }  // the next items start a new model
  uint64_t paused_bursts() const { return paused_bursts_.load(); }
  // Where the latencies were measured from: "capture", "receive", both joined by '+', or "ingest".
  std::string LatencyOrigin() const;

 private:
  BurstSource* source_;
  UndoLog* undo_;
  BurstRing* ring_;
  const std::vector<uint64_t> undo_after_bursts_;
  std::atomic<bool> paused_{false};
  std::atomic<uint64_t> epoch_{0};
  std::atomic<uint64_t> paused_bursts_{0}, control_items_{0};
  std::atomic<uint64_t> latency_origin_capture_{0}, latency_origin_receive_{0};
  uint64_t undo_ingested_ = 0;  // undo requests already sent down the graph
  uint64_t bursts_ingested_ = 0;
};

}  // namespace d3d
