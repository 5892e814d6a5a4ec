// The host graph's fuse stage (fuse thread): fuses each placed view into the live volume, keeps the
// fused views' frames (packed, in the view archive: memory or a spill file) for the refusion at the
// end, and takes the frames of undone views out. It owns the model: a save mid-scan (Save, another
// thread) and the end of the scan (Finish) take the model's lock.
// Threads: Run on the fuse thread; Save from any thread but the stages' (under the model's lock,
// waiting on the fuse stage); Finish and Report after the graph has joined; the counters and
// Memory from any thread.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "host/app/scan_item.h"
#include "host/app/undo_log.h"
#include "pipeline/chain/scan_chain.h"
#include "pipeline/chain/view_archive.h"

namespace d3d {

struct FuseStageOptions {
  TsdfOptions live_tsdf;  // the live volume (ScanAppOptions::LiveTsdf)
  FreeSpaceOptions free_space;
  ReconstructOptions recon;     // of the kept views when they are fused again
  bool keep_views = true;       // ScanAppOptions::keep_views
  std::string views_spill_dir;  // ScanAppOptions::views_spill_dir
};

class FuseStage {
 public:
  // view_calibration: the views' (binned); `undo` is borrowed.
  FuseStage(const ProbeCalibration& view_calibration, const FuseStageOptions& options,
            const UndoLog* undo);

  bool Run(ScanItem& item);
  // The current model (the live volume; the kept views fused again first when it holds undone
  // views) as DIR/scan.ply and DIR/scan.stl, once the undos asked for before (`undo_requests`)
  // have reached this stage (at most 10 s: UNAVAILABLE). INTERNAL for an empty model.
  [[nodiscard]] Status Save(uint64_t undo_requests, const std::string& dir);
  // After Join: FinishScan on the live volume with `registrar`; without a provider the kept views
  // are fused again (keep_views). times.ms_fuse is set here.
  [[nodiscard]] Status Finish(const ScanOptions& scan, ScanTimes times, ScanRegistrar* registrar,
                              const ScanViewProvider& provider, const ScanTruth& truth,
                              ScanResult* out);
  // The kept views' figures (views_kept, views_kept_mib, views_spilled, spill errors).
  void Report(nlohmann::json* host) const;

  uint64_t fused() const { return fused_.load(); }
  uint64_t control_done() const { return control_done_.load(); }
  const ScanFuser& fuser() const { return *fuser_; }  // after Join
  // Why the kept frames stay in memory although a spill folder was given (empty: they spill).
  const std::string& spill_error() const { return spill_error_; }
  void Memory(ScanMemory* m) const;  // tsdf_mib, views_kept_memory_mib

 private:
  std::unique_ptr<ScanFuser> MakeFuser() const;

  const ProbeCalibration& calibration_;  // the app's (outlives the stage)
  const FuseStageOptions o_;
  const UndoLog* undo_;
  FramePacker packer_;
  std::mutex model_mu_;
  std::condition_variable model_cv_;  // undo_requests_ moved (Save waits for it)
  uint64_t epoch_ = 0, undo_gen_ = 0;
  uint64_t undo_requests_ = 0;  // undo requests applied up to the last item
  std::unique_ptr<ScanFuser> fuser_;
  ViewArchive archive_;          // keep_views: the fused views' frames
  std::string spill_error_;      // constructor: why the archive could not spill
  uint64_t spill_failures_ = 0;  // Adds whose spill write failed (kept in memory)
  std::string spill_failure_;    // ... the first one's error
  struct FusedView {
    int64_t view_index;
    uint64_t burst_seq;
    Rigid3d world_from_cam;  // tracked
  };
  std::vector<FusedView> fused_views_;  // keep_views: the archive's views, in order
  bool volume_has_undone_ = false;      // the live volume holds views an undo took back
  uint64_t memory_views_ = 0;           // fused views since the figures were last published
  std::atomic<uint64_t> fused_{0}, control_done_{0};
  std::atomic<double> mem_tsdf_mib_{0}, mem_views_kept_mib_{0};
};

}  // namespace d3d
