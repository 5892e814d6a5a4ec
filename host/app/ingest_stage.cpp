#include "host/app/ingest_stage.h"

#include <utility>

namespace d3d {

IngestStage::IngestStage(BurstSource* source, UndoLog* undo, BurstRing* ring,
                         std::vector<uint64_t> undo_after_bursts)
    : source_(source), undo_(undo), ring_(ring), undo_after_bursts_(std::move(undo_after_bursts)) {
  // A replay's left-out bursts are the ones a live graph would have dropped: bridgeable too.
  if (ring_) source_->set_skipped_sink([this](const IngestedBurst& b) { ring_->Put(b); });
}

StageGraph<ScanItem>::SourceResult IngestStage::Run(ScanItem& item, ItemMeta* meta) {
  using Result = StageGraph<ScanItem>::SourceResult;
  item.recon_ok = false;
  item.fused = false;
  const uint64_t undo = undo_->requests();
  if (undo != undo_ingested_) {
    // An undo request goes down the graph at once, without a burst (paused, or no probe).
    undo_ingested_ = undo;
    item.control = true;
    item.undo_requests = undo;
    item.epoch = epoch_.load(std::memory_order_relaxed);
    item.packed_ok = false;
    control_items_.fetch_add(1, std::memory_order_relaxed);
    return Result::kItem;
  }
  const BurstSource::Result r = source_->Next(&item.burst);
  if (r == BurstSource::Result::kEnd) return Result::kEnd;
  if (r == BurstSource::Result::kNothing) return Result::kSkip;
  if (paused_.load(std::memory_order_relaxed)) {
    paused_bursts_.fetch_add(1, std::memory_order_relaxed);
    return Result::kSkip;
  }
  if (ring_) ring_->Put(item.burst);  // kept or dropped by the graph, a burst a bridge may use
  item.control = false;
  item.undo_requests = undo_ingested_;
  item.epoch = epoch_.load(std::memory_order_relaxed);
  ++bursts_ingested_;
  for (const uint64_t n : undo_after_bursts_)
    if (n == bursts_ingested_) (void)undo_->Request();  // sent before the next burst
  // Latency origin: the capture time when the probe's clock agrees with ours (live), else the
  // time the host received the burst (a replayed recording carries its old capture times).
  const int64_t now = GraphNowNs();
  if (item.burst.capture_ns > 0 && item.burst.capture_ns <= now &&
      now - item.burst.capture_ns < 2'000'000'000) {
    meta->origin_ns = item.burst.capture_ns;
    latency_origin_capture_.fetch_add(1, std::memory_order_relaxed);
  } else if (item.burst.receive_ns > 0 && item.burst.receive_ns <= now &&
             now - item.burst.receive_ns < 2'000'000'000) {
    meta->origin_ns = item.burst.receive_ns;
    latency_origin_receive_.fetch_add(1, std::memory_order_relaxed);
  }  // else: the ingest time (set by the graph)
  return Result::kItem;
}

std::string IngestStage::LatencyOrigin() const {
  const bool capture = latency_origin_capture_.load() > 0,
             receive = latency_origin_receive_.load() > 0;
  return capture ? (receive ? "capture+receive" : "capture") : (receive ? "receive" : "ingest");
}

}  // namespace d3d
