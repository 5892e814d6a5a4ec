#include "tools/scan/scan_input.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "common/mesh/mesh_io.h"
#include "sim/trajectory/trajectory.h"

namespace fs = std::filesystem;

namespace d3d {

void DeclareScanToolArgs(OptionRegistry* r, ScanToolArgs* a, ScanAppOptions* app) {
  r->Add("--replay", &a->replay,
         "replay a recording (d3d-record) through the same graph instead of listening on DDS");
  r->Add("--replay-rate", &a->replay_rate,
         "--replay: 0 = as fast as the graph takes bursts, else the recorded timing x this");
  r->Add("--frames", &a->max_bursts, "--replay: use the first N bursts only (0 = all)");
  r->Add(
      "--replay-views", &a->replay_views,
      "--replay: only the bursts whose capture times this TUM file lists (e.g. a live run's "
      "poses.txt: its views again, "
      "losslessly, with the live tracker's gates: --step 6 by default and motion by capture time; "
      "the bursts left out are the gap bridge's, as a live graph's dropped ones are)");
  r->Add("--rx-queue", &a->rx_queue,
         "live: bursts the DDS receiver may hold for the graph (default: 64 live, 8 with "
         "--catch-up 0, 300 lossless)");
  r->Add("--catch-up", &app->live_catch_up_max_s,
         "live: process the bursts that arrived while the host set up, in order, until the graph "
         "has caught up, for at most "
         "this many seconds, then thinned out (1 of 3 to 1 of 6) until caught up (0 = start on the "
         "newest burst and drop them)")
      .Range(0.0, 10.0);
  r->Add("--bridge", &app->bridge.ring_bursts,
         "live: recent bursts kept so that a view refused several bursts after the last placed one "
         "is tried again after "
         "one from between (host/app/gap_bridge.h; 0 = off)")
      .Range(0, 300);
  r->Flag("--just-in-time,!--no-just-in-time", &app->live_just_in_time,
          "live: start reconstructing a burst just in time for the register stage, on a newer "
          "burst, instead of as soon as "
          "the register stage took the last one");
  r->Add("--policy", &a->policy_text,
         "edge policy: live (latest wins, drops counted) | lossless (default: live on DDS, "
         "lossless with --replay)");
  r->Add("--step", &a->step,
         "expected bursts between processed views for the tracker's gates (default: 1 lossless, 6 "
         "live)");
  // Live takes 1 thread: the stage threads alone keep a slow machine's cores busy, and oneTBB's
  // workers only contend with them (docs/decisions/0013); lossless runs keep 2.
  r->Add("--threads", &a->threads,
         "OpenCV / oneTBB threads (the reconstruction's row blocks, the ICP, the fusion's loops); "
         "0 = 1 live (the stage "
         "threads alone own the cores), 2 lossless");
  r->Add("--icp-threads", &a->icp_threads,
         "threads of the tracker's ICP (association and normal equations; at most --threads; 0 = "
         "--threads)");
  r->Add("--spill-views", &a->spill_views,
         "--refuse: keep the fused bursts' frames in an unnamed temporary file in this folder (it "
         "leaves nothing behind) "
         "so that memory stays flat however long the scan; 'memory' keeps them in memory (default: "
         "the --out folder)");
  r->Add("--reference", &a->reference, "evaluate against this scene: typodont or a mesh file (mm)");
  r->Add("--sim-trajectory", &a->sim_trajectory,
         "the virtual probe's scan path (a style: full-arch, lifts, quadrants, ...; quadrant or "
         "FILE.tum): true poses for "
         "the best fit and the ATE");
  r->Add("--sim-seed", &a->sim_seed, "--sim-trajectory: its seed");
  r->Add("--sim-rate", &a->sim_rate,
         "the probe's burst rate (Hz): the true poses' timing with --sim-trajectory; live, the "
         "tracker's view period is "
         "--step / rate");
  r->Add("--domain", &a->domain, "DDS domain id");
  r->Add("--serial", &a->serial, "listen to this probe only (default: any)");
  r->Add("--probe-timeout", &a->probe_timeout_s, "seconds without a burst before 'probe lost'");
  r->Add("--idle-exit", &a->idle_exit_s,
         "live: finish after this many seconds without a burst (0 = wait for the probe to return)");
  r->Add("--wait-probe", &a->wait_probe_s, "live: seconds to wait for the probe's ProbeInfo");
  r->Add("--out", &a->session.out_dir, "output folder");
  r->Flag("--headless", &a->headless, "render the preview offscreen (EGL, no display needed)");
  r->Flag("--no-preview", &a->no_preview, "no preview at all");
  r->Add("--screenshot", &a->screenshot,
         "save the final preview picture here too (PNG; DIR/preview.png is always written)");
  r->Add("--duration", &a->session.duration_s,
         "stop after this many seconds (0 = until the end of the replay / the window closes / "
         "SIGINT)")
      .NonNegative();
  r->Add("--preview-fps", &a->session.preview_fps, "preview frame-rate cap");
  r->Add("--size", &a->width, "preview width (px; height = 3/4)");
  r->Flag("--json", &a->json, "print report.json as one line on stdout");
  r->Flag("--quiet", &a->session.quiet,
          "no status line on stderr (SIGUSR1 saves the model now, as the 's' key; SIGUSR2 undoes, "
          "as 'u')");
  r->Add("--undo-seconds", &app->undo_seconds,
         "the 'u' key takes back the views of this many seconds of scanning");
  r->Add("--undo-views", &app->undo_max_views,
         "how many views back undo can reach (0 = no undo; ~0.4 MB each)");
  r->Add("--undo-after", &app->undo_after_bursts,
         "scripted undo: press 'u' right after the N-th burst (repeatable; tests and demos)");
}

int ResolveScanToolArgs(ScanToolArgs* a) {
  a->policy = a->replay.empty() ? EdgePolicy::kLive : EdgePolicy::kLossless;
  if (a->policy_text == "live") {
    a->policy = EdgePolicy::kLive;
  } else if (a->policy_text == "lossless") {
    a->policy = EdgePolicy::kLossless;
  } else if (!a->policy_text.empty()) {
    std::fprintf(stderr, "d3d-scan: --policy must be live or lossless\n");
    return 2;
  }
  if (!a->replay_views.empty() && a->replay.empty()) {
    std::fprintf(stderr,
                 "d3d-scan: --replay-views needs --replay (the recording the live run scanned)\n");
    return 2;
  }
  // A live run's views (--replay-views) come as unevenly as they did live: the live tracker's
  // gates.
  a->live_views = a->policy == EdgePolicy::kLive || !a->replay_views.empty();
  if (a->step <= 0) a->step = a->live_views ? 6 : 1;
  if (a->threads <= 0) a->threads = a->policy == EdgePolicy::kLive ? 1 : 2;
  if (a->icp_threads <= 0) a->icp_threads = a->threads;
  return 0;
}

Status MakeScanAppOptions(const ScanToolArgs& a, const ScanFlags& flags, ScanAppOptions* app) {
  app->policy = a.policy;
  app->bridge_lossless = !a.replay_views.empty();
  D3D_RETURN_IF_ERROR(ApplyScanFlags(flags, a.step, &app->scan));
  // The tracker's ICP (association and normal equations) on the register thread and oneTBB
  // workers, at most --threads; its sums in a fixed order, so a lossless run repeats bit for bit.
  app->scan.tracker.odometry.icp.threads = std::clamp(a.icp_threads, 1, a.threads);
  app->scan.recon.threads = a.threads;  // the reconstruction's per-pixel passes on blocks of rows
  // Live, the gaps between processed views vary with the load: motion prediction and limits by
  // capture time, in views of `step` bursts.
  if (a.live_views && a.sim_rate > 0)
    app->scan.tracker.motion.view_period_ns = std::llround(a.step * 1e9 / a.sim_rate);
  app->keep_views = flags.refuse;
  if (flags.refuse && a.spill_views != "memory") {
    app->views_spill_dir = a.spill_views.empty() ? a.session.out_dir : a.spill_views;
    std::error_code ec;
    fs::create_directories(app->views_spill_dir, ec);  // the --out folder is made early for it
  }
  app->live.voxel_mm = flags.live_voxel_mm;
  app->view_stride_px = std::max(2, app->view_stride_px / flags.bin);
  return Status::Ok();
}

std::unique_ptr<Viewer> OpenViewer(const ScanToolArgs& a) {
  std::unique_ptr<Viewer> viewer;
  if (a.no_preview) return viewer;
  ViewerOptions vo;
  vo.headless = a.headless;
  vo.width = a.width;
  vo.height = a.width * 3 / 4;
  Status s = Viewer::Create(vo, &viewer);
  if (!s.ok() && !a.headless) {
    std::fprintf(stderr, "d3d-scan: %s; rendering offscreen instead\n", s.ToString().c_str());
    vo.headless = true;
    s = Viewer::Create(vo, &viewer);
  }
  if (!s.ok()) std::fprintf(stderr, "d3d-scan: no preview: %s\n", s.ToString().c_str());
  return viewer;
}

namespace {

int OpenRecording(const ScanToolArgs& a, ScanInput* in) {
  RecordingSourceOptions ro;
  ro.rate = a.replay_rate;
  ro.max_bursts = a.max_bursts;
  if (!a.replay_views.empty()) {
    Trajectory views;
    if (const Status s = Trajectory::LoadTum(a.replay_views, &views); !s.ok()) {
      std::fprintf(stderr, "d3d-scan: --replay-views: %s\n", s.ToString().c_str());
      return 2;
    }
    for (const TimedPose& k : views.keys()) ro.select_capture_ns.push_back(k.t_ns);
  }
  if (const Status s = RecordingBurstSource::Open(a.replay, ro, &in->recording); !s.ok()) {
    std::fprintf(stderr, "d3d-scan: %s: %s\n", a.replay.c_str(), s.ToString().c_str());
    return 2;
  }
  in->calibration = in->recording->calibration();
  in->probe_serial = in->recording->header().probe_serial;
  in->source = in->recording.get();
  return 0;
}

int OpenDds(const ScanToolArgs& a, const ScanAppOptions& app, Viewer* viewer,
            std::atomic<bool>* stop, ScanInput* in) {
  if (const Status s = tools::CreateToolParticipant(a.domain, &in->participant, "d3d-scan");
      !s.ok()) {
    std::fprintf(stderr, "d3d-scan: DDS: %s\n", s.ToString().c_str());
    return 3;
  }
  const double catch_up_s = app.live_catch_up_max_s;
  const bool live = a.policy == EdgePolicy::kLive;
  ReceiverOptions ro;
  ro.serial = a.serial;
  // Live: room for the backlog the catch-up start works off: the bursts that arrive while the
  // host sets up (~0.4 s) and while it falls behind before it thins out (docs/decisions/0014).
  ro.queue_capacity = a.rx_queue > 0 ? a.rx_queue : (live ? (catch_up_s > 0 ? 64 : 8) : 300);
  ro.log = [](const std::string& m) { std::fprintf(stderr, "d3d-scan: %s\n", m.c_str()); };
  in->receiver = std::make_unique<BurstReceiver>(ro);
  if (const Status s = in->receiver->Start(&in->participant); !s.ok()) {
    std::fprintf(stderr, "d3d-scan: %s\n", s.ToString().c_str());
    return 3;
  }
  DdsSourceOptions dso;
  dso.probe_timeout_s = a.probe_timeout_s;
  dso.idle_exit_s = a.idle_exit_s;
  // Live: no burst older than this is ingested (without the catch-up start: start on fresh bursts,
  // not on those queued during set-up). With it, the backlog may reach ~2 s before the thinning
  // gains on it; dropped here, its oldest bursts would leave a gap the tracker cannot bridge.
  if (live) dso.max_age_s = catch_up_s > 0 ? 1.25 + catch_up_s : 0.25;
  in->dds = std::make_unique<DdsBurstSource>(in->receiver.get(), dso);
  std::fprintf(stderr, "d3d-scan: waiting for a probe on DDS domain %d...\n", a.domain);
  proto::InfoMsg info;
  const auto waiting_frame = [&] {  // the preview stays responsive while it waits (close = quit)
    if (!viewer) return;
    PreviewStatus st;
    st.override_cue = true;
    st.cue_override = PreviewCue::kWaiting;
    st.message = "waiting for a probe on DDS domain " + std::to_string(a.domain);
    if (!viewer->Render(nullptr, st, 0)) stop->store(true);  // window closed
  };
  if (const Status s =
          in->dds->WaitForCalibration(a.wait_probe_s, stop, &in->calibration, &info, waiting_frame);
      !s.ok()) {
    std::fprintf(stderr, "d3d-scan: %s\n", s.ToString().c_str());
    return 3;
  }
  in->probe_serial = info.serial;
  std::fprintf(stderr, "d3d-scan: probe %s (%s, %ux%u)\n", info.serial.c_str(),
               info.sensor_model.c_str(), info.width, info.height);
  in->source = in->dds.get();
  return 0;
}

}  // namespace

int OpenScanInput(const ScanToolArgs& a, const ScanAppOptions& app, Viewer* viewer,
                  std::atomic<bool>* stop, ScanInput* in) {
  return a.replay.empty() ? OpenDds(a, app, viewer, stop, in) : OpenRecording(a, in);
}

void ReportInput(const ScanToolArgs& a, const ScanFlags& flags, const ScanInput& in,
                 nlohmann::json* report) {
  nlohmann::json& r = *report;
  r["input"] = a.replay.empty() ? "dds" : a.replay;
  r["step"] = a.step;
  r["threads"] = a.threads;
  r["bin"] = flags.bin;
  if (!in.recording) return;
  const RecordingBurstSource& rec = *in.recording;
  r["recording_problems"] = rec.diagnostics().problems;
  // What a damaged recording lost (from the index, the chunk headers and the bursts' numbers):
  // bursts_missing_upstream counts only the jumps within intact data.
  const SequenceLossCounter& lost = rec.bursts_lost();
  r["recording_damaged"] = rec.diagnostics().damaged();
  r["recording_lost"] = rec.diagnostics().LossSummary();
  r["bursts_lost_in_recording"] = lost.lost_min();
  r["bursts_lost_in_recording_max"] =
      lost.lost_max() ? nlohmann::json(*lost.lost_max()) : nlohmann::json(nullptr);
  if (!a.replay_views.empty()) {
    r["replay_views"] = a.replay_views;
    r["bursts_skipped"] = rec.skipped();
  }
}

Status LoadEvaluationTruth(const ScanToolArgs& a, const ProbeCalibration& calib,
                           EvaluationTruth* out) {
  if (a.reference.empty()) return Status::Ok();
  SimSceneOptions so;
  so.model = a.reference;
  so.trajectory = a.sim_trajectory.empty() ? "full-arch" : a.sim_trajectory;
  so.seed = a.sim_seed;
  so.burst_rate_hz = a.sim_rate;
  if (a.reference == "typodont" || !a.sim_trajectory.empty()) {
    D3D_RETURN_IF_ERROR(SimScene::Create(so, &out->world));
    out->scene = out->world.scene();
  } else {
    D3D_RETURN_IF_ERROR(LoadMesh(a.reference, &out->scene));
  }
  if (!out->scene.face_colors.empty() && out->scene.face_labels.empty())
    LabelFacesFromColors(&out->scene);
  out->truth.reference = &out->scene;
  if (!a.sim_trajectory.empty()) {
    // The true pose of burst i: the trajectory at the middle of its frames.
    const SimScene* world = &out->world;
    const int frames = calib.pattern.steps;
    out->truth.true_pose = [world, frames](const ScanViewRecord& v, Rigid3d* p) {
      if (static_cast<int64_t>(v.burst_seq) >= world->NumBursts(frames)) return false;
      *p = world->trajectory().WorldFromProbe(
          world->BurstMiddleNs(static_cast<int64_t>(v.burst_seq), frames));
      return true;
    };
  }
  return Status::Ok();
}

}  // namespace d3d
