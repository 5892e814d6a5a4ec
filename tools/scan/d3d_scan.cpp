// d3d-scan: the host application, the main job. Subscribes to the probe over DDS (or replays a
// recording losslessly with --replay), runs the stage graph ingest → reconstruct → register → fuse →
// preview (host/scan), shows the live preview (viewer/: a GLFW window, or offscreen with
// --headless), and at the end writes DIR/scan.ply, DIR/scan.stl, DIR/poses.txt, DIR/report.json and
// DIR/preview.png (and DIR/heatmap.png with a reference). A replay of a damaged recording scans
// every intact burst and saves the scan, then says on stderr what the file lost and exits 3.
//
// Thread pools are capped here (the tool owns the process): OpenCV and oneTBB to --threads, Mesa's
// llvmpipe to 1 rendering thread (LP_NUM_THREADS, unless set), so the graph's threads own the cores.
#include <tbb/global_control.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <thread>
#include <malloc.h>
#include <unistd.h>

#include "common/mesh/mesh_io.h"
#include "firmware/sim/session/sim_session.h"
#include "firmware/sim/trajectory/trajectory.h"
#include "host/scan/scan_app.h"
#include "tools/dds/tool_dds.h"
#include "viewer/viewer.h"

namespace fs = std::filesystem;
using namespace d3d;

namespace {
std::atomic<bool> g_stop{false}, g_save{false}, g_undo{false};
void OnSignal(int) { g_stop.store(true); }
void OnSave(int) { g_save.store(true); }
void OnUndo(int) { g_undo.store(true); }
// Resident set size now (MiB), from /proc/self/statm.
double RssMiB() {
  std::ifstream f("/proc/self/statm");
  long pages = 0, resident = 0;
  f >> pages >> resident;
  return static_cast<double>(resident) * static_cast<double>(sysconf(_SC_PAGESIZE)) / (1024.0 * 1024.0);
}
// Bytes malloc has handed out and not had back (all arenas: in use in the heaps, plus mmapped
// chunks), MiB. Beside the RSS it tells a growing program from an allocator keeping freed pages.
double HeapInUseMiB() {
  const struct mallinfo2 mi = mallinfo2();
  return static_cast<double>(mi.uordblks + mi.hblkhd) / (1024.0 * 1024.0);
}
double SteadyS() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }
}  // namespace

int main(int argc, char** argv) {
  CLI::App cli{"d3d-scan: the host application: live scan from the probe over DDS (or --replay FILE), live preview,\n"
               "and the fused model with its report. Writes DIR/scan.ply, scan.stl, poses.txt, report.json, preview.png."};
  std::string replay, out_dir = "scan_out", screenshot, policy_text, reference, sim_trajectory, serial, association = "grid";
  bool headless = false, json = false, no_preview = false, refuse = true, quiet = false;
  double undo_seconds = 2.0;
  int undo_views = 150;
  std::vector<uint64_t> undo_after;
  double duration_s = 0, probe_timeout_s = 1.0, idle_exit_s = 0, wait_probe_s = 120, preview_fps = 20, replay_rate = 0, step = 0;
  int domain = 0, threads = 0, width = 960, height = 720, bin = 2, icp_threads = 0;
  uint32_t sim_seed = 1;
  double sim_rate = 30;
  cli.add_option("--replay", replay, "replay a recording (d3d-record) through the same graph instead of listening on DDS");
  cli.add_option("--replay-rate", replay_rate, "--replay: 0 = as fast as the graph takes bursts, else the recorded timing x this")->capture_default_str();
  int64_t max_bursts = 0;
  size_t rx_queue = 0;
  cli.add_option("--frames", max_bursts, "--replay: use the first N bursts only (0 = all)")->capture_default_str();
  std::string replay_views;
  cli.add_option("--replay-views", replay_views,
                 "--replay: only the bursts whose capture times this TUM file lists (e.g. a live run's poses.txt: its views again, "
                 "losslessly, with the live tracker's gates: --step 6 by default and motion by capture time)");
  cli.add_option("--rx-queue", rx_queue,
                 "live: bursts the DDS receiver may hold for the graph (default: 64 live, 8 with --catch-up 0, 300 lossless)");
  double catch_up_s = ScanAppOptions{}.live_catch_up_max_s;
  cli.add_option("--catch-up", catch_up_s,
                 "live: process the bursts that arrived while the host set up, in order, until the graph has caught up, for at most "
                 "this many seconds, then thinned out (1 of 3 to 1 of 6) until caught up (0 = start on the newest burst and drop them)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 10.0));
  int bridge_bursts = GapBridgeOptions{}.ring_bursts;
  cli.add_option("--bridge", bridge_bursts,
                 "live: recent bursts kept so that a view refused several bursts after the last placed one is tried again after "
                 "one from between (host/scan/gap_bridge.h; 0 = off)")
      ->check(CLI::Range(0, 300))
      ->capture_default_str();
  cli.add_option("--out", out_dir, "output folder")->capture_default_str();
  cli.add_flag("--headless", headless, "render the preview offscreen (EGL, no display needed)");
  cli.add_flag("--no-preview", no_preview, "no preview at all");
  cli.add_option("--screenshot", screenshot, "save the final preview picture here too (PNG; DIR/preview.png is always written)");
  cli.add_option("--duration", duration_s, "stop after this many seconds (0 = until the end of the replay / the window closes / SIGINT)")->capture_default_str();
  cli.add_option("--policy", policy_text, "edge policy: live (latest wins, drops counted) | lossless (default: live on DDS, lossless with --replay)");
  cli.add_option("--reference", reference, "evaluate against this scene: typodont or a mesh file (mm)");
  cli.add_option("--sim-trajectory", sim_trajectory, "the virtual probe's scan path (a style: full-arch, lifts, quadrants, ...; quadrant or FILE.tum): true poses for the best fit and the ATE");
  cli.add_option("--sim-seed", sim_seed, "--sim-trajectory: its seed")->capture_default_str();
  cli.add_option("--sim-rate", sim_rate,
                 "the probe's burst rate (Hz): the true poses' timing with --sim-trajectory; live, the tracker's view period is --step / rate")
      ->capture_default_str();
  cli.add_flag("--refuse,!--no-refuse", refuse,
               "keep the fused bursts' frames (zstd, ~0.15 MB each at --bin 2) and fuse them again at the pose graph's poses at "
               "the end (default; the mesh then does not depend on how the tracker drifted, live or lossless)");
  std::string spill_views;
  cli.add_option("--spill-views", spill_views,
                 "--refuse: keep the fused bursts' frames in an unnamed temporary file in this folder (it leaves nothing behind) "
                 "so that memory stays flat however long the scan; 'memory' keeps them in memory (default: the --out folder)");
  bool just_in_time = ScanAppOptions{}.live_just_in_time;
  cli.add_flag("--just-in-time,!--no-just-in-time", just_in_time,
               "live: start reconstructing a burst just in time for the register stage, on a newer burst, instead of as soon as "
               "the register stage took the last one")
      ->capture_default_str();
  double live_voxel_mm = LiveVolumeOptions{}.voxel_mm;
  cli.add_option("--live-voxel", live_voxel_mm,
                 "--refuse: voxel (mm) of the live volume the fuse stage fuses each burst into, which a save mid-scan ('s') "
                 "writes (its band at least 2 voxels); the final model is fused again at 0.05 mm (0 = live at 0.05 mm too, "
                 "~4x the fuse stage's CPU)")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  cli.add_option("--bin", bin,
                 "average the camera's pixels over NxN blocks before reconstruction (1 = full resolution; 2: views of a quarter "
                 "the pixels, ~4x less reconstruction work)")
      ->capture_default_str();
  cli.add_option("--association", association, "the tracker's ICP data association: grid (nearest model sample, on a decimated model at the coarse level) | kdtree (exact nearest at every level, by nanoflann) | projective")->capture_default_str();
  cli.add_option("--step", step, "expected bursts between processed views for the tracker's gates (default: 1 lossless, 6 live)");
  double tracked_edge_factor = TrackerOptions{}.keyframes.tracked_edge_information_factor;
  cli.add_option("--tracked-edge-factor", tracked_edge_factor,
                 "pose graph: each keyframe also gets the tracked relative pose to its parent as an edge, with the keyframe ICP "
                 "edge's information times this (0 = none; KeyframeGraphOptions::tracked_edge_information_factor)")
      ->check(CLI::Range(0.0, 10.0))
      ->capture_default_str();
  cli.add_option("--domain", domain, "DDS domain id")->capture_default_str();
  cli.add_option("--serial", serial, "listen to this probe only (default: any)");
  cli.add_option("--probe-timeout", probe_timeout_s, "seconds without a burst before 'probe lost'")->capture_default_str();
  cli.add_option("--idle-exit", idle_exit_s, "live: finish after this many seconds without a burst (0 = wait for the probe to return)")->capture_default_str();
  cli.add_option("--wait-probe", wait_probe_s, "live: seconds to wait for the probe's ProbeInfo")->capture_default_str();
  cli.add_option("--threads", threads,
                 "OpenCV / oneTBB threads (the reconstruction's row blocks, the ICP, the fusion's loops); 0 = 1 live (the stage "
                 "threads alone own the cores), 2 lossless")->capture_default_str();
  cli.add_option("--icp-threads", icp_threads, "threads of the tracker's ICP (association and normal equations; at most --threads; 0 = --threads)")
      ->capture_default_str();
  cli.add_option("--preview-fps", preview_fps, "preview frame-rate cap")->capture_default_str();
  cli.add_option("--size", width, "preview width (px; height = 3/4)")->capture_default_str();
  cli.add_flag("--json", json, "print report.json as one line on stdout");
  cli.add_flag("--quiet", quiet, "no status line on stderr (SIGUSR1 saves the model now, as the 's' key; SIGUSR2 undoes, as 'u')");
  cli.add_option("--undo-seconds", undo_seconds, "the 'u' key takes back the views of this many seconds of scanning")->capture_default_str();
  cli.add_option("--undo-views", undo_views, "how many views back undo can reach (0 = no undo; ~0.4 MB each)")->capture_default_str();
  cli.add_option("--undo-after", undo_after, "scripted undo: press 'u' right after the N-th burst (repeatable; tests and demos)");
  CLI11_PARSE(cli, argc, argv);
  height = width * 3 / 4;
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  std::signal(SIGUSR1, OnSave);  // save the model now (as the 's' key)
  std::signal(SIGUSR2, OnUndo);  // undo the last seconds (as the 'u' key)
  EdgePolicy policy = replay.empty() ? EdgePolicy::kLive : EdgePolicy::kLossless;
  if (policy_text == "live") policy = EdgePolicy::kLive;
  else if (policy_text == "lossless") policy = EdgePolicy::kLossless;
  else if (!policy_text.empty()) {
    std::fprintf(stderr, "d3d-scan: --policy must be live or lossless\n");
    return 2;
  }
  if (!replay_views.empty() && replay.empty()) {
    std::fprintf(stderr, "d3d-scan: --replay-views needs --replay (the recording the live run scanned)\n");
    return 2;
  }
  // A live run's views (--replay-views) come as unevenly as they did live: the live tracker's gates.
  const bool live_views = policy == EdgePolicy::kLive || !replay_views.empty();
  if (step <= 0) step = live_views ? 6 : 1;
  // Live, the graph's stage threads (reconstruct, register, preview, fuse) and the render thread
  // already keep the 2 cores busy when the machine is slow, and oneTBB's worker then only contends
  // with them: its chunks wait for a core while the stage that lent them waits for the chunks, and
  // every hand-off costs wake-ups. Live 450-burst typodont recording (tools/bench/live_latency.sh):
  //   at 1.1 cores' worth of CPU (--cpu-quota 1.1, as the machine's slow hours), 6 interleaved rounds:
  //     2 threads: 24.4-29.3 bursts/s, latency p50 24-80 ms, p95 83-114 (median 86.6);
  //     1 thread:  28.3-29.6 bursts/s, p50 24-44 ms, p95 80-102 (median 85.2);
  //   at 1.0 core, 2 pairs: p95 116.7 / 92.2 ms at 24.8 / 28.4 bursts/s against 102.1 / 97.0 at 28.0;
  //   CPU over the busiest 12 s: 106-109 % of a core against 99-103 % (2 pairs, full speed);
  //   at full speed 1 thread costs ~3 ms: p50 21.5-21.8 against 18.5-18.6 ms, p95 27.0 against 24.9-25.2.
  // So live takes 1 (the worst cases matter, not the best). Lossless runs (replay, tests) keep 2:
  // nothing waits there but the run's length.
  if (threads <= 0) threads = policy == EdgePolicy::kLive ? 1 : 2;
  if (icp_threads <= 0) icp_threads = threads;
  Association assoc = Association::kGrid;
  if (bin < 1 || !ParseAssociation(association, &assoc)) {
    std::fprintf(stderr, "d3d-scan: --bin must be >= 1 and --association grid, kdtree or projective\n");
    return 2;
  }
  cv::setNumThreads(threads);
  tbb::global_control tbb_cap(tbb::global_control::max_allowed_parallelism, static_cast<size_t>(threads));
  setenv("LP_NUM_THREADS", "1", 0);

  try {
    // The preview first: the window is there (showing "waiting for probe") while the host waits for
    // the probe, and its set-up is not part of the ~0.4 s in which the probe's first bursts queue.
    std::unique_ptr<Viewer> viewer;
    if (!no_preview) {
      ViewerOptions vo;
      vo.headless = headless;
      vo.width = width;
      vo.height = height;
      Status s = Viewer::Create(vo, &viewer);
      if (!s.ok() && !headless) {
        std::fprintf(stderr, "d3d-scan: %s; rendering offscreen instead\n", s.ToString().c_str());
        vo.headless = true;
        s = Viewer::Create(vo, &viewer);
      }
      if (!s.ok()) std::fprintf(stderr, "d3d-scan: no preview: %s\n", s.ToString().c_str());
    }
    // Source.
    std::unique_ptr<RecordingBurstSource> rec;
    proto::DdsParticipant participant;
    std::unique_ptr<BurstReceiver> rx;
    std::unique_ptr<DdsBurstSource> dds;
    BurstSource* source = nullptr;
    ProbeCalibration calib;
    if (!replay.empty()) {
      RecordingSourceOptions ro;
      ro.rate = replay_rate;
      ro.max_bursts = max_bursts;
      if (!replay_views.empty()) {
        Trajectory views;
        if (const Status s = Trajectory::LoadTum(replay_views, &views); !s.ok()) {
          std::fprintf(stderr, "d3d-scan: --replay-views: %s\n", s.ToString().c_str());
          return 2;
        }
        for (const TimedPose& k : views.keys()) ro.select_capture_ns.push_back(k.t_ns);
      }
      if (const Status s = RecordingBurstSource::Open(replay, ro, &rec); !s.ok()) {
        std::fprintf(stderr, "d3d-scan: %s: %s\n", replay.c_str(), s.ToString().c_str());
        return 2;
      }
      calib = rec->calibration();
      source = rec.get();
    } else {
      if (const Status s = tools::CreateToolParticipant(domain, &participant, "d3d-scan"); !s.ok()) {
        std::fprintf(stderr, "d3d-scan: DDS: %s\n", s.ToString().c_str());
        return 3;
      }
      ReceiverOptions ro;
      ro.serial = serial;
      // Live: room for the backlog the catch-up start works off: the bursts that arrive while the
      // host sets up (~0.4 s) and while it falls behind before it thins out (docs/decisions/0014).
      ro.queue_capacity = rx_queue > 0 ? rx_queue : (policy == EdgePolicy::kLive ? (catch_up_s > 0 ? 64 : 8) : 300);
      ro.log = [](const std::string& m) { std::fprintf(stderr, "d3d-scan: %s\n", m.c_str()); };
      rx = std::make_unique<BurstReceiver>(ro);
      if (const Status s = rx->Start(&participant); !s.ok()) {
        std::fprintf(stderr, "d3d-scan: %s\n", s.ToString().c_str());
        return 3;
      }
      DdsSourceOptions dso;
      dso.probe_timeout_s = probe_timeout_s;
      dso.idle_exit_s = idle_exit_s;
      // Live: no burst older than this is ingested (without the catch-up start: start on fresh bursts,
      // not on those queued during set-up). With it, the backlog may reach ~2 s before the thinning
      // gains on it; dropped here, its oldest bursts would leave a gap the tracker cannot bridge.
      if (policy == EdgePolicy::kLive) dso.max_age_s = catch_up_s > 0 ? 1.25 + catch_up_s : 0.25;
      dds = std::make_unique<DdsBurstSource>(rx.get(), dso);
      std::fprintf(stderr, "d3d-scan: waiting for a probe on DDS domain %d...\n", domain);
      proto::InfoMsg info;
      const auto waiting_frame = [&] {  // the preview stays responsive while it waits (close = quit)
        if (!viewer) return;
        PreviewStatus st;
        st.override_cue = true;
        st.cue_override = PreviewCue::kWaiting;
        st.message = "waiting for a probe on DDS domain " + std::to_string(domain);
        if (!viewer->Render(nullptr, st, 0)) g_stop.store(true);  // window closed
      };
      if (const Status s = dds->WaitForCalibration(wait_probe_s, &g_stop, &calib, &info, waiting_frame); !s.ok()) {
        std::fprintf(stderr, "d3d-scan: %s\n", s.ToString().c_str());
        return 3;
      }
      std::fprintf(stderr, "d3d-scan: probe %s (%s, %ux%u)\n", info.serial.c_str(), info.sensor_model.c_str(), info.width, info.height);
      source = dds.get();
    }
    ScanAppOptions ao;
    ao.policy = policy;
    ao.scan.tracker = TrackerOptionsForStep(ao.scan.tracker, step);
    ao.scan = LiveScanProfile(ao.scan);  // keyframe work off the critical path, keyframe reuse, ICP sample caps
    ao.scan.tracker.odometry.association = assoc;
    ao.scan.tracker.keyframes.tracked_edge_information_factor = tracked_edge_factor;
    // The tracker's ICP (association and normal equations) on the register thread and a oneTBB
    // worker (--icp-threads, at most --threads; its sums in a fixed order, so a lossless run still
    // repeats bit for bit). Once the graph left a share of the 2 cores idle (~67 % used live), the
    // worker shortened the register stage where it sets the latency. Live 450-burst typodont
    // recording at 30 Hz, runs interleaved, 1 thread (12 runs) -> 2 (11 runs): register wall 21.8 ->
    // 18.3 ms per burst, latency p50 40.2 -> 34.2 ms, p95 median 80.4 -> 53.3 ms, trueness 11.0-13.3
    // -> 11.0-13.2 um; lossless 12.15 -> 12.14 um. It used to be 1: when the stages alone kept both
    // cores busy, the workers only contended with them (600-burst recording, before the stages got
    // cheaper: register 144 -> 78 ms per burst with 1 thread, 6.8 -> 10.8-12.1 bursts/s). Since
    // the machine's slow hours made the stages alone fill what the cores deliver, live takes 1 again
    // (see --threads above); lossless keeps 2.
    ao.scan.tracker.odometry.icp.threads = std::clamp(icp_threads, 1, threads);
    // The reconstruction's per-pixel passes on blocks of rows (ReconstructOptions::threads): the
    // same bits, shorter when a core is free (d3d-bench-recon, 640 x 480 on an idle machine: 47.6 ->
    // 41.3 ms; phase 11.1 -> 9.0, triangulation and normals 11.4 -> 6.8; the unwrapping stays serial).
    ao.scan.recon.threads = threads;
    // Live, the gaps between processed views vary with the load: motion prediction and limits by
    // capture time, in views of `step` bursts.
    if (live_views && sim_rate > 0) ao.scan.tracker.motion.view_period_ns = std::llround(step * 1e9 / sim_rate);
    ao.scan.refuse_min_correction_mm = refuse ? 0.01 : -1;
    ao.keep_views = refuse;
    if (refuse && spill_views != "memory") {
      ao.views_spill_dir = spill_views.empty() ? out_dir : spill_views;
      std::error_code ec;
      fs::create_directories(ao.views_spill_dir, ec);  // the --out folder is made early for it
    }
    ao.live.voxel_mm = live_voxel_mm;
    ao.live_just_in_time = just_in_time;
    ao.live_catch_up_max_s = catch_up_s;
    ao.bridge.ring_bursts = bridge_bursts;
    ao.undo_seconds = undo_seconds;
    ao.undo_max_views = undo_views;
    ao.undo_after_bursts = undo_after;
    ao.scan = ScanOptionsForBin(ao.scan, bin);
    ao.view_stride_px = std::max(2, ao.view_stride_px / bin);
    ScanApp app(calib, ao, source);
    if (!app.views_spill_error().empty())
      std::fprintf(stderr, "d3d-scan: the kept frames stay in memory: %s\n", app.views_spill_error().c_str());

    std::fprintf(stderr, "d3d-scan: %s graph, %s preview; out %s\n", EdgePolicyName(policy),
                 viewer ? (viewer->headless() ? "offscreen" : "window") : "no", out_dir.c_str());
    app.Start();
    const double t0 = SteadyS();
    double next_frame = t0, next_line = t0 + 1, fps = 0, fps_t0 = t0, last_fps_t = t0;
    int64_t frames = 0, fps_frames = 0;
    std::vector<double> rss_timeline;  // MiB, once a second: memory must stay flat after warm-up
    std::vector<ScanMemory> memory_timeline;  // what the scan's growing parts hold, at the same seconds
    std::vector<double> heap_timeline;        // MiB malloc has handed out, at the same seconds
    std::mutex message_mu;  // the saver thread sets the message line, the render loop reads it
    std::string message;
    double message_until = 0;
    std::thread saver;
    std::atomic<bool> saving{false};
    const double frame_dt = 1.0 / std::max(1.0, preview_fps);
    uint64_t undos_seen = 0;
    const auto undo = [&](double now) {
      if (app.RequestUndo()) return;
      std::lock_guard<std::mutex> lock(message_mu);
      message = "undo is off (--no-refuse or --undo-views 0)";
      message_until = now + 3;
    };
    while (!app.finished()) {
      const double now = SteadyS();
      if (g_stop.load() || (duration_s > 0 && now - t0 >= duration_s)) break;
      if (g_undo.exchange(false)) undo(now);
      if (app.undos_done() != undos_seen) {  // what the last undo did, on the status line
        undos_seen = app.undos_done();
        const std::string m = app.LastUndoMessage();
        if (!quiet) std::fprintf(stderr, "\nd3d-scan: %s\n", m.c_str());
        std::lock_guard<std::mutex> lock(message_mu);
        message = m;
        message_until = now + 3;
      }
      if (g_save.exchange(false) && !saving.exchange(true)) {
        if (saver.joinable()) saver.join();
        saver = std::thread([&app, &saving, out_dir, &message, &message_until, &message_mu] {
          const Status s = app.SaveNow(out_dir);
          std::fprintf(stderr, "\nd3d-scan: %s\n", s.ok() ? ("saved " + out_dir + "/scan.ply").c_str() : s.ToString().c_str());
          std::lock_guard<std::mutex> lock(message_mu);
          message = s.ok() ? "saved " + out_dir + "/scan.ply" : "save failed: " + s.ToString();
          message_until = SteadyS() + 4;
          saving.store(false);
        });
      }
      if (viewer) {
        if (now >= next_frame) {
          next_frame = std::max(next_frame + frame_dt, now);
          PreviewStatus st = app.CurrentStatus();
          {
            std::lock_guard<std::mutex> lock(message_mu);
            if (now < message_until) st.message = message;
          }
          if (!viewer->Render(app.LatestSnapshot(), st, fps)) break;  // window closed
          ++frames;
          ++fps_frames;
          if (now - last_fps_t >= 1.0) {
            fps = static_cast<double>(fps_frames) / (now - last_fps_t);
            fps_frames = 0;
            last_fps_t = now;
          }
          for (ViewerAction a : viewer->TakeActions()) {
            if (a == ViewerAction::kQuit) g_stop.store(true);
            else if (a == ViewerAction::kPause) app.SetPaused(!app.paused());
            else if (a == ViewerAction::kUndo) undo(now);
            else if (a == ViewerAction::kReset) {
              app.Reset();
              std::lock_guard<std::mutex> lock(message_mu);
              message = "model reset";
              message_until = now + 3;
            } else if (a == ViewerAction::kSave && !saving.exchange(true)) {
              if (saver.joinable()) saver.join();
              saver = std::thread([&app, &saving, out_dir, &message, &message_until, &message_mu] {
                const Status s = app.SaveNow(out_dir);
                std::lock_guard<std::mutex> lock(message_mu);
                message = s.ok() ? "saved " + out_dir + "/scan.ply" : "save failed: " + s.ToString();
                message_until = SteadyS() + 4;
                saving.store(false);
              });
            }
          }
        }
      }
      if (now >= next_line) {
        next_line += 1;
        rss_timeline.push_back(RssMiB());
        memory_timeline.push_back(app.Memory());
        heap_timeline.push_back(HeapInUseMiB());
        if (quiet) continue;
        const PreviewStatus st = app.CurrentStatus();
        std::fprintf(stderr, "\rd3d-scan: %5.0f s  received %llu  processed %llu  fused %llu  dropped %llu  %.1f bursts/s  latency p95 %.0f ms  %s   ",
                     now - t0, static_cast<unsigned long long>(st.bursts_received), static_cast<unsigned long long>(st.bursts_processed),
                     static_cast<unsigned long long>(st.bursts_fused), static_cast<unsigned long long>(st.bursts_dropped), st.bursts_per_s,
                     st.latency_ms_p95, st.override_cue ? PreviewCueText(st.cue_override) : "");
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(viewer ? 2 : 20));
    }
    const double preview_s = SteadyS() - fps_t0;
    app.RequestStop();
    app.Join();
    if (saver.joinable()) saver.join();
    if (!quiet) std::fprintf(stderr, "\n");
    if (rx) rx->Stop();

    // Evaluation truth.
    std::unique_ptr<SimSession> session;
    TriangleMesh scene;
    ScanTruth truth;
    if (!reference.empty()) {
      SimSessionOptions so;
      so.model = reference;
      so.trajectory = sim_trajectory.empty() ? "full-arch" : sim_trajectory;
      so.seed = sim_seed;
      so.burst_rate_hz = sim_rate;
      so.camera_width = calib.camera.width;
      so.camera_height = calib.camera.height;
      if (reference == "typodont" || !sim_trajectory.empty()) {
        if (const Status s = SimSession::Create(so, &session); !s.ok()) {
          std::fprintf(stderr, "d3d-scan: reference: %s\n", s.ToString().c_str());
          return 2;
        }
        scene = session->scene();
      } else if (const Status s = LoadMesh(reference, &scene); !s.ok()) {
        std::fprintf(stderr, "d3d-scan: reference: %s\n", s.ToString().c_str());
        return 2;
      }
      if (!scene.face_colors.empty() && scene.face_labels.empty()) LabelFacesFromColors(&scene);
      truth.reference = &scene;
      if (!sim_trajectory.empty()) {
        const int64_t offset = (calib.pattern.steps - 1) * so.render.frame_interval_ns / 2;
        truth.true_pose = [&session, offset](const ScanViewRecord& v, Rigid3d* p) {
          if (static_cast<int64_t>(v.burst_seq) >= session->NumBursts()) return false;
          *p = session->trajectory().WorldFromProbe(session->BurstStartNs(static_cast<int64_t>(v.burst_seq)) + offset);
          return true;
        };
      }
    }
    // Refusion (--refuse): the app's kept views.
    ScanResult result;
    const Status fs_status = app.Finish(truth, ScanViewProvider(), &result);
    result.report["input"] = replay.empty() ? "dds" : replay;
    result.report["preview_fps"] = viewer && preview_s > 0 ? static_cast<double>(frames) / preview_s : 0.0;
    // Of those frames, the ones drawn: the others showed the same picture (Viewer::Render).
    result.report["preview_draws_per_s"] = viewer && preview_s > 0 ? static_cast<double>(viewer->frames_drawn()) / preview_s : 0.0;
    result.report["preview"] = viewer ? (viewer->headless() ? "offscreen" : "window") : "none";
    result.report["step"] = step;
    result.report["rss_mb_per_s"] = rss_timeline;
    {
      nlohmann::json mem;  // one array per figure, aligned with rss_mb_per_s
      const auto column = [&](const char* name, auto field) {
        nlohmann::json a = nlohmann::json::array();
        for (const ScanMemory& m : memory_timeline) a.push_back(field(m));
        mem[name] = std::move(a);
      };
      column("views", [](const ScanMemory& m) { return m.views; });
      column("model_samples", [](const ScanMemory& m) { return m.model_samples; });
      column("model_mib", [](const ScanMemory& m) { return m.model_mib; });
      column("undo_journal_mib", [](const ScanMemory& m) { return m.undo_journal_mib; });
      column("keyframes", [](const ScanMemory& m) { return m.keyframes; });
      column("keyframes_mib", [](const ScanMemory& m) { return m.keyframes_mib; });
      column("tsdf_mib", [](const ScanMemory& m) { return m.tsdf_mib; });
      column("views_kept_memory_mib", [](const ScanMemory& m) { return m.views_kept_memory_mib; });
      column("preview_points", [](const ScanMemory& m) { return m.preview_points; });
      mem["heap_in_use_mib"] = heap_timeline;
      result.report["memory_per_s"] = std::move(mem);
    }
    result.report["threads"] = threads;
    result.report["bin"] = bin;
    if (rec) {
      result.report["recording_problems"] = rec->diagnostics().problems;
      // What a damaged recording lost (from the index, the chunk headers and the bursts' numbers):
      // bursts_missing_upstream counts only the jumps within intact data.
      const SequenceLossCounter& lost = rec->bursts_lost();
      result.report["recording_damaged"] = rec->diagnostics().damaged();
      result.report["recording_lost"] = rec->diagnostics().LossSummary();
      result.report["bursts_lost_in_recording"] = lost.lost_min();
      result.report["bursts_lost_in_recording_max"] = lost.lost_max() ? nlohmann::json(*lost.lost_max()) : nlohmann::json(nullptr);
    }
    if (rec && !replay_views.empty()) {
      result.report["replay_views"] = replay_views;
      result.report["bursts_skipped"] = rec->skipped();
    }
    if (!fs_status.ok()) {
      std::fprintf(stderr, "d3d-scan: %s\n", fs_status.ToString().c_str());
      std::error_code ec;
      fs::create_directories(out_dir, ec);
      std::ofstream(fs::path(out_dir) / "report.json") << result.report.dump(2) << "\n";
      return 1;
    }
    if (const Status s = WriteScanOutputs(out_dir, result); !s.ok()) {
      std::fprintf(stderr, "d3d-scan: %s\n", s.ToString().c_str());
      return 1;
    }
    if (viewer) {
      // The final picture: the last snapshot (the whole model), status as at the end.
      PreviewStatus st = app.CurrentStatus();
      st.message = "scan finished";
      st.override_cue = st.override_cue && st.cue_override != PreviewCue::kProbeLost;  // the model's own state
      const PreviewSnapshot* snap = app.LatestSnapshot();
      cv::Mat picture;
      viewer->Render(snap, st, fps, &picture);
      if (!picture.empty()) {
        cv::imwrite((fs::path(out_dir) / "preview.png").string(), picture);
        if (!screenshot.empty()) cv::imwrite(screenshot, picture);
      }
    }
    if (json) std::printf("%s\n", result.report.dump().c_str());
    else {
      nlohmann::json brief = result.report;
      brief.erase("events");
      std::printf("%s\n", brief.dump(2).c_str());
    }
    if (rec && rec->diagnostics().damaged()) {  // the scan is saved; the input was not whole
      for (const std::string& p : rec->diagnostics().problems) std::fprintf(stderr, "d3d-scan: %s: damaged: %s\n", replay.c_str(), p.c_str());
      std::fprintf(stderr,
                   "d3d-scan: warning: %s is damaged; the scan used every intact chunk and is saved in %s; lost: %s; bursts lost: %s (exit 3)\n",
                   replay.c_str(), out_dir.c_str(), rec->diagnostics().LossSummary().c_str(), rec->bursts_lost().Describe().c_str());
      return 3;
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-scan: %s\n", e.what());
    return 2;
  }
  return 0;
}
