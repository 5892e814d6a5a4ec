// The host application's scan: a stage graph (host/graph) on dedicated threads
//
//   ingest (BurstSource) → reconstruct → register → preview snapshot → fuse
//
// running the scan chain's pieces (pipeline/scan), with a live preview handed to the render thread
// through a triple buffer, control from any thread (pause, reset, undo, save) and the host's figures
// (bursts received / processed / dropped, bursts/s, latency percentiles, per-stage timing).
// The preview is built from the registered views' points (a decimated point model), not from the
// TSDF, so it comes before the fuse stage: a burst is on screen once it is registered, and the
// latency (capture to preview) does not include its fusion, which only the saved model waits for
// (the report gives both: latency_ms_* and latency_fused_ms_*). A burst processed = fused or refused.
//
// Buffers and threads (who owns what):
//   ScanItem (pool of the graph): frames (ingest writes), view (reconstruct writes; register, fuse and
//     preview read), track (register writes; fuse and preview read), kept_frames (reconstruct writes,
//     fuse reads), packed (fuse). One thread at a time, handed over by the graph's edges.
//   ScanReconstructor: reconstruct thread.   ScanRegistrar (Tracker): register thread (with
//     d3d-scan's keyframe features on demand, their SIFT too, when a relocalisation needs them);
//     with KeyframeGraphOptions::FeatureTiming::kWorker, the tracker's keyframe-feature worker thread
//     touches only the copies of a keyframe's points and texture it is handed and its own job and
//     result lists (tracker.cpp).
//   BurstRing (live, ScanAppOptions::bridge): the ingest thread puts every burst, the register
//     thread's GapBridge (its own reconstructor and view) takes one, under the ring's mutex.
//   ScanFuser (the live TSDF, at ScanAppOptions::live) and the ViewArchive: fuse thread,
//     then Finish(), under model_mu_, which SaveNow() (a saver thread) also takes.
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
// (undo_log_, under undo_mu_; read only when an item brings a newer undo); the preview stage drops
// those views' points, the fuse stage their kept frames. The live TSDF cannot forget a view, so it
// still holds them: SaveNow fuses the kept views again first, and Finish always does.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <unordered_map>
#include <vector>

#include "host/graph/stage_graph.h"
#include "host/scan/burst_source.h"
#include "host/scan/gap_bridge.h"
#include "host/scan/pace_monitor.h"
#include "host/scan/preview_model.h"
#include "pipeline/scan/scan_chain.h"
#include "pipeline/scan/view_archive.h"
#include "viewer/preview.h"

namespace d3d {

struct ScanAppOptions {
  ScanOptions scan;
  EdgePolicy policy = EdgePolicy::kLossless;
  size_t lossless_capacity = 3;      // items per lossless edge
  // Live: the reconstruct stage starts each burst just in time for the register stage
  // (StageGraphOptions::live_just_in_time), on a newer burst instead of one that then waits.
  bool live_just_in_time = true;
  // Live: the bursts that queued while the host set up (the probe streams from the moment its
  // calibration arrives) are processed in order until the graph has caught up, for at most this
  // long (StageGraphOptions::live_catch_up_max_s; 0 = start on the newest burst, dropping them).
  // The source must hold them: d3d-scan's DDS receiver keeps up to 1 s of bursts live.
  double live_catch_up_max_s = 1.0;
  double preview_cell_mm = 0.2;      // one preview point per cell of this size
  size_t preview_max_points = 150000;  // the preview stops adding points beyond this (llvmpipe: ~100k at 20 fps)
  int preview_stride_px = 3;         // pixels sampled per view for the preview model
  int view_stride_px = 8;            // pixels sampled for the highlighted current view
  // Keep the frames of every fused view (zstd, ~150-200 kB per burst at bin 2: pipeline/scan/
  // view_archive.h) so that Finish can fuse them again at the pose graph's poses when it is given
  // no view provider (with ScanOptions::refuse_min_correction_mm >= 0). In memory they grow with the
  // scan (4-5 MB/s live); see views_spill_dir.
  bool keep_views = true;
  // keep_views: a directory for the kept frames (an unnamed temporary file there, ViewArchive::
  // SpillTo; gone when the scan app is), so that memory holds only their index (~56 bytes a view)
  // and stays flat however long the scan. Empty = in memory. When no file can be made there the
  // frames stay in memory and the report says why (views_spill_error); a write that fails later keeps
  // that view's frames in memory (views_spill_failures).
  std::string views_spill_dir;
  // The live TSDF the fuse stage fuses every burst into, when keep_views is on (else the scan's:
  // the live volume is then the result). It is what SaveNow saves mid-scan; Finish always fuses the
  // kept views again at scan.tsdf.voxel_mm (FinishScan), so the final model does not depend on it.
  LiveVolumeOptions live;
  // The live volume's options: live.Of(scan.tsdf) when keep_views is on, else scan.tsdf.
  TsdfOptions LiveTsdf() const;
  // Undo: each request takes back the views captured in the last undo_seconds (of the views still
  // in the model); the tracker's undo journal reaches back undo_max_views views
  // (OdometryOptions::map.undo_inserts; ~0.4 MB per view at bin 2). 0 or keep_views off = no undo
  // (the fused model could not leave the undone views out).
  double undo_seconds = 2.0;
  int undo_max_views = 150;
  // Scripted undo requests (tests, demos): one right after the N-th burst ingested, for each N.
  std::vector<uint64_t> undo_after_bursts;
  // Live: a view refused several bursts after the last one placed is tried again after a burst from
  // between them is placed (gap_bridge.h); the ring of recent bursts it takes them from.
  GapBridgeOptions bridge;
  void Check() const;                // throws std::invalid_argument
};

struct ScanItem {
  uint64_t epoch = 0;
  bool control = false;        // an undo request without a burst (ingest writes; every stage lets it through)
  uint64_t undo_requests = 0;  // undo requests up to this item (ingest writes)
  uint64_t undo_gen = 0;       // undos the register stage had done by this item (register writes)
  int64_t view_index = -1;     // the registrar's index of this view (register writes)
  IngestedBurst burst;
  bool recon_ok = false;
  ReconstructedView view;
  TrackResult track;
  bool fused = false;
  // keep_views: the frames the reconstruction used (binned), copied (reconstruct writes, fuse reads),
  // and packed for the view archive by the fuse stage, off the latency path (zstd: ~0.6 ms a burst).
  std::vector<cv::Mat> kept_frames;
  std::string packed;       // fuse writes and reads
  bool packed_ok = false;
};

// What the scan's growing parts hold, published by the stages that own them (ScanApp::Memory):
// to be read beside the process's RSS, which says how much but not what.
struct ScanMemory {
  uint64_t views = 0;                // views registered (register stage)
  uint64_t model_samples = 0;        // the tracking model's samples (register stage)
  double model_mib = 0;              // the tracking model without its undo journal (PointMap::memory_bytes)
  double undo_journal_mib = 0;       // the model's undo journal (PointMap::journal_bytes)
  uint64_t keyframes = 0;
  double keyframes_mib = 0;          // Tracker::keyframe_bytes
  double tsdf_mib = 0;               // the live volume (fuse stage; TsdfVolume::MemoryBytes)
  double views_kept_memory_mib = 0;  // the kept frames in memory (ViewArchive::memory_bytes)
  uint64_t preview_points = 0;       // the preview's decimated model (preview stage; ScanAppOptions::preview_max_points)
};

class ScanApp {
 public:
  // `source` is borrowed and must outlive Join(). Throws std::invalid_argument for bad options or
  // calibration. Live policy: the constructor also warms up every pool item (one reconstruction of a
  // blank burst each, ~85 ms per item on 2 cores, 10 items), so that the first views are not slowed
  // by allocating their maps; the time is reported as warm_up_ms.
  ScanApp(const ProbeCalibration& calibration, const ScanAppOptions& options, BurstSource* source);
  ~ScanApp();

  void Start();
  void RequestStop();  // any thread: the source ends; lossless edges drain
  void Join();
  bool finished() const { return graph_->finished(); }
  // Why the kept frames stay in memory although views_spill_dir was given (empty: they spill, or were
  // not to). Set by the constructor.
  const std::string& views_spill_error() const { return spill_error_; }

  // Control, any thread.
  void SetPaused(bool paused) { paused_.store(paused); }
  bool paused() const { return paused_.load(); }
  void Reset() { epoch_.fetch_add(1); }
  // Takes back the views of the last options().undo_seconds (any thread; applied in order with the
  // bursts, see the file comment). false when undo is off (undo_max_views 0 or keep_views off).
  bool RequestUndo();
  bool undo_available() const { return o_.scan.tracker.odometry.map.undo_inserts > 0; }
  // What the latest undo did ("undid 2.0 s: 57 views", or why nothing), and how many undos have
  // been applied or refused so far (any thread).
  std::string LastUndoMessage() const;
  uint64_t undos_done() const { return undos_done_.load(); }
  // Any thread but the stages': extracts the current model (the live volume, at
  // options().live; waits for the fuse stage's current burst) and writes DIR/scan.ply and
  // DIR/scan.stl. An undo asked for before the call is in the
  // saved model: it first waits (at most 10 s) until an item carrying that request has reached
  // the fuse stage, which has then taken those views' frames out (UNAVAILABLE if that does not
  // happen in time: a stalled graph). After an undo the live volume still holds the
  // undone views: the kept views are first fused again into a new volume at their tracked poses
  // (~20 ms per view, the fuse stage waits; without the register thread's model anchoring, which
  // Finish's refusion adds back), which then replaces the live one. INTERNAL for an empty model;
  // a kept view that cannot be read back: its error.
  [[nodiscard]] Status SaveNow(const std::string& dir);

  // Render thread only: the newest snapshot (nullptr before the first).
  const PreviewSnapshot* LatestSnapshot() { return preview_.Latest(); }
  // Any thread.
  PreviewStatus CurrentStatus() const;
  // Any thread: the figures as the stages last published them (the register stage every
  // kMemoryEvery views, the fuse stage every kMemoryEvery fused views: ~0.5 s at 30 bursts/s).
  ScanMemory Memory() const;
  static constexpr uint64_t kMemoryEvery = 15;

  // After Join(): pose graph, mesh, evaluation (FinishScan) with the host's figures added to the
  // report. `provider` may be empty: the kept views are then fused again (keep_views), if any.
  [[nodiscard]] Status Finish(const ScanTruth& truth, const ScanViewProvider& provider, ScanResult* out);
  // The host's figures (any time; percentiles only after Join()).
  nlohmann::json HostReport() const;
  // The views' calibration: the probe's, binned when options.scan.bin > 1.
  const ProbeCalibration& calibration() const { return calibration_; }
  const ScanAppOptions& options() const { return o_; }

 private:
  using Graph = StageGraph<ScanItem>;
  Graph::SourceResult Ingest(ScanItem& item, ItemMeta* meta);
  bool ReconstructStage(ScanItem& item);
  bool RegisterStage(ScanItem& item);
  // The register stage's after-hook (StageGraph::Stage::after): the tracker's model insert of the
  // view just handed to the preview (OdometryOptions::defer_model_insert), then the memory figures.
  void RegisterAfter();
  bool FuseStage(ScanItem& item);
  bool PreviewStage(ScanItem& item);

  ProbeCalibration calibration_;  // the views' (binned with o_.scan.bin)
  ScanAppOptions o_;
  BurstSource* source_;
  std::atomic<bool> paused_{false};
  std::atomic<uint64_t> epoch_{0};
  std::atomic<uint64_t> paused_bursts_{0}, failed_{0}, fused_{0}, refused_{0};
  // Undo: requests (any thread), control items sent (ingest) and through the last stage (fuse),
  // undos applied and views taken back (register), requests that took nothing back.
  std::atomic<uint64_t> undo_requests_{0}, control_items_{0}, control_done_{0}, undos_done_{0}, views_undone_{0}, undos_refused_{0};
  uint64_t BurstsCompleted() const;  // items the graph completed that carried a burst
  mutable std::mutex undo_mu_;
  std::vector<int64_t> undo_log_;  // per undo (register stage appends): its first view taken back
  std::string undo_message_;
  // The smallest first view of undos [from_gen, to_gen) (what a stage that applied from_gen must cut).
  int64_t UndoCut(uint64_t from_gen, uint64_t to_gen) const;
  std::atomic<uint64_t> latency_origin_capture_{0}, latency_origin_receive_{0};
  // ingest thread
  uint64_t undo_ingested_ = 0;  // undo requests already sent down the graph
  uint64_t bursts_ingested_ = 0;
  // ingest thread (Put) and register thread (the bridge's Take): live bridging (o_.bridge)
  std::unique_ptr<BurstRing> ring_;
  // reconstruct thread
  ScanReconstructor recon_;
  double ms_recon_ = 0;
  double ms_warm_up_ = 0;  // constructor: the pool items' warm-up (report: warm_up_ms)
  FramePacker packer_;
  // register thread
  uint64_t reg_epoch_ = 0;
  uint64_t reg_undo_requests_ = 0, reg_undo_gen_ = 0;
  std::unique_ptr<ScanRegistrar> registrar_;
  uint64_t reg_memory_views_ = 0;  // views since the register stage last published its memory figures
  bool reg_view_pending_ = false;  // register thread: RegisterStage registered a view, RegisterAfter commits it
  std::unique_ptr<GapBridge> bridge_;  // live with o_.bridge.ring_bursts > 0
  int64_t reg_last_placed_ns_ = 0;     // capture time of the last view the tracker placed (this epoch)
  std::atomic<uint64_t> bridge_views_{0}, bridge_attempts_{0}, bridge_placed_{0}, bridge_resumed_{0};  // register writes
  // fuse thread (+ SaveNow under model_mu_)
  std::mutex model_mu_;
  std::condition_variable model_cv_;  // the fuse stage moved fuse_undo_requests_ (SaveNow waits for it)
  uint64_t fuse_epoch_ = 0, fuse_undo_gen_ = 0;
  uint64_t fuse_undo_requests_ = 0;  // undo requests applied up to the fuse stage's last item
  std::unique_ptr<ScanFuser> fuser_;
  ViewArchive archive_;  // keep_views: the fused views' frames (fuse thread, then Finish)
  std::string spill_error_;        // constructor: why the archive could not spill (report)
  uint64_t spill_failures_ = 0;    // fuse thread: Adds whose spill write failed (kept in memory)
  std::string spill_failure_;      // ... the first one's error
  struct FusedView {
    int64_t view_index;
    uint64_t burst_seq;
    Rigid3d world_from_cam;  // tracked
  };
  std::vector<FusedView> fused_views_;  // keep_views: the archive's views, in order
  bool volume_has_undone_ = false;      // the live volume holds views an undo took back
  uint64_t fuse_memory_views_ = 0;      // fused views since the fuse stage last published its memory figures
  // Memory(): written by the register stage (views … keyframes_mib), the fuse stage (tsdf, views
  // kept) and the preview stage (preview points), read by any thread.
  std::atomic<uint64_t> mem_views_{0}, mem_model_samples_{0}, mem_keyframes_{0}, mem_preview_points_{0};
  std::atomic<double> mem_model_mib_{0}, mem_undo_journal_mib_{0}, mem_keyframes_mib_{0}, mem_tsdf_mib_{0}, mem_views_kept_mib_{0};
  // preview thread
  uint64_t preview_epoch_ = 0, preview_undo_gen_ = 0;
  PreviewModel preview_model_;
  PaceMonitor pace_;  // the "slow down" cue (pace_monitor.h)
  uint64_t last_burst_seq_ = 0;
  TripleBuffer<PreviewSnapshot> preview_;
  // Rolling window of latencies for the status line: preview thread; its percentiles are atomics.
  std::vector<double> recent_latency_ms_;
  size_t recent_next_ = 0;
  std::atomic<double> recent_p50_{0}, recent_p95_{0};
  std::atomic<int64_t> pace_advices_{0};  // pace_.advices(), for the report (any thread)

  std::unique_ptr<Graph> graph_;
};

}  // namespace d3d
