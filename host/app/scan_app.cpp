#include "host/app/scan_app.h"

#include <chrono>
#include <stdexcept>

#include "common/core/process_stats.h"

namespace d3d {

void ScanAppOptions::Check() const {
  scan.Check();
  if (lossless_capacity < 1)
    throw std::invalid_argument("ScanAppOptions: lossless_capacity must be >= 1");
  if (!(live_catch_up_max_s >= 0))
    throw std::invalid_argument("ScanAppOptions: live_catch_up_max_s must be >= 0");
  if (!(preview_cell_mm > 0) || preview_stride_px < 1 || view_stride_px < 1)
    throw std::invalid_argument("ScanAppOptions: preview cell > 0 and strides >= 1");
  if (!(undo_seconds > 0) || undo_max_views < 0)
    throw std::invalid_argument("ScanAppOptions: undo_seconds > 0 and undo_max_views >= 0");
  live.Check();
  bridge.Check();
  LiveTsdf().Check();  // e.g. a live voxel above the truncation
}

TsdfOptions ScanAppOptions::LiveTsdf() const { return keep_views ? live.Of(scan.tsdf) : scan.tsdf; }

namespace {

// The options as the app runs them: undo needs the tracker's journal and the kept frames (the
// fused model is made again without the undone views); the tracker's model insert runs after the
// register stage has handed the burst on (RegisterStage::After). Checked first.
ScanAppOptions AppOptions(const ScanAppOptions& options) {
  options.Check();
  ScanAppOptions o = options;
  o.scan.tracker.odometry.map.undo_inserts = o.keep_views ? o.undo_max_views : 0;
  o.scan.tracker.odometry.defer_model_insert = true;
  return o;
}

// The bridge ring of a lossless replay of chosen views: this many times the live one (384 bursts at
// the default 96: 115 MB at 640 × 480, bin 2).
constexpr int kLosslessRingFactor = 4;

}  // namespace

ScanApp::ScanApp(const ProbeCalibration& calibration, const ScanAppOptions& options,
                 BurstSource* source)
    : calibration_(options.scan.bin > 1 ? BinnedCalibration(calibration, options.scan.bin)
                                        : calibration),
      o_(AppOptions(options)),
      source_(source),
      undo_(o_.scan.tracker.odometry.map.undo_inserts > 0) {
  reconstruct_ =
      std::make_unique<ReconstructStage>(calibration, o_.scan.recon, o_.scan.bin, o_.keep_views);
  std::unique_ptr<GapBridge> bridge;
  if ((o_.policy == EdgePolicy::kLive || o_.bridge_lossless) && o_.bridge.ring_bursts > 0) {
    // A lossless replay's source is not held to real time: it reads ahead of the register stage by
    // the items its edges hold (~7), each up to a sparse selection's gap of tens of bursts, and
    // the bursts of the gap a bridge needs must still be in the ring then.
    const int ring =
        o_.bridge.ring_bursts * (o_.policy == EdgePolicy::kLive ? 1 : kLosslessRingFactor);
    ring_ = std::make_unique<BurstRing>(static_cast<size_t>(ring), calibration.camera.width,
                                        calibration.camera.height, 4, o_.scan.bin);
    bridge = std::make_unique<GapBridge>(o_.bridge, ring_.get(), calibration_, o_.scan.recon);
    bridge->WarmUp();
  }
  register_ = std::make_unique<RegisterStage>(calibration_, o_.scan, o_.undo_seconds, &undo_,
                                              std::move(bridge));
  FuseStageOptions fo;
  fo.live_tsdf = o_.LiveTsdf();
  fo.free_space = o_.scan.free_space;
  fo.recon = o_.scan.recon;
  fo.keep_views = o_.keep_views;
  fo.views_spill_dir = o_.views_spill_dir;
  fuse_ = std::make_unique<FuseStage>(calibration_, fo, &undo_);
  preview_ = std::make_unique<PreviewStage>(
      calibration_,
      PreviewModelOptions{o_.preview_cell_mm, o_.preview_max_points, o_.preview_stride_px},
      o_.view_stride_px, &undo_);
  ingest_ = std::make_unique<IngestStage>(source_, &undo_, ring_.get(), o_.undo_after_bursts);
  StageGraphOptions go;
  go.policy = o_.policy;
  go.lossless_capacity = o_.lossless_capacity;
  go.latency_stage =
      2;  // the preview: what the dentist sees (the fuse stage after it only feeds the saved model)
  go.live_just_in_time = o_.live_just_in_time;
  go.live_catch_up_max_s = o_.live_catch_up_max_s;
  const int w = calibration.camera.width, h = calibration.camera.height;  // the probe's frames
  graph_ = std::make_unique<Graph>(
      go,
      [w, h] {
        auto it = std::make_unique<ScanItem>();
        it->burst.frames.resize(4);  // the usual burst, allocated once (each frame its own buffer)
        for (cv::Mat& f : it->burst.frames) f.create(h, w, CV_8U);
        return it;
      },
      [this](ScanItem& it, ItemMeta* meta) { return ingest_->Run(it, meta); },
      std::vector<Graph::Stage>{
          {"reconstruct", [this](ScanItem& it, const ItemMeta&) { return reconstruct_->Run(it); }},
          {"register", [this](ScanItem& it, const ItemMeta&) { return register_->Run(it); },
           [this] { register_->After(); }},
          {"preview",
           [this](ScanItem& it, const ItemMeta&) {
             const bool ok = preview_->Run(it);
             preview_->AddLatency(graph_->last_latency_ms());
             return ok;
           }},
          {"fuse", [this](ScanItem& it, const ItemMeta&) { return fuse_->Run(it); }}});
  // Live warm-up (set-up, before Start): one reconstruction of a blank burst into every pool item,
  // so that each item's reconstructed maps (~18 MB) are allocated and paged in now rather than by
  // its first burst, which then took 3-5x its steady time and put the first views further apart
  // than the tracker bridges without a motion prediction. Lossless runs drop nothing meanwhile and
  // skip it: the pool is sized for full queues, and items a run never uses stay unallocated.
  if (o_.policy == EdgePolicy::kLive) {
    const auto t_warm = std::chrono::steady_clock::now();
    graph_->ForEachItem([this](ScanItem& it) { reconstruct_->WarmUp(it); });
    ms_warm_up_ =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t_warm)
            .count();
  }
}

ScanApp::~ScanApp() {
  RequestStop();
  Join();
}

void ScanApp::Start() { graph_->Start(); }
void ScanApp::RequestStop() { graph_->RequestStop(); }
void ScanApp::Join() { graph_->Join(); }

uint64_t ScanApp::BurstsCompleted() const {
  const uint64_t control =
      fuse_->control_done();  // before completed(): the graph counts an item after its last stage
  const uint64_t all = graph_->completed();
  return all > control ? all - control : 0;
}

PreviewStatus ScanApp::CurrentStatus() const {
  PreviewStatus st;
  st.bursts_received = source_->received();
  st.bursts_processed = BurstsCompleted();
  st.bursts_fused = fuse_->fused();
  st.bursts_dropped = graph_->dropped() + source_->dropped();
  st.bursts_rejected = register_->refused() + reconstruct_->failed();
  const int64_t span = graph_->last_done_ns() - graph_->first_done_ns();
  st.bursts_per_s =
      span > 0 ? static_cast<double>(st.bursts_processed - 1) / (static_cast<double>(span) * 1e-9)
               : 0.0;
  st.latency_ms_p50 = preview_->latency_ms_p50();
  st.latency_ms_p95 = preview_->latency_ms_p95();
  if (ingest_->paused()) {
    st.override_cue = true;
    st.cue_override = PreviewCue::kPaused;
  } else if (source_->probe_lost()) {
    st.override_cue = true;
    st.cue_override = PreviewCue::kProbeLost;
  } else if (source_->received() == 0) {
    st.override_cue = true;
    st.cue_override = PreviewCue::kWaiting;
  }
  return st;
}

ScanMemory ScanApp::Memory() const {
  ScanMemory m;
  register_->Memory(&m);
  fuse_->Memory(&m);
  preview_->Memory(&m);
  return m;
}

nlohmann::json ScanApp::HostReport() const {
  nlohmann::json j;
  const uint64_t processed = BurstsCompleted();
  const uint64_t fused = fuse_->fused(), failed = reconstruct_->failed(),
                 paused = ingest_->paused_bursts();
  j["policy"] = EdgePolicyName(o_.policy);
  j["bursts_received"] = source_->received();
  j["bursts_malformed"] = source_->malformed();
  j["bursts_missing_upstream"] = source_->missing();
  j["bursts_ingested"] = graph_->ingested();
  j["bursts_processed"] = processed;
  j["bursts_fused"] = fused;
  j["bursts_refused"] = register_->refused();
  j["bridges"] = register_->BridgeReport();
  j["bursts_failed"] = failed;
  j["bursts_paused"] = paused;
  j["undo_requests"] = undo_.requests();
  j["undos_applied"] = undo_.done() - undo_.refused();
  j["undos_refused"] = undo_.refused();
  j["views_undone_live"] = undo_.views_undone();
  j["slow_down_cues"] = preview_->slow_down_cues();
  // Every burst that reached the host and was neither processed nor malformed, failed or paused was
  // dropped for lack of time (where: "drops"; the receiver's figure counts samples of every topic).
  const uint64_t accounted = processed + source_->malformed() + failed + paused;
  j["bursts_dropped"] = source_->received() > accounted ? source_->received() - accounted : 0;
  nlohmann::json drops;
  drops["receiver_queue"] = source_->dropped();
  for (size_t i = 0; i < graph_->num_stages(); ++i)
    drops["before_" + graph_->stage_name(i)] = graph_->dropped_at(i);
  j["drops"] = drops;
  const double span_s = static_cast<double>(graph_->last_done_ns() - graph_->start_ns()) * 1e-9;
  const double active_s =
      static_cast<double>(graph_->last_done_ns() - graph_->first_done_ns()) * 1e-9;
  j["bursts_per_s"] = active_s > 0 ? static_cast<double>(processed - 1) / active_s : 0.0;
  j["fused_per_s"] = active_s > 0 ? static_cast<double>(fused) / active_s : 0.0;
  j["wall_s"] = span_s;
  j["latency_ms_p50"] = graph_->LatencyPercentileMs(50);
  j["latency_ms_p95"] = graph_->LatencyPercentileMs(95);
  j["latency_ms_max"] = graph_->LatencyPercentileMs(100);
  // ... and to the end of the fuse stage (the saved model; the preview does not wait for it).
  j["latency_fused_ms_p50"] = graph_->DoneLatencyPercentileMs(50);
  j["latency_fused_ms_p95"] = graph_->DoneLatencyPercentileMs(95);
  j["latency_origin"] = ingest_->LatencyOrigin();
  nlohmann::json stages;
  for (size_t i = 0; i < graph_->num_stages(); ++i) {
    const StageCounters& c = graph_->stage(i);
    const uint64_t n = c.processed.load();
    const auto ms_mean = [n](uint64_t ns) {
      return n > 0 ? static_cast<double>(ns) * 1e-6 / static_cast<double>(n) : 0.0;
    };
    stages[graph_->stage_name(i)] = {{"items", n},
                                     {"ms_mean", ms_mean(c.busy_ns.load())},
                                     {"ms_max", static_cast<double>(c.max_ns.load()) * 1e-6},
                                     {"cpu_ms_mean", ms_mean(c.cpu_ns.load())},
                                     {"held_ms_mean", ms_mean(c.held_ns.load())},
                                     {"order_violations", c.order_violations.load()}};
  }
  j["stages"] = stages;
  j["probe_returns"] = source_->probe_returns();
  j["live_voxel_mm"] =
      o_.LiveTsdf().voxel_mm;  // the live volume's (SaveNow); the final model's is voxel_mm
  j["warm_up_ms"] = ms_warm_up_;
  j["bursts_caught_up"] =
      graph_->catch_up_items();  // live: processed in order at the start (live_catch_up_max_s)
  j["catch_up_thinned"] =
      graph_->catch_up_thinned();  // ... the graph fell behind and kept 1 burst of 3 meanwhile
  j["warm_up_items"] = o_.policy == EdgePolicy::kLive ? graph_->pool_size() : 0;
  j["peak_rss_mib"] = PeakRssMiB();
  return j;
}

Status ScanApp::Finish(const ScanTruth& truth, const ScanViewProvider& provider, ScanResult* out) {
  ScanRegistrar* registrar = register_->registrar();
  ScanTimes times;
  times.bursts = static_cast<int64_t>(registrar->views().size());
  times.ms_recon = reconstruct_->ms_recon();
  times.ms_register = registrar->ms_register();
  const Status s = fuse_->Finish(o_.scan, times, registrar, provider, truth, out);
  nlohmann::json host = HostReport();
  fuse_->Report(&host);
  if (!s.ok()) {  // still say what happened
    out->report = host;
    out->report["bursts"] = registrar->views().size();
    out->report["fused"] = fuse_->fuser().fused();
    out->report["rejected"] = registrar->rejected();
    out->report["tracking_lost"] = registrar->lost_events();
    out->report["events"] = registrar->events();
    out->report["error"] = s.ToString();
    return s;
  }
  for (auto it = host.begin(); it != host.end(); ++it) out->report[it.key()] = it.value();
  return Status::Ok();
}

}  // namespace d3d
