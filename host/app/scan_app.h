// The host application's scan: a stage graph (host/graph) on dedicated threads
//
//   ingest (BurstSource) → reconstruct → register → preview snapshot → fuse
//
// Each stage is its own class (ingest_stage.h, reconstruct_stage.h, register_stage.h,
// preview_stage.h, fuse_stage.h; the undo bookkeeping they share: undo_log.h); ScanApp wires them
// into the graph, takes the control calls and gathers the figures.
// running the scan chain's pieces (pipeline/chain), with a live preview handed to the render thread
// through a triple buffer, control from any thread (pause, reset, undo, save) and the host's
// figures (bursts received / processed / dropped, bursts/s, latency percentiles, per-stage timing).
// The preview is built from the registered views' points (a decimated point model), not from the
// TSDF, so it comes before the fuse stage: a burst is on screen once it is registered, and the
// latency (capture to preview) does not include its fusion, which only the saved model waits for
// (the report gives both: latency_ms_* and latency_fused_ms_*). A burst processed = fused or
// refused.
//
// Buffers and threads (who owns what):
//   ScanItem (pool of the graph): frames (ingest writes), view (reconstruct writes; register, fuse
//   and
//     preview read), track (register writes; fuse and preview read), kept_frames (reconstruct
//     writes, fuse reads), packed (fuse). One thread at a time, handed over by the graph's edges.
//   ScanReconstructor: reconstruct thread.   ScanRegistrar (Tracker): register thread (with
//     d3d-scan's keyframe features on demand, their SIFT too, when a relocalisation needs them);
//     with KeyframeGraphOptions::FeatureTiming::kWorker, the tracker's keyframe-feature worker
//     thread touches only the copies of a keyframe's points and texture it is handed and its own
//     job and result lists (tracker.cpp).
//   BurstRing (live, ScanAppOptions::bridge): the ingest thread puts every burst, the register
//     thread's GapBridge (its own reconstructor and view) takes one, under the ring's mutex.
//   ScanFuser (the live TSDF, at ScanAppOptions::live) and the ViewArchive: fuse thread,
//     then Finish(), under the fuse stage's model lock, which SaveNow() (a saver thread) also
//     takes.
//   FramePacker: fuse thread.
//   Preview grid (the decimated model) and the TripleBuffer's back copy: preview thread.
//   The TripleBuffer's front copy: the render thread (LatestSnapshot()).
//   Memory figures (Memory()): atomics the register and fuse stages store, any thread loads.
//   After Join(): everything belongs to the thread that calls Finish().
// Control flags (pause, reset epoch, undo requests) and counters are atomics. Reset bumps an epoch
// that travels with the items, so each stage resets its own state when the first item of the new
// epoch arrives (in order, without locks).
// Undo ("undo last seconds", RequestUndo): the ingest thread sends the request down the graph as a
// control item (no burst: it goes through while paused or while the probe is away) and stamps the
// request count on every burst after it (a live edge may drop the control item). The register stage
// takes the views back (ScanRegistrar::UndoLastSeconds) and logs where each undo cut the views
// (UndoLog; read only when an item brings a newer undo); the preview stage drops
// those views' points, the fuse stage their kept frames. The live TSDF cannot forget a view, so it
// still holds them: SaveNow fuses the kept views again first, and Finish always does.
#pragma once

#include <cstdint>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "host/app/burst_source.h"
#include "host/app/fuse_stage.h"
#include "host/app/gap_bridge.h"
#include "host/app/ingest_stage.h"
#include "host/app/preview_stage.h"
#include "host/app/reconstruct_stage.h"
#include "host/app/register_stage.h"
#include "host/app/scan_item.h"
#include "host/app/undo_log.h"
#include "host/graph/stage_graph.h"
#include "pipeline/chain/scan_chain.h"
#include "viewer/preview.h"

namespace d3d {

struct ScanAppOptions {
  ScanOptions scan;                           // the scan chain's pieces (pipeline/chain)
  EdgePolicy policy = EdgePolicy::kLossless;  // the graph's edges: live (latest wins) or lossless
  size_t lossless_capacity = 3;               // items per lossless edge
  // Live: the reconstruct stage starts each burst just in time for the register stage
  // (StageGraphOptions::live_just_in_time), on a newer burst instead of one that then waits.
  bool live_just_in_time = true;
  // Live: the bursts that queued while the host set up (the probe streams from the moment its
  // calibration arrives) are processed in order until the graph has caught up, for at most this
  // long (StageGraphOptions::live_catch_up_max_s; 0 = start on the newest burst, dropping them).
  // The source must hold them: d3d-scan's DDS receiver keeps up to 1 s of bursts live.
  double live_catch_up_max_s = 1.0;
  double preview_cell_mm = 0.2;  // one preview point per cell of this size
  size_t preview_max_points =
      150000;  // the preview stops adding points beyond this (draw cost; docs/decisions/0015)
  int preview_stride_px = 3;  // pixels sampled per view for the preview model
  int view_stride_px = 8;     // pixels sampled for the highlighted current view
  // Keep the frames of every fused view (zstd: pipeline/chain/view_archive.h) so that Finish can
  // fuse them again at the pose graph's poses when it is given no view provider (with
  // ScanOptions::refuse_min_correction_mm >= 0). In memory they grow with the scan (sizes:
  // docs/decisions/0015); see views_spill_dir.
  bool keep_views = true;
  // keep_views: a directory for the kept frames (an unnamed temporary file there, ViewArchive::
  // SpillTo; gone when the scan app is), so that memory holds only their index (tens of bytes a
  // view) and stays flat however long the scan. Empty = in memory. When no file can be made there
  // the frames stay in memory and the report says why (views_spill_error); a write that fails later
  // keeps that view's frames in memory (views_spill_failures).
  std::string views_spill_dir;
  // The live TSDF the fuse stage fuses every burst into, when keep_views is on (else the scan's:
  // the live volume is then the result). It is what SaveNow saves mid-scan; Finish always fuses the
  // kept views again at scan.tsdf.voxel_mm (FinishScan), so the final model does not depend on it.
  LiveVolumeOptions live;
  // The live volume's options: live.Of(scan.tsdf) when keep_views is on, else scan.tsdf.
  TsdfOptions LiveTsdf() const;
  // Undo: each request takes back the views captured in the last undo_seconds (of the views still
  // in the model); the tracker's undo journal reaches back undo_max_views views
  // (OdometryOptions::map.undo_inserts; its memory per view: docs/decisions/0015). 0 or keep_views
  // off = no undo (the fused model could not leave the undone views out).
  double undo_seconds = 2.0;
  int undo_max_views = 150;
  // Scripted undo requests (tests, demos): one right after the N-th burst ingested, for each N.
  std::vector<uint64_t> undo_after_bursts;
  // Live: a view refused several bursts after the last one placed is tried again after a burst from
  // between them is placed (gap_bridge.h); the ring of recent bursts it takes them from.
  GapBridgeOptions bridge;
  // Lossless too: a replay of chosen views (d3d-scan --replay-views) bridges from the bursts it
  // leaves out, as the live host it reproduces did from those its graph dropped.
  bool bridge_lossless = false;
  void Check() const;  // throws std::invalid_argument
};

class ScanApp {
 public:
  // `source` is borrowed and must outlive Join(). Throws std::invalid_argument for bad options or
  // calibration. Live policy: the constructor also warms up every pool item (one reconstruction of
  // a blank burst each), so that the first views are not slowed by allocating their maps; the time
  // is reported as warm_up_ms.
  ScanApp(const ProbeCalibration& calibration, const ScanAppOptions& options, BurstSource* source);
  ~ScanApp();

  void Start();
  void RequestStop();  // any thread: the source ends; lossless edges drain
  void Join();
  bool finished() const { return graph_->finished(); }
  // Why the kept frames stay in memory although views_spill_dir was given (empty: they spill, or
  // were not to). Set by the constructor.
  const std::string& views_spill_error() const { return fuse_->spill_error(); }

  // Control, any thread.
  void SetPaused(bool paused) { ingest_->SetPaused(paused); }
  bool paused() const { return ingest_->paused(); }
  void Reset() { ingest_->Reset(); }
  // Takes back the views of the last options().undo_seconds (any thread; applied in order with the
  // bursts, see the file comment). false when undo is off (undo_max_views 0 or keep_views off).
  bool RequestUndo() { return undo_.Request(); }
  bool undo_available() const { return undo_.enabled(); }
  // What the latest undo did ("undid 2.0 s: 57 views", or why nothing), and how many undos have
  // been applied or refused so far (any thread).
  std::string LastUndoMessage() const { return undo_.LastMessage(); }
  uint64_t undos_done() const { return undo_.done(); }
  // Any thread but the stages': extracts the current model (the live volume, at options().live;
  // waits for the fuse stage's current burst) and writes DIR/scan.ply and DIR/scan.stl. An undo
  // asked for before the call is in the saved model: it first waits (at most 10 s) until an item
  // carrying that request has reached the fuse stage, which has then taken those views' frames out
  // (UNAVAILABLE if that does not happen in time: a stalled graph). After an undo the live volume
  // still holds the undone views: the kept views are first fused again into a new volume at their
  // tracked poses (the fuse stage waits; without the register thread's model anchoring, which
  // Finish's refusion adds back), which then replaces the live one. INTERNAL for an empty model;
  // a kept view that cannot be read back: its error.
  [[nodiscard]] Status SaveNow(const std::string& dir) {
    return fuse_->Save(undo_.requests(), dir);
  }

  // Render thread only: the newest snapshot (nullptr before the first).
  const PreviewSnapshot* LatestSnapshot() { return preview_->Latest(); }
  // Any thread.
  PreviewStatus CurrentStatus() const;
  // Any thread: the figures as the stages last published them (the register stage every
  // kMemoryEvery views, the fuse stage every kMemoryEvery fused views).
  ScanMemory Memory() const;
  static constexpr uint64_t kMemoryEvery = kScanMemoryEvery;

  // After Join(): pose graph, mesh, evaluation (FinishScan) with the host's figures added to the
  // report. `provider` may be empty: the kept views are then fused again (keep_views), if any.
  [[nodiscard]] Status Finish(const ScanTruth& truth, const ScanViewProvider& provider,
                              ScanResult* out);
  // The host's figures (any time; percentiles only after Join()).
  nlohmann::json HostReport() const;
  // The views' calibration: the probe's, binned when options.scan.bin > 1.
  const ProbeCalibration& calibration() const { return calibration_; }
  const ScanAppOptions& options() const { return o_; }

 private:
  using Graph = StageGraph<ScanItem>;
  uint64_t BurstsCompleted() const;  // items the graph completed that carried a burst

  ProbeCalibration calibration_;  // the views' (binned with o_.scan.bin)
  ScanAppOptions o_;  // as given, with the undo journal and the deferred model insert set
  BurstSource* source_;
  UndoLog undo_;
  std::unique_ptr<BurstRing>
      ring_;  // live bridging: the ingest stage puts, the register stage's bridge takes
  std::unique_ptr<IngestStage> ingest_;
  std::unique_ptr<ReconstructStage> reconstruct_;
  std::unique_ptr<RegisterStage> register_;
  std::unique_ptr<PreviewStage> preview_;
  std::unique_ptr<FuseStage> fuse_;
  double ms_warm_up_ = 0;  // constructor: the pool items' warm-up (report: warm_up_ms)
  std::unique_ptr<Graph> graph_;
};

}  // namespace d3d
