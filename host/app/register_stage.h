// The host graph's register stage (register thread): applies the undo requests an item carries,
// registers the view onto the model (ScanRegistrar: tracking, relocalisation, segments), bridges a
// gap the live policy left (gap_bridge.h) and, in its after-hook, commits the view's model insert
// once the preview has the burst; publishes its memory figures.
// Threads: Run and After on the register thread; the counters and Memory from any thread;
// registrar() after the graph has joined.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <nlohmann/json.hpp>

#include "host/app/gap_bridge.h"
#include "host/app/scan_item.h"
#include "host/app/undo_log.h"
#include "pipeline/chain/scan_chain.h"

namespace d3d {

class RegisterStage {
 public:
  // view_calibration: the views' (binned). `scan`: its tracker, anchor and recon options are the
  // registrar's (made again on a reset). `undo` is borrowed; `bridge` may be null (no bridging).
  RegisterStage(const ProbeCalibration& view_calibration, const ScanOptions& scan,
                double undo_seconds, UndoLog* undo, std::unique_ptr<GapBridge> bridge);

  bool Run(ScanItem& item);
  // The graph's after-hook: the tracker's model insert of the view just handed to the preview
  // (OdometryOptions::defer_model_insert), then the memory figures every kScanMemoryEvery views.
  void After();

  ScanRegistrar* registrar() { return registrar_.get(); }
  uint64_t refused() const { return refused_.load(); }
  // Live bridging: refused views bridged, bursts tried and placed between, views then placed.
  nlohmann::json BridgeReport() const;
  void Memory(ScanMemory* m) const;  // views … keyframes_mib

 private:
  std::unique_ptr<ScanRegistrar> MakeRegistrar() const;

  const ProbeCalibration& calibration_;  // the app's (outlives the stage)
  const ScanOptions& scan_;              // the app's (outlives the stage)
  const double undo_seconds_;
  UndoLog* undo_;
  std::unique_ptr<GapBridge> bridge_;
  std::unique_ptr<ScanRegistrar> registrar_;
  uint64_t epoch_ = 0;
  uint64_t undo_requests_ = 0, undo_gen_ = 0;
  uint64_t memory_views_ = 0;   // views since the figures were last published
  bool view_pending_ = false;   // Run registered a view, After commits it
  int64_t last_placed_ns_ = 0;  // capture time of the last view the tracker placed (this epoch)
  std::atomic<uint64_t> refused_{0};
  std::atomic<uint64_t> bridge_views_{0}, bridge_attempts_{0}, bridge_placed_{0},
      bridge_resumed_{0};
  std::atomic<uint64_t> mem_views_{0}, mem_model_samples_{0}, mem_keyframes_{0};
  std::atomic<double> mem_model_mib_{0}, mem_undo_journal_mib_{0}, mem_keyframes_mib_{0};
};

}  // namespace d3d
