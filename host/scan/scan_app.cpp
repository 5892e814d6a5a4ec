#include "host/scan/scan_app.h"

#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <stdexcept>

#include "common/mesh/mesh_io.h"

namespace d3d {
namespace {

PreviewCue CueOf(TrackingState s) {
  switch (s) {
    case TrackingState::kTracking: return PreviewCue::kTracking;
    case TrackingState::kLost: return PreviewCue::kLost;
    case TrackingState::kRelocalised: return PreviewCue::kRelocalised;
    case TrackingState::kInitialising: return PreviewCue::kWaiting;
  }
  return PreviewCue::kWaiting;
}

}  // namespace

void ScanAppOptions::Check() const {
  scan.Check();
  if (lossless_capacity < 1) throw std::invalid_argument("ScanAppOptions: lossless_capacity must be >= 1");
  if (!(live_catch_up_max_s >= 0)) throw std::invalid_argument("ScanAppOptions: live_catch_up_max_s must be >= 0");
  if (!(preview_cell_mm > 0) || preview_stride_px < 1 || view_stride_px < 1)
    throw std::invalid_argument("ScanAppOptions: preview cell > 0 and strides >= 1");
  if (!(undo_seconds > 0) || undo_max_views < 0) throw std::invalid_argument("ScanAppOptions: undo_seconds > 0 and undo_max_views >= 0");
  live.Check();
  bridge.Check();
  LiveTsdf().Check();  // e.g. a live voxel above the truncation
}

TsdfOptions ScanAppOptions::LiveTsdf() const { return keep_views ? live.Of(scan.tsdf) : scan.tsdf; }

ScanApp::ScanApp(const ProbeCalibration& calibration, const ScanAppOptions& options, BurstSource* source)
    : calibration_(options.scan.bin > 1 ? BinnedCalibration(calibration, options.scan.bin) : calibration),
      o_(options),
      source_(source),
      recon_(calibration, options.scan.recon, options.scan.bin),
      preview_model_(PreviewModelOptions{options.preview_cell_mm, options.preview_max_points, options.preview_stride_px}) {
  o_.Check();
  // Undo needs the tracker's journal and the kept frames (the fused model is made again without
  // the undone views).
  o_.scan.tracker.odometry.map.undo_inserts = o_.keep_views ? o_.undo_max_views : 0;
  // The tracker's model insert runs after the register stage has handed the burst on (RegisterAfter).
  o_.scan.tracker.odometry.defer_model_insert = true;
  registrar_ = std::make_unique<ScanRegistrar>(calibration_, o_.scan.tracker, o_.scan.anchor, o_.scan.recon.normal_max_gap_mm);
  if (o_.policy == EdgePolicy::kLive && o_.bridge.ring_bursts > 0) {
    ring_ =
        std::make_unique<BurstRing>(static_cast<size_t>(o_.bridge.ring_bursts), calibration.camera.width, calibration.camera.height, 4, o_.scan.bin);
    bridge_ = std::make_unique<GapBridge>(o_.bridge, ring_.get(), calibration_, o_.scan.recon);
    bridge_->WarmUp();
  }
  fuser_ = std::make_unique<ScanFuser>(calibration_.camera, o_.LiveTsdf(), o_.scan.free_space);
  if (o_.keep_views && !o_.views_spill_dir.empty()) {
    if (const Status s = archive_.SpillTo(o_.views_spill_dir); !s.ok()) spill_error_ = s.ToString();
  }
  recent_latency_ms_.reserve(64);
  StageGraphOptions go;
  go.policy = o_.policy;
  go.lossless_capacity = o_.lossless_capacity;
  go.latency_stage = 2;  // the preview: what the dentist sees (the fuse stage after it only feeds the saved model)
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
      [this](ScanItem& it, ItemMeta* meta) { return Ingest(it, meta); },
      std::vector<Graph::Stage>{{"reconstruct", [this](ScanItem& it, const ItemMeta&) { return ReconstructStage(it); }},
                                {"register", [this](ScanItem& it, const ItemMeta&) { return RegisterStage(it); },
                                 [this] { RegisterAfter(); }},
                                {"preview", [this](ScanItem& it, const ItemMeta&) { return PreviewStage(it); }},
                                {"fuse", [this](ScanItem& it, const ItemMeta&) { return FuseStage(it); }}});
  // Live warm-up (set-up, before Start): one reconstruction of a blank burst into every pool item, so
  // that each item's reconstructed maps (~18 MB) are allocated and paged in now rather than by its
  // first burst. Without it each of the first ~8 bursts of a live scan took 3-5x its steady time to
  // reconstruct (262-361 vs ~70 ms): the first views came 6+ bursts apart, more than the tracker
  // bridges without a motion prediction (none yet at the second view), and live tracking never
  // started on the demo's path. Lossless runs drop nothing meanwhile and skip it: the pool is sized
  // for full queues, and items a run never uses stay unallocated.
  if (o_.policy == EdgePolicy::kLive) {
    const auto t_warm = std::chrono::steady_clock::now();
    graph_->ForEachItem([this](ScanItem& it) {
      for (cv::Mat& f : it.burst.frames) f.setTo(0);
      (void)recon_.Reconstruct(it.burst.frames, &it.view);  // dark burst: no points, every map allocated
    });
    ms_warm_up_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t_warm).count();
  }
}

ScanApp::~ScanApp() {
  RequestStop();
  Join();
}

void ScanApp::Start() { graph_->Start(); }
void ScanApp::RequestStop() { graph_->RequestStop(); }
void ScanApp::Join() { graph_->Join(); }

bool ScanApp::RequestUndo() {
  if (!undo_available()) return false;
  undo_requests_.fetch_add(1);
  return true;
}

std::string ScanApp::LastUndoMessage() const {
  std::lock_guard<std::mutex> lock(undo_mu_);
  return undo_message_;
}

int64_t ScanApp::UndoCut(uint64_t from_gen, uint64_t to_gen) const {
  std::lock_guard<std::mutex> lock(undo_mu_);
  int64_t cut = std::numeric_limits<int64_t>::max();
  for (uint64_t g = from_gen; g < to_gen && g < undo_log_.size(); ++g) cut = std::min(cut, undo_log_[g]);
  return cut;
}

ScanApp::Graph::SourceResult ScanApp::Ingest(ScanItem& item, ItemMeta* meta) {
  item.recon_ok = false;
  item.fused = false;
  const uint64_t undo = undo_requests_.load();
  if (undo != undo_ingested_) {
    // An undo request goes down the graph at once, without a burst (paused, or no probe).
    undo_ingested_ = undo;
    item.control = true;
    item.undo_requests = undo;
    item.epoch = epoch_.load(std::memory_order_relaxed);
    item.packed_ok = false;
    control_items_.fetch_add(1, std::memory_order_relaxed);
    return Graph::SourceResult::kItem;
  }
  const BurstSource::Result r = source_->Next(&item.burst);
  if (r == BurstSource::Result::kEnd) return Graph::SourceResult::kEnd;
  if (r == BurstSource::Result::kNothing) return Graph::SourceResult::kSkip;
  if (paused_.load(std::memory_order_relaxed)) {
    paused_bursts_.fetch_add(1, std::memory_order_relaxed);
    return Graph::SourceResult::kSkip;
  }
  if (ring_) ring_->Put(item.burst);  // kept or dropped by the graph, a burst a bridge may use
  item.control = false;
  item.undo_requests = undo_ingested_;
  item.epoch = epoch_.load(std::memory_order_relaxed);
  ++bursts_ingested_;
  for (const uint64_t n : o_.undo_after_bursts)
    if (n == bursts_ingested_) (void)RequestUndo();  // sent before the next burst
  // Latency origin: the capture time when the probe's clock agrees with ours (live), else the
  // time the host received the burst (a replayed recording carries its old capture times).
  const int64_t now = GraphNowNs();
  if (item.burst.capture_ns > 0 && item.burst.capture_ns <= now && now - item.burst.capture_ns < 2'000'000'000) {
    meta->origin_ns = item.burst.capture_ns;
    latency_origin_capture_.fetch_add(1, std::memory_order_relaxed);
  } else if (item.burst.receive_ns > 0 && item.burst.receive_ns <= now && now - item.burst.receive_ns < 2'000'000'000) {
    meta->origin_ns = item.burst.receive_ns;
    latency_origin_receive_.fetch_add(1, std::memory_order_relaxed);
  }  // else: the ingest time (set by the graph)
  return Graph::SourceResult::kItem;
}

bool ScanApp::ReconstructStage(ScanItem& item) {
  if (item.control) return true;
  item.recon_ok = recon_.Reconstruct(item.burst.frames, &item.view).ok();
  if (!item.recon_ok) {
    failed_.fetch_add(1, std::memory_order_relaxed);
    return false;
  }
  ms_recon_ += item.view.ms_total;
  if (o_.keep_views) {
    // Copied here, packed by the fuse stage (FuseStage): copyTo into a buffer of the same size and
    // type reuses it, so the item pool allocates nothing after warm-up.
    const std::vector<cv::Mat>& used = recon_.frames_used();
    item.kept_frames.resize(used.size());
    for (size_t i = 0; i < used.size(); ++i) used[i].copyTo(item.kept_frames[i]);
  }
  return true;
}

bool ScanApp::RegisterStage(ScanItem& item) {
  if (item.epoch != reg_epoch_) {
    registrar_ = std::make_unique<ScanRegistrar>(calibration_, o_.scan.tracker, o_.scan.anchor, o_.scan.recon.normal_max_gap_mm);
    reg_epoch_ = item.epoch;
    reg_last_placed_ns_ = 0;
  }
  for (; reg_undo_requests_ < item.undo_requests; ++reg_undo_requests_) {
    const ScanRegistrar::UndoResult u = registrar_->UndoLastSeconds(o_.undo_seconds);
    char text[160];
    if (u.ok)
      std::snprintf(text, sizeof text, "undid %.1f s: %lld views%s", u.seconds_undone, static_cast<long long>(u.views_undone),
                    u.clamped ? " (as far back as undo reaches)" : "");
    else
      std::snprintf(text, sizeof text, "nothing undone: %s", u.reason.c_str());
    {
      std::lock_guard<std::mutex> lock(undo_mu_);
      if (u.ok) undo_log_.push_back(u.first_view);
      undo_message_ = text;
    }
    if (u.ok) {
      ++reg_undo_gen_;
      views_undone_.fetch_add(static_cast<uint64_t>(u.views_undone));
    } else {
      undos_refused_.fetch_add(1);
    }
    undos_done_.fetch_add(1);
  }
  item.undo_gen = reg_undo_gen_;
  if (item.control) {
    item.track = TrackResult{};
    item.track.state = registrar_->tracker().state();
    item.view_index = -1;
    return true;
  }
  item.view_index = static_cast<int64_t>(registrar_->views().size());
  const TrackingState before = registrar_->tracker().state();
  item.track = registrar_->Register(item.view, item.burst.burst_seq, item.burst.capture_ns);
  if (bridge_ && bridge_->Applies(before, item.track, item.burst.capture_ns, reg_last_placed_ns_)) {
    // A gap the live policy left: a burst from between placed first, then this view again.
    int64_t placed_ns = 0;
    const bool placed = bridge_->Bridge(registrar_.get(), reg_last_placed_ns_, item.burst.capture_ns, &placed_ns);
    bridge_views_.store(bridge_->stats().views, std::memory_order_relaxed);
    bridge_attempts_.store(bridge_->stats().attempts, std::memory_order_relaxed);
    bridge_placed_.store(bridge_->stats().placed, std::memory_order_relaxed);
    if (placed) {
      reg_last_placed_ns_ = placed_ns;
      item.view_index = static_cast<int64_t>(registrar_->views().size());
      item.track = registrar_->Register(item.view, item.burst.burst_seq, item.burst.capture_ns);
      if (item.track.accepted) bridge_resumed_.fetch_add(1, std::memory_order_relaxed);
    }
  }
  if (item.track.accepted) reg_last_placed_ns_ = item.burst.capture_ns;
  if (!item.track.accepted) refused_.fetch_add(1, std::memory_order_relaxed);
  reg_view_pending_ = true;
  return true;  // refused views still go on: the preview shows them (red)
}

void ScanApp::RegisterAfter() {
  if (!reg_view_pending_) return;  // a control item
  reg_view_pending_ = false;
  registrar_->Commit();  // the view's model insert, now that the preview has the burst
  if (++reg_memory_views_ >= kMemoryEvery) {
    reg_memory_views_ = 0;
    constexpr double kMiB = 1.0 / (1024.0 * 1024.0);
    const Tracker& tracker = registrar_->tracker();
    mem_views_.store(registrar_->views().size(), std::memory_order_relaxed);
    mem_model_samples_.store(tracker.model().size(), std::memory_order_relaxed);
    mem_model_mib_.store(static_cast<double>(tracker.model().memory_bytes()) * kMiB, std::memory_order_relaxed);
    mem_undo_journal_mib_.store(static_cast<double>(tracker.model().journal_bytes()) * kMiB, std::memory_order_relaxed);
    mem_keyframes_.store(tracker.keyframes().size(), std::memory_order_relaxed);
    mem_keyframes_mib_.store(static_cast<double>(tracker.keyframe_bytes()) * kMiB, std::memory_order_relaxed);
  }
}

bool ScanApp::FuseStage(ScanItem& item) {
  std::lock_guard<std::mutex> lock(model_mu_);
  if (item.epoch != fuse_epoch_) {
    fuser_ = std::make_unique<ScanFuser>(calibration_.camera, o_.LiveTsdf(), o_.scan.free_space);
    archive_.Clear();
    fused_views_.clear();
    volume_has_undone_ = false;
    fuse_epoch_ = item.epoch;
  }
  if (item.undo_gen > fuse_undo_gen_) {
    // The undone views' frames go; the volume keeps them until it is fused again (SaveNow, Finish).
    const int64_t cut = UndoCut(fuse_undo_gen_, item.undo_gen);
    while (!fused_views_.empty() && fused_views_.back().view_index >= cut) {
      (void)archive_.Remove(fused_views_.back().burst_seq);
      fused_views_.pop_back();
      volume_has_undone_ = true;
    }
    fuse_undo_gen_ = item.undo_gen;
  }
  if (item.undo_requests > fuse_undo_requests_) {  // those undos are applied up to here (SaveNow waits for it)
    fuse_undo_requests_ = item.undo_requests;
    model_cv_.notify_all();
  }
  if (item.control) {
    control_done_.fetch_add(1);
    return true;
  }
  if (item.track.accepted) {
    // A view of a scan segment apart (not joined to the main model yet) is not fused live: it is
    // kept, and FinishScan fuses it once joined, or on its own.
    item.fused = item.track.in_main && fuser_->Fuse(item.view, item.track.world_from_cam).ok();
    if (item.fused) fused_.fetch_add(1, std::memory_order_relaxed);
    const bool keep = item.fused || !item.track.in_main;
    item.packed_ok = keep && o_.keep_views && packer_.Pack(item.kept_frames, &item.packed).ok();
    if (keep && item.packed_ok) {
      if (const Status s = archive_.Add(item.burst.burst_seq, item.packed); !s.ok() && spill_failures_++ == 0) spill_failure_ = s.ToString();
      if (item.fused) fused_views_.push_back({item.view_index, item.burst.burst_seq, item.track.world_from_cam});
    }
    if (item.fused && ++fuse_memory_views_ >= kMemoryEvery) {
      fuse_memory_views_ = 0;
      constexpr double kMiB = 1.0 / (1024.0 * 1024.0);
      mem_tsdf_mib_.store(static_cast<double>(fuser_->volume().MemoryBytes()) * kMiB, std::memory_order_relaxed);
      mem_views_kept_mib_.store(static_cast<double>(archive_.memory_bytes()) * kMiB, std::memory_order_relaxed);
    }
  }
  return true;
}

bool ScanApp::PreviewStage(ScanItem& item) {
  if (item.epoch != preview_epoch_) {
    preview_model_.Reset();
    pace_.Reset();
    preview_epoch_ = item.epoch;
  }
  if (item.undo_gen > preview_undo_gen_) {
    preview_model_.Undo(UndoCut(preview_undo_gen_, item.undo_gen));
    preview_undo_gen_ = item.undo_gen;
  }
  if (!item.control) preview_model_.AddView(item.view_index, item.track, item.view.points_in_cam, item.view.normals);
  mem_preview_points_.store(preview_model_.model_points(), std::memory_order_relaxed);
  // A view of a segment not joined yet is drawn beside the model (display_from_cam), in its colour.
  const bool apart = !item.control && item.track.accepted && !item.track.in_main;
  const Eigen::Matrix4f model_from_cam = (apart ? item.track.display_from_cam : item.track.world_from_cam).matrix().cast<float>();
  const Eigen::Matrix3f r = model_from_cam.topLeftCorner<3, 3>();
  const Eigen::Vector3f t = model_from_cam.topRightCorner<3, 1>();
  const cv::Mat& pts = item.view.points_in_cam;
  PreviewSnapshot& s = preview_.Back();
  preview_model_.CopyTo(&s);
  s.view_points.clear();
  for (int y = o_.view_stride_px / 2; !item.control && y < pts.rows; y += o_.view_stride_px) {
    const auto* p = pts.ptr<cv::Vec3f>(y);
    for (int x = o_.view_stride_px / 2; x < pts.cols; x += o_.view_stride_px)
      if (std::isfinite(p[x][2])) s.view_points.push_back(r * Eigen::Vector3f(p[x][0], p[x][1], p[x][2]) + t);
  }
  s.view_accepted = item.track.accepted;
  // A control item (undo) has no view: no probe pose until the next burst.
  s.have_pose = !item.control && (item.track.state != TrackingState::kInitialising || item.track.accepted);
  s.model_from_cam = model_from_cam;
  const PinholeBrownConrady& cam = calibration_.camera;
  s.tan_half_x = static_cast<float>(0.5 * cam.width / cam.fx);
  s.tan_half_y = static_cast<float>(0.5 * cam.height / cam.fy);
  s.near_mm = static_cast<float>(calibration_.depth_min_mm);
  s.far_mm = static_cast<float>(calibration_.depth_max_mm);
  // The host keeping too few bursts for how fast the probe moves, or so few that the track fails,
  // says so (pace_monitor.h): while tracking, and while lost, where slowing down is how the track
  // comes back.
  const bool tracked = !item.control && item.track.accepted && item.track.state == TrackingState::kTracking && !apart;
  const bool lost = !item.control && !item.track.accepted && item.track.state == TrackingState::kLost && !item.track.too_few_points;
  const bool slow_down =
      !item.control && pace_.Add(item.burst.burst_seq, item.burst.capture_ns, tracked ? &item.track.world_from_cam : nullptr, lost);
  if (!item.control) pace_advices_.store(pace_.advices(), std::memory_order_relaxed);
  PreviewCue cue = apart ? PreviewCue::kNewSegment : CueOf(item.track.state);
  if (slow_down && cue == PreviewCue::kTracking) cue = PreviewCue::kSlowDown;
  if (slow_down && cue == PreviewCue::kLost) cue = PreviewCue::kLostSlowDown;
  s.cue = cue;
  s.bursts_in_model = preview_model_.views_in_model();
  if (!item.control) last_burst_seq_ = item.burst.burst_seq;
  s.last_burst_seq = last_burst_seq_;
  s.model_area_mm2 = preview_model_.model_area_mm2();
  preview_.Publish();
  // Status line: percentiles of the latest 64 latencies (the graph's, of the bursts before this one).
  const double lat = graph_->last_latency_ms();
  if (recent_latency_ms_.size() < 64) recent_latency_ms_.push_back(lat);
  else recent_latency_ms_[recent_next_++ % 64] = lat;
  recent_p50_.store(PercentileOf(recent_latency_ms_, 50), std::memory_order_relaxed);
  recent_p95_.store(PercentileOf(recent_latency_ms_, 95), std::memory_order_relaxed);
  return true;
}

Status ScanApp::SaveNow(const std::string& dir) {
  // Undos asked for before this save: the request travels down the graph, and a save right after
  // 'u' came before the fuse stage had taken the undone views out and saved them. Every item
  // carries the request count; once one reaches the fuse stage, the register stage has applied
  // those undos and the fuse stage has cut their views.
  const uint64_t requested = undo_requests_.load();
  TriangleMesh mesh;
  {
    std::unique_lock<std::mutex> lock(model_mu_);
    if (!model_cv_.wait_for(lock, std::chrono::seconds(10), [&] { return fuse_undo_requests_ >= requested; }))
      return Unavailable("save: the last undo has not reached the model yet (graph stalled?)");
    if (volume_has_undone_) {
      // The kept views again, at their tracked poses, into a volume that then replaces the live one.
      const ScanViewProvider again = KeptViewProvider(archive_, calibration_, o_.scan.recon);
      ScanFuser rebuilt(calibration_.camera, o_.LiveTsdf(), o_.scan.free_space);
      ReconstructedView view;
      for (const FusedView& v : fused_views_) {
        ScanViewRecord record;
        record.burst_seq = v.burst_seq;
        D3D_RETURN_IF_ERROR(again(v.view_index, record, &view));
        D3D_RETURN_IF_ERROR(rebuilt.Fuse(view, v.world_from_cam));
      }
      fuser_->AdoptVolume(std::move(rebuilt));
      volume_has_undone_ = false;
    }
    mesh = fuser_->volume().ExtractMesh();
  }
  if (mesh.faces.empty()) return Status(StatusCode::kInternal, "the model is empty: nothing to save");
  mesh.ComputeVertexNormals();
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  D3D_RETURN_IF_ERROR(SavePlyBinary((std::filesystem::path(dir) / "scan.ply").string(), mesh));
  return SaveStlBinary((std::filesystem::path(dir) / "scan.stl").string(), mesh);
}

uint64_t ScanApp::BurstsCompleted() const {
  const uint64_t control = control_done_.load();  // before completed(): the graph counts an item after its last stage
  const uint64_t all = graph_->completed();
  return all > control ? all - control : 0;
}

PreviewStatus ScanApp::CurrentStatus() const {
  PreviewStatus st;
  st.bursts_received = source_->received();
  st.bursts_processed = BurstsCompleted();
  st.bursts_fused = fused_.load(std::memory_order_relaxed);
  st.bursts_dropped = graph_->dropped() + source_->dropped();
  st.bursts_rejected = refused_.load(std::memory_order_relaxed) + failed_.load(std::memory_order_relaxed);
  const int64_t span = graph_->last_done_ns() - graph_->first_done_ns();
  st.bursts_per_s = span > 0 ? static_cast<double>(st.bursts_processed - 1) / (static_cast<double>(span) * 1e-9) : 0.0;
  st.latency_ms_p50 = recent_p50_.load(std::memory_order_relaxed);
  st.latency_ms_p95 = recent_p95_.load(std::memory_order_relaxed);
  if (paused_.load()) {
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
  m.views = mem_views_.load(std::memory_order_relaxed);
  m.model_samples = mem_model_samples_.load(std::memory_order_relaxed);
  m.model_mib = mem_model_mib_.load(std::memory_order_relaxed);
  m.undo_journal_mib = mem_undo_journal_mib_.load(std::memory_order_relaxed);
  m.keyframes = mem_keyframes_.load(std::memory_order_relaxed);
  m.keyframes_mib = mem_keyframes_mib_.load(std::memory_order_relaxed);
  m.tsdf_mib = mem_tsdf_mib_.load(std::memory_order_relaxed);
  m.views_kept_memory_mib = mem_views_kept_mib_.load(std::memory_order_relaxed);
  m.preview_points = mem_preview_points_.load(std::memory_order_relaxed);
  return m;
}

nlohmann::json ScanApp::HostReport() const {
  nlohmann::json j;
  const uint64_t processed = BurstsCompleted();
  j["policy"] = EdgePolicyName(o_.policy);
  j["bursts_received"] = source_->received();
  j["bursts_malformed"] = source_->malformed();
  j["bursts_missing_upstream"] = source_->missing();
  j["bursts_ingested"] = graph_->ingested();
  j["bursts_processed"] = processed;
  j["bursts_fused"] = fused_.load();
  j["bursts_refused"] = refused_.load();
  // Live bridging (gap_bridge.h): refused views bridged, bursts tried and placed between, views then placed.
  j["bridges"] = {
      {"views", bridge_views_.load()}, {"attempts", bridge_attempts_.load()}, {"placed", bridge_placed_.load()}, {"resumed", bridge_resumed_.load()}};
  j["bursts_failed"] = failed_.load();
  j["bursts_paused"] = paused_bursts_.load();
  j["undo_requests"] = undo_requests_.load();
  j["undos_applied"] = undos_done_.load() - undos_refused_.load();
  j["undos_refused"] = undos_refused_.load();
  j["views_undone_live"] = views_undone_.load();
  j["slow_down_cues"] = pace_advices_.load();  // times the preview told the dentist to slow down
  // Every burst that reached the host and was neither processed nor malformed, failed or paused was
  // dropped for lack of time (where: "drops"; the receiver's figure counts samples of every topic).
  const uint64_t accounted = processed + source_->malformed() + failed_.load() + paused_bursts_.load();
  j["bursts_dropped"] = source_->received() > accounted ? source_->received() - accounted : 0;
  nlohmann::json drops;
  drops["receiver_queue"] = source_->dropped();
  for (size_t i = 0; i < graph_->num_stages(); ++i) drops["before_" + graph_->stage_name(i)] = graph_->dropped_at(i);
  j["drops"] = drops;
  const double span_s = static_cast<double>(graph_->last_done_ns() - graph_->start_ns()) * 1e-9;
  const double active_s = static_cast<double>(graph_->last_done_ns() - graph_->first_done_ns()) * 1e-9;
  j["bursts_per_s"] = active_s > 0 ? static_cast<double>(processed - 1) / active_s : 0.0;
  j["fused_per_s"] = active_s > 0 ? static_cast<double>(fused_.load()) / active_s : 0.0;
  j["wall_s"] = span_s;
  j["latency_ms_p50"] = graph_->LatencyPercentileMs(50);
  j["latency_ms_p95"] = graph_->LatencyPercentileMs(95);
  j["latency_ms_max"] = graph_->LatencyPercentileMs(100);
  // ... and to the end of the fuse stage (the saved model; the preview does not wait for it).
  j["latency_fused_ms_p50"] = graph_->DoneLatencyPercentileMs(50);
  j["latency_fused_ms_p95"] = graph_->DoneLatencyPercentileMs(95);
  j["latency_origin"] = latency_origin_capture_.load() > 0 ? (latency_origin_receive_.load() > 0 ? "capture+receive" : "capture")
                                                           : (latency_origin_receive_.load() > 0 ? "receive" : "ingest");
  nlohmann::json stages;
  for (size_t i = 0; i < graph_->num_stages(); ++i) {
    const StageCounters& c = graph_->stage(i);
    const uint64_t n = c.processed.load();
    const auto ms_mean = [n](uint64_t ns) { return n > 0 ? static_cast<double>(ns) * 1e-6 / static_cast<double>(n) : 0.0; };
    stages[graph_->stage_name(i)] = {{"items", n},
                                     {"ms_mean", ms_mean(c.busy_ns.load())},
                                     {"ms_max", static_cast<double>(c.max_ns.load()) * 1e-6},
                                     {"cpu_ms_mean", ms_mean(c.cpu_ns.load())},
                                     {"held_ms_mean", ms_mean(c.held_ns.load())},
                                     {"order_violations", c.order_violations.load()}};
  }
  j["stages"] = stages;
  j["probe_returns"] = source_->probe_returns();
  j["live_voxel_mm"] = o_.LiveTsdf().voxel_mm;  // the live volume's (SaveNow); the final model's is voxel_mm
  j["warm_up_ms"] = ms_warm_up_;
  j["bursts_caught_up"] = graph_->catch_up_items();  // live: processed in order at the start (ScanAppOptions::live_catch_up_max_s)
  j["catch_up_thinned"] = graph_->catch_up_thinned();  // ... the graph fell behind and kept 1 burst of 3 meanwhile
  j["warm_up_items"] = o_.policy == EdgePolicy::kLive ? graph_->pool_size() : 0;
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  j["peak_rss_mb"] = static_cast<double>(u.ru_maxrss) / 1024.0;
  return j;
}

Status ScanApp::Finish(const ScanTruth& truth, const ScanViewProvider& provider, ScanResult* out) {
  ScanTimes times;
  times.bursts = static_cast<int64_t>(registrar_->views().size());
  times.ms_recon = ms_recon_;
  times.ms_register = registrar_->ms_register();
  times.ms_fuse = fuser_->ms_fuse();
  // Without a provider, the kept views: their frames again through a reconstructor of the binned
  // calibration (the frames are binned already), so each view comes back as it was fused.
  ScanViewProvider kept;
  if (!provider && o_.keep_views && (archive_.size() > 0 || registrar_->views_undone() > 0))
    kept = KeptViewProvider(archive_, calibration_, o_.scan.recon);
  Status s;
  {
    // A refusion replaces the fuser's volume: SaveNow (saver thread) waits meanwhile.
    std::lock_guard<std::mutex> lock(model_mu_);
    s = FinishScan(o_.scan, times, registrar_.get(), fuser_.get(), provider ? provider : kept, truth, out);
  }
  nlohmann::json host = HostReport();
  host["views_kept"] = archive_.size();
  host["views_kept_mib"] = static_cast<double>(archive_.bytes()) / (1024.0 * 1024.0);
  host["views_kept_memory_mib"] = static_cast<double>(archive_.memory_bytes()) / (1024.0 * 1024.0);
  host["views_spilled"] = archive_.spilling();
  if (!spill_error_.empty()) host["views_spill_error"] = spill_error_;
  host["views_spill_failures"] = spill_failures_;
  if (spill_failures_ > 0) host["views_spill_failure"] = spill_failure_;
  if (!s.ok()) {  // still say what happened
    out->report = host;
    out->report["bursts"] = registrar_->views().size();
    out->report["fused"] = fuser_->fused();
    out->report["rejected"] = registrar_->rejected();
    out->report["tracking_lost"] = registrar_->lost_events();
    out->report["events"] = registrar_->events();
    out->report["error"] = s.ToString();
    return s;
  }
  for (auto it = host.begin(); it != host.end(); ++it) out->report[it.key()] = it.value();
  return Status::Ok();
}

}  // namespace d3d
