#include "host/app/register_stage.h"

#include <utility>

namespace d3d {

RegisterStage::RegisterStage(const ProbeCalibration& view_calibration, const ScanOptions& scan,
                             double undo_seconds, UndoLog* undo, std::unique_ptr<GapBridge> bridge)
    : calibration_(view_calibration),
      scan_(scan),
      undo_seconds_(undo_seconds),
      undo_(undo),
      bridge_(std::move(bridge)) {
  registrar_ = MakeRegistrar();
}

std::unique_ptr<ScanRegistrar> RegisterStage::MakeRegistrar() const {
  return std::make_unique<ScanRegistrar>(calibration_, scan_.tracker, scan_.anchor,
                                         scan_.recon.normal_max_gap_mm);
}

bool RegisterStage::Run(ScanItem& item) {
  if (item.epoch != epoch_) {
    registrar_ = MakeRegistrar();
    epoch_ = item.epoch;
    last_placed_ns_ = 0;
  }
  for (; undo_requests_ < item.undo_requests; ++undo_requests_)
    if (undo_->Record(registrar_->UndoLastSeconds(undo_seconds_))) ++undo_gen_;
  item.undo_gen = undo_gen_;
  if (item.control) {
    item.track = TrackResult{};
    item.track.state = registrar_->tracker().state();
    item.view_index = -1;
    return true;
  }
  item.view_index = static_cast<int64_t>(registrar_->views().size());
  const TrackingState before = registrar_->tracker().state();
  item.track = registrar_->Register(item.view, item.burst.burst_seq, item.burst.capture_ns);
  if (bridge_ && bridge_->Applies(before, item.track, item.burst.capture_ns, last_placed_ns_)) {
    // A gap the live policy left: a burst from between placed first, then this view again.
    int64_t placed_ns = 0;
    const bool placed =
        bridge_->Bridge(registrar_.get(), last_placed_ns_, item.burst.capture_ns, &placed_ns);
    bridge_views_.store(bridge_->stats().views, std::memory_order_relaxed);
    bridge_attempts_.store(bridge_->stats().attempts, std::memory_order_relaxed);
    bridge_placed_.store(bridge_->stats().placed, std::memory_order_relaxed);
    if (placed) {
      last_placed_ns_ = placed_ns;
      item.view_index = static_cast<int64_t>(registrar_->views().size());
      item.track = registrar_->Register(item.view, item.burst.burst_seq, item.burst.capture_ns);
      if (item.track.accepted) bridge_resumed_.fetch_add(1, std::memory_order_relaxed);
    }
  }
  if (item.track.accepted) last_placed_ns_ = item.burst.capture_ns;
  if (!item.track.accepted) refused_.fetch_add(1, std::memory_order_relaxed);
  view_pending_ = true;
  return true;  // refused views still go on: the preview shows them (red)
}

void RegisterStage::After() {
  if (!view_pending_) return;  // a control item
  view_pending_ = false;
  registrar_->Commit();  // the view's model insert, now that the preview has the burst
  if (++memory_views_ >= kScanMemoryEvery) {
    memory_views_ = 0;
    constexpr double kMiB = 1.0 / (1024.0 * 1024.0);
    const Tracker& tracker = registrar_->tracker();
    mem_views_.store(registrar_->views().size(), std::memory_order_relaxed);
    mem_model_samples_.store(tracker.model().size(), std::memory_order_relaxed);
    mem_model_mib_.store(static_cast<double>(tracker.model().memory_bytes()) * kMiB,
                         std::memory_order_relaxed);
    mem_undo_journal_mib_.store(static_cast<double>(tracker.model().journal_bytes()) * kMiB,
                                std::memory_order_relaxed);
    mem_keyframes_.store(tracker.keyframes().size(), std::memory_order_relaxed);
    mem_keyframes_mib_.store(static_cast<double>(tracker.keyframe_bytes()) * kMiB,
                             std::memory_order_relaxed);
  }
}

nlohmann::json RegisterStage::BridgeReport() const {
  return {{"views", bridge_views_.load()},
          {"attempts", bridge_attempts_.load()},
          {"placed", bridge_placed_.load()},
          {"resumed", bridge_resumed_.load()}};
}

void RegisterStage::Memory(ScanMemory* m) const {
  m->views = mem_views_.load(std::memory_order_relaxed);
  m->model_samples = mem_model_samples_.load(std::memory_order_relaxed);
  m->model_mib = mem_model_mib_.load(std::memory_order_relaxed);
  m->undo_journal_mib = mem_undo_journal_mib_.load(std::memory_order_relaxed);
  m->keyframes = mem_keyframes_.load(std::memory_order_relaxed);
  m->keyframes_mib = mem_keyframes_mib_.load(std::memory_order_relaxed);
}

}  // namespace d3d
