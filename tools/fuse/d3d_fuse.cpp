// d3d-fuse: the whole offline chain on the virtual probe or a folder of bursts:
// burst → reconstruction (pipeline/recon) → frame-to-model registration with loss detection and
// relocalisation (pipeline/register) → TSDF fusion (pipeline/fuse) → pose graph with loop
// closures → mesh (PLY, STL, mm) → evaluation against the scene (pipeline/eval) when it is known.
#include <sys/resource.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <optional>
#include <thread>
#include <nlohmann/json.hpp>
#include <tbb/concurrent_queue.h>

#include "common/burst/burst_io.h"
#include "common/core/progress.h"
#include "common/mesh/mesh_io.h"
#include "common/pack/frame_pack.h"
#include "firmware/sim/session/sim_session.h"
#include "pipeline/recon/evaluate.h"
#include "pipeline/scan/scan_chain.h"
#include "pipeline/scan/view_archive.h"

namespace fs = std::filesystem;
using namespace d3d;

namespace {

double PeakRssMiB() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return static_cast<double>(u.ru_maxrss) / 1024.0;
}

int Fail(const Status& s) {
  std::fprintf(stderr, "d3d-fuse: %s\n", s.ToString().c_str());
  return 1;
}

void PrintPose(std::FILE* f, const Rigid3d& p) { std::fprintf(f, " %s", TumPoseFields(p).c_str()); }

// --pose-graph: the keyframes' nodes (their pose in the graph: optimised, or the tracked one when
// the graph was not optimised (--no-loops); and the true one when known) and every edge
// with its measurement and information, for offline study of what bends the arch.
Status WritePoseGraph(const std::string& path, const ScanRegistrar& registrar, const std::map<uint64_t, Rigid3d>& true_poses) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) return IoError("cannot write '" + path + "'");
  std::fprintf(f, "# node <node> <view> <burst> <graph t q> [<true t q>]\n"
                  "# edge <from> <to> <loop> <measured from_from_to t q> <information 6x6 row-major>\n");
  const Tracker& tracker = registrar.tracker();
  for (const Keyframe& kf : tracker.keyframes()) {
    const uint64_t burst = registrar.views()[static_cast<size_t>(kf.view)].burst_seq;
    std::fprintf(f, "node %d %lld %llu", kf.node, static_cast<long long>(kf.view), static_cast<unsigned long long>(burst));
    PrintPose(f, tracker.graph().pose(kf.node));
    if (const auto it = true_poses.find(burst); it != true_poses.end()) PrintPose(f, it->second);
    std::fprintf(f, "\n");
  }
  for (const PoseGraphEdge& e : tracker.graph().edges()) {
    std::fprintf(f, "edge %d %d %d", e.from, e.to, e.loop ? 1 : 0);
    PrintPose(f, e.from_from_to);
    for (int i = 0; i < 36; ++i) std::fprintf(f, " %.6g", e.information(i / 6, i % 6));
    std::fprintf(f, "\n");
  }
  const bool ok = std::ferror(f) == 0;
  return std::fclose(f) == 0 && ok ? Status::Ok() : IoError("cannot write '" + path + "'");
}

// Bursts loaded (rendered by the virtual probe, or read) in order on a thread of its own, at most
// two ahead of the one the chain takes: the renderer works while the chain processes the burst
// before. The same bursts in the same order, so the same outputs. Threads: `load` runs on the
// prefetch thread only (the virtual probe is that thread's while the prefetcher lives); Next is
// the caller's.
class BurstPrefetcher {
 public:
  using Loader = std::function<Status(int64_t index, Burst* out)>;
  BurstPrefetcher(std::vector<int64_t> indices, Loader load) {
    queue_.set_capacity(2);
    thread_ = std::thread([this, indices = std::move(indices), load = std::move(load)] {
      for (const int64_t index : indices) {
        if (stop_.load()) break;
        Loaded item;
        const auto t0 = std::chrono::steady_clock::now();
        try {
          item.status = load(index, &item.burst);
        } catch (const std::exception& e) {
          item.status = Status(StatusCode::kInternal, std::string("loading burst ") + std::to_string(index) + ": " + e.what());
        }
        item.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
        const bool failed = !item.status.ok();
        while (!stop_.load() && !queue_.try_push(std::move(item))) std::this_thread::sleep_for(std::chrono::microseconds(200));
        if (failed) break;
      }
    });
  }
  ~BurstPrefetcher() {  // an early return: the thread stops after its current burst
    stop_.store(true);
    thread_.join();
  }
  // The next burst in order, its loader's status and how long it took on the prefetch thread (ms).
  // Call it at most once per index, and not after a failed one (the thread pushes one item per
  // index up to the first failure, so a pop always has an item coming).
  Status Next(Burst* out, double* ms) {
    Loaded item;
    queue_.pop(item);
    *out = std::move(item.burst);
    *ms = item.ms;
    return item.status;
  }

 private:
  struct Loaded {
    Status status;
    Burst burst;
    double ms = 0;
  };
  tbb::concurrent_bounded_queue<Loaded> queue_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"d3d-fuse: registers and fuses a scan into one mesh (mm) and evaluates it when the truth is known.\n"
               "Input: the virtual probe (--sim MODEL) or a folder of bursts written by d3d-sim (--bursts DIR).\n"
               "Output: DIR/scan.ply, DIR/scan.stl, DIR/poses.txt (TUM, mm), DIR/report.json, DIR/heatmap.png,\n"
               "DIR/truth_poses.txt (the true poses of the fused views, scene frame, when the source knows them)."};
  std::string sim_model, bursts_dir, trajectory = "full-arch", out_dir, association = "grid", trace_path, graph_path;
  uint32_t seed = 1;
  int every = 1;
  int bin = 2;  // d3d-scan's
  int64_t max_bursts = -1, first = 0;
  double voxel_mm = 0.05, truncation_mm = 0.2;
  float min_mesh_weight = TsdfOptions{}.min_mesh_weight;
  double max_cell_sdf_span = TsdfOptions{}.max_cell_sdf_span, occlusion_margin_mm = TsdfOptions{}.occlusion_margin_mm;
  double max_rmse_um = TrackerOptions{}.odometry.icp.max_rmse_mm * 1000;
  bool json = false, no_eval = false, no_loops = false, quiet = false, no_refuse = false, truth_poses = false;
  int edge_fill_passes = EdgeFillOptions{}.passes;
  float edge_fill_quality = EdgeFillOptions{}.quality_factor;
  float secondary_fade_weight = TsdfOptions{}.secondary_fade_weight;
  double keyframe_max_rotation_deg = TrackerOptions{}.keyframes.max_rotation_deg;
  int keyframe_max_views = TrackerOptions{}.keyframes.max_views;
  double tracked_edge_factor = TrackerOptions{}.keyframes.tracked_edge_information_factor;
  double reentry_max_violation = ReentryCheckOptions{}.max_violation_fraction;
  bool no_model_anchor = false, coverage_ceiling = false, no_free_space = false;
  std::string profile = "live";
  app.add_option("--profile", profile,
                 "scan profile: live (d3d-scan's: LiveScanProfile, pipeline/scan/scan_chain.h: keyframe work off the\n"
                 "critical path, keyframe reuse, ICP sample caps per level) | full (every ICP sample, keyframe features and\n"
                 "edges as they come)")
      ->check(CLI::IsMember({"live", "full"}))
      ->capture_default_str();
  app.add_option("--sim", sim_model, "scan with the virtual probe: 'typodont' or a mesh file (PLY/STL/OBJ, mm)");
  app.add_option("--bursts", bursts_dir, "a d3d-sim output folder (calibration.json, bursts/NNNNNN/, scene.ply)");
  app.add_option("--trajectory", trajectory, "--sim: a scan style (" + ScanStyleList() + "), quadrant or a TUM file")->capture_default_str();
  app.add_option("--seed", seed, "--sim: seed of hand motion and sensor noise")->capture_default_str();
  app.add_option("--out", out_dir, "output folder")->required();
  app.add_option("--every", every, "use every N-th burst (a lower burst rate, for quick runs)")->capture_default_str();
  app.add_option("--bin", bin, "average the camera's pixels over NxN blocks before reconstruction (2, as d3d-scan; 1 = full resolution)")
      ->capture_default_str();
  app.add_option("--first", first, "first burst index")->capture_default_str();
  app.add_option("--max-bursts", max_bursts, "stop after this many bursts used (default: all)");
  app.add_option("--association", association, "ICP data association: grid (default; nearest model sample, on a decimated model at the coarse level) | kdtree (exact nearest at every level, by nanoflann) | projective")->capture_default_str();
  app.add_option("--voxel", voxel_mm, "TSDF voxel (mm)")->capture_default_str();
  app.add_option("--truncation", truncation_mm, "TSDF truncation (mm)")->capture_default_str();
  app.add_option("--max-rmse-um", max_rmse_um, "tracking: a view whose ICP residual (RMS, um) is above this is refused")
      ->capture_default_str();
  app.add_option("--min-mesh-weight", min_mesh_weight, "mesh only where the fused weight (sum of point qualities) is at least this")
      ->capture_default_str();
  app.add_option("--max-cell-sdf-span", max_cell_sdf_span,
                 "mesh: drop a vertex whose 8 voxels' signed distances span more than this many cell diagonals (0 = off)")
      ->capture_default_str();
  app.add_option("--occlusion-margin", occlusion_margin_mm,
                 "fusion: a point more than this (mm) behind a surface the model knows is not fused (0 = no test)")
      ->capture_default_str();
  app.add_flag("--no-free-space", no_free_space,
               "fusion: no free-space test (by default a point in space that earlier views saw through is not fused)");
  app.add_flag("--no-eval", no_eval, "skip the evaluation against the scene");
  app.add_flag("--no-loops", no_loops, "no loop-closure detection / pose graph");
  app.add_option("--edge-fill-passes", edge_fill_passes,
                 "reconstruction: pixel layers of the albedo-edge cut given the phase of the anchored pixels beside them (0 = off)")
      ->check(CLI::Range(0, 64));
  app.add_option("--edge-fill-quality", edge_fill_quality,
                 "reconstruction: a pixel filled in the albedo-edge cut weighs this times the anchored pixel it came from")
      ->check(CLI::Range(0.001f, 1.0f));
  app.add_option("--keyframe-max-rotation", keyframe_max_rotation_deg,
                 "tracking: a view that turned more than this (deg) since the last keyframe is one too (0 = off)")
      ->capture_default_str();
  app.add_option("--keyframe-max-views", keyframe_max_views,
                 "tracking: a view this many views after the last keyframe is one too (0 = off)")
      ->capture_default_str();
  app.add_option("--tracked-edge-factor", tracked_edge_factor,
                 "pose graph: each keyframe also gets the tracked relative pose to its parent as an edge, with the keyframe ICP "
                 "edge's information times this (0 = none; KeyframeGraphOptions::tracked_edge_information_factor)")
      ->check(CLI::Range(0.0, 10.0))
      ->capture_default_str();
  app.add_option("--reentry-max-violation", reentry_max_violation,
                 "tracking: a re-entry pose is refused when more than this share of the points it compares with the keyframes\n"
                 "near it lie in space one side saw through (1 = no check; ReentryCheckOptions::max_violation_fraction)")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  app.add_option("--edge-fill-fade", secondary_fade_weight,
                 "fusion: edge-filled points shape the surface only until the other points' fused weight reaches this (0 = they count "
                 "like the rest; 2 measured: trueness -0.1..-0.5 um, memory +360 MiB)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_flag("--no-model-anchor", no_model_anchor,
               "no model-guided anchoring (the parts of a view its burst could not anchor stay out)");
  app.add_flag("--coverage-ceiling", coverage_ceiling,
               "--sim: also report coverage_seen_pct, the share of the reference tooth surface that the bursts saw\n"
               "(lit, in the measurement volume, within the fusion's incidence limit): what coverage_pct can reach");
  app.add_flag("--quiet", quiet, "no progress bar");
  double live_voxel_mm = LiveVolumeOptions{}.voxel_mm;
  app.add_option("--live-voxel", live_voxel_mm,
                 "voxel (mm) of the live volume each view is fused into as the scan goes, as d3d-scan's; the model is the\n"
                 "kept views fused again at --voxel at the end (0 = live at --voxel; with --no-refuse the live volume is the\n"
                 "model, at --voxel)")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  app.add_flag("--no-refuse", no_refuse,
               "keep the model fused at the tracked poses (default: when the pose graph moves a view by more than\n"
               "10 um, the accepted bursts are reconstructed again and fused at the optimised poses)");
  app.add_flag("--truth-poses", truth_poses,
               "debug: no registration; every view is fused at its true pose (from the virtual probe or the bursts'\n"
               "truth), which measures the fusion-only error floor");
  app.add_option("--trace", trace_path,
                 "debug: write one line per burst (burst, accepted, state, icp rmse um, overlap, eigen ratio,\n"
                 "correspondences, new keyframe, loops, true step error um / deg; with --sim also the registered view's\n"
                 "RMS error um, wrong fringe orders % and tooth pixels reconstructed %) to this file");
  app.add_option("--pose-graph", graph_path,
                 "debug: write the pose graph to this file: one line per keyframe (node, view, burst, its world_from_cam\n"
                 "in the graph: optimised, or with --no-loops the tracked one; and, when known, the true one: t mm,\n"
                 "quaternion x y z w) and per edge (from, to, loop, measured from_from_to, its 6x6 information\n"
                 "row-major, zeros when the edge uses its sigmas)");
  app.add_flag("--json", json, "print report.json as one line on stdout");
  CLI11_PARSE(app, argc, argv);
  if (sim_model.empty() == bursts_dir.empty()) {
    std::fprintf(stderr, "d3d-fuse: give exactly one of --sim MODEL or --bursts DIR\n");
    return 2;
  }
  Association assoc = Association::kGrid;
  if (every < 1 || bin < 1 || !ParseAssociation(association, &assoc)) {
    std::fprintf(stderr, "d3d-fuse: --every and --bin must be >= 1 and --association grid|kdtree|projective\n");
    return 2;
  }
  try {
    std::error_code ec;
    fs::create_directories(out_dir, ec);
    if (ec) return Fail(IoError("cannot create '" + out_dir + "'"));
    // Source of bursts.
    std::unique_ptr<SimSession> session;
    ProbeCalibration calib;
    TriangleMesh scene;
    std::vector<std::string> burst_dirs;
    int64_t n_total = 0;
    if (!sim_model.empty()) {
      SimSessionOptions so;
      so.model = sim_model;
      so.trajectory = trajectory;
      so.seed = seed;
      if (const Status s = SimSession::Create(so, &session); !s.ok()) return Fail(s);
      calib = session->calibration();
      scene = session->scene();
      n_total = session->NumBursts();
    } else {
      if (const Status s = ProbeCalibration::Load((fs::path(bursts_dir) / "calibration.json").string(), &calib); !s.ok())
        return Fail(s);
      for (const auto& e : fs::directory_iterator(fs::path(bursts_dir) / "bursts"))
        if (e.is_directory()) burst_dirs.push_back(e.path().string());
      std::sort(burst_dirs.begin(), burst_dirs.end());
      n_total = static_cast<int64_t>(burst_dirs.size());
      const fs::path scene_path = fs::path(bursts_dir) / "scene.ply";
      if (fs::exists(scene_path) && !LoadMesh(scene_path.string(), &scene).ok()) scene = TriangleMesh{};
      if (!scene.face_colors.empty() && scene.face_labels.empty()) LabelFacesFromColors(&scene);
    }
    std::vector<int64_t> indices;
    for (int64_t i = first; i < n_total; i += every) {
      if (max_bursts >= 0 && static_cast<int64_t>(indices.size()) >= max_bursts) break;
      indices.push_back(i);
    }
    // The chain of pipeline/scan, all on this thread.
    ScanOptions so;
    if (profile == "live") so = LiveScanProfile(so);
    so.tracker.odometry.association = assoc;
    so.tracker.keyframes.detect_loops = !no_loops;
    so.anchor.enabled = !no_model_anchor;
    so.recon.edge_fill.passes = edge_fill_passes;
    so.recon.edge_fill.quality_factor = edge_fill_quality;
    so.free_space.enabled = !no_free_space;
    so.tracker.odometry.icp.max_rmse_mm = max_rmse_um / 1000.0;
    so.tracker = TrackerOptionsForStep(so.tracker, every);  // a lower burst rate means larger steps
    so.tsdf.voxel_mm = voxel_mm;
    so.tsdf.truncation_mm = truncation_mm;
    so.tsdf.min_mesh_weight = min_mesh_weight;
    so.tsdf.secondary_fade_weight = secondary_fade_weight;
    so.tracker.keyframes.max_rotation_deg = keyframe_max_rotation_deg;
    so.tracker.keyframes.max_views = keyframe_max_views;
    so.tracker.keyframes.tracked_edge_information_factor = tracked_edge_factor;
    so.tracker.relocaliser.check.max_violation_fraction = reentry_max_violation;
    so.tsdf.max_cell_sdf_span = max_cell_sdf_span;
    so.tsdf.occlusion_margin_mm = occlusion_margin_mm;
    if (no_refuse) so.refuse_min_correction_mm = -1;
    so = ScanOptionsForBin(so, bin);
    so.Check();
    ScanReconstructor recon(calib, so.recon, so.bin);
    const ProbeCalibration& view_calib = recon.calibration();  // of the (binned) views
    ScanRegistrar registrar(view_calib, so.tracker, so.anchor, so.recon.normal_max_gap_mm);
    LiveVolumeOptions live;
    live.voxel_mm = no_refuse ? 0.0 : live_voxel_mm;
    live.Check();
    ScanFuser fuser(view_calib.camera, live.Of(so.tsdf), so.free_space);
    // Burst `index` of the source, rendered or read (again, for the refusion pass).
    bool trace_truth = false;  // per-burst truth maps, for the trace's reconstruction figures
    auto load_burst = [&](int64_t index, Burst* b) -> Status {
      if (session) {
        *b = session->RenderBurst(index, trace_truth);
        return Status::Ok();
      }
      return ReadBurstDir(burst_dirs[static_cast<size_t>(index)], false, b);
    };
    auto frames_of = [&](const Burst& b) {
      std::vector<cv::Mat> frames;
      for (const BurstFrame& f : b.frames) frames.push_back(f.image);
      return frames;
    };
    // True pose at the burst's reference time (middle of the burst), when the source knows it.
    auto true_pose_of = [&](const Burst& b) {
      if (session) return session->trajectory().WorldFromProbe(b.reference_ns);
      if (b.frames.empty()) return Rigid3d::Identity();
      return InterpolateRigid(b.frames.front().truth.world_from_probe, b.frames.back().truth.world_from_probe, 0.5);
    };
    // The accepted views' frames as reconstructed (binned), kept for the end of the scan (refusion,
    // segments apart) instead of rendering or reading their bursts again: zstd, in an unnamed
    // temporary file in the output folder (memory when that cannot be made).
    ViewArchive kept;
    FramePacker packer;
    std::string packed;
    if (const Status s = kept.SpillTo(out_dir); !s.ok() && !quiet)
      std::fprintf(stderr, "d3d-fuse: keeping the views' frames in memory: %s\n", s.ToString().c_str());
    ProgressBar bar("d3d-fuse", static_cast<int64_t>(indices.size()), !quiet);
    ScanTimes times;
    double ms_render = 0;
    std::map<uint64_t, Rigid3d> true_poses;  // by burst index
    ReconstructedView view;
    std::ofstream trace;
    if (!trace_path.empty()) {
      trace.open(trace_path);
      trace << "# burst accepted state rmse_um overlap eigen_ratio correspondences keyframe loops err_mm err_deg"
               " view_rms_um view_order_error_pct tooth_valid_pct in_model reentry_keyframes reentry_agreeing"
               " reentry_seen_through prediction_offset_mm prediction_offset_deg\n";
      trace_truth = session != nullptr && !scene.faces.empty();
    }
    Rigid3d first_truth_from_est = Rigid3d::Identity();
    bool have_first = false;
    std::optional<SeenSurface> seen;
    if (coverage_ceiling && session && !scene.faces.empty())
      seen.emplace(scene, calib.depth_min_mm, calib.depth_max_mm, so.tsdf.max_incidence_deg);
    using ms = std::chrono::duration<double, std::milli>;
    // The coverage ceiling renders truth maps with the probe on this thread: no prefetching then.
    std::optional<BurstPrefetcher> prefetch;
    if (!seen) prefetch.emplace(indices, load_burst);
    for (size_t k = 0; k < indices.size(); ++k) {
      const auto t0 = std::chrono::steady_clock::now();
      Burst b;
      double ms_load = 0;
      if (const Status s = prefetch ? prefetch->Next(&b, &ms_load) : load_burst(indices[k], &b); !s.ok()) return Fail(s);
      const auto t1 = std::chrono::steady_clock::now();
      if (!prefetch) ms_load = ms(t1 - t0).count();
      if (const Status s = recon.Reconstruct(frames_of(b), &view); !s.ok()) return Fail(s);
      const auto t2 = std::chrono::steady_clock::now();
      const Rigid3d truth_pose = true_pose_of(b);
      true_poses[static_cast<uint64_t>(indices[k])] = truth_pose;
      if (seen) {
        if (b.reference_truth.has_maps()) {
          seen->Add(b.reference_truth);  // already rendered for the trace, at the same pose
        } else {
          FrameTruth seen_truth;
          session->probe().RenderTruth(truth_pose, &seen_truth);
          seen->Add(seen_truth);
        }
      }
      TrackResult r;
      if (truth_poses) {
        registrar.RegisterAtPose(static_cast<uint64_t>(indices[k]), b.reference_ns, truth_pose);
        r.accepted = true;
        r.state = TrackingState::kTracking;
        r.world_from_cam = truth_pose;
      } else {
        r = registrar.Register(view, static_cast<uint64_t>(indices[k]), b.reference_ns);
      }
      if (r.accepted && r.in_main)  // a segment apart is fused at the end, on its own or joined
        if (const Status s = fuser.Fuse(view, r.world_from_cam); !s.ok()) return Fail(s);
      if (r.accepted) {
        if (const Status s = packer.Pack(recon.frames_used(), &packed); !s.ok()) return Fail(s);
        // A failed spill write keeps the blob in memory: nothing is lost.
        (void)kept.Add(static_cast<uint64_t>(indices[k]), packed);
      }
      if (!quiet && (r.state != TrackingState::kTracking || !r.accepted))
        std::fprintf(stderr, "\nburst %lld: %s%s%s\n", static_cast<long long>(indices[k]), TrackingStateName(r.state),
                     r.reason.empty() ? "" : ": ", r.reason.c_str());
      if (trace.is_open()) {
        // Pose error against the truth, both frames tied at the first accepted view.
        double err_mm = NAN, err_deg = NAN;
        if (r.accepted && !have_first) {
          first_truth_from_est = truth_pose * r.world_from_cam.inverse();
          have_first = true;
        }
        // Accepted views, and the pose a refused re-entry was checked at.
        if (have_first && (r.accepted || r.reentry.keyframes > 0)) {
          const Rigid3d e = first_truth_from_est * r.world_from_cam;
          err_mm = TranslationDistanceMm(e, truth_pose);
          err_deg = RotationAngleRad(e, truth_pose) * 180 / M_PI;
        }
        // The view as registered (with any model-anchored parts) against the renderer's truth.
        CloudErrors ve;
        ve.rms_um = ve.order_error_pct = ve.tooth_valid_pct = NAN;
        if (trace_truth && b.reference_truth.has_maps())
          ve = EvaluateCloud(view.points_in_cam, view.unwrap.Phi, bin > 1 ? BinnedTruth(b.reference_truth, bin) : b.reference_truth,
                             scene, calib.pattern);
        char line[640];
        std::snprintf(line, sizeof line, "%lld %d %s %.2f %.3f %.5f %d %d %d %.4f %.4f %.2f %.4f %.1f %d %d %lld %lld %.4f %.4f\n",
                      static_cast<long long>(indices[k]), r.accepted ? 1 : 0, TrackingStateName(r.state), r.icp.rmse_mm * 1000,
                      r.icp.overlap, r.icp.eigen_ratio, r.icp.correspondences, r.new_keyframe ? 1 : 0, r.loops_added, err_mm,
                      err_deg, ve.rms_um, ve.order_error_pct, ve.tooth_valid_pct, r.in_model ? 1 : 0, r.reentry.keyframes,
                      static_cast<long long>(r.reentry.agreeing), static_cast<long long>(r.reentry.seen_through),
                      r.prediction_offset_mm, r.prediction_offset_deg);
        trace << line;
      }
      ms_render += ms_load;
      times.ms_recon += ms(t2 - t1).count();
      bar.Update(static_cast<int64_t>(k + 1));
    }
    bar.Finish();
    times.bursts = static_cast<int64_t>(indices.size());
    times.ms_register = registrar.ms_register();
    times.ms_fuse = fuser.ms_fuse();
    // Pose graph, refusion at the optimised poses (the kept frames reconstructed again: the same
    // views bit for bit), mesh, evaluation and report.
    ProgressBar bar2("d3d-fuse: pose graph, refusion, mesh, evaluation", 1, !quiet);
    const ScanViewProvider provider = KeptViewProvider(kept, view_calib, so.recon);
    ScanTruth truth;
    if (!no_eval && !scene.faces.empty()) truth.reference = &scene;
    const bool have_true_poses =
        session != nullptr || (!true_poses.empty() && true_poses.begin()->second.matrix() != Rigid3d::Identity().matrix());
    if (have_true_poses)
      truth.true_pose = [&](const ScanViewRecord& record, Rigid3d* world_from_cam) {
        const auto it = true_poses.find(record.burst_seq);
        if (it == true_poses.end()) return false;
        *world_from_cam = it->second;
        return true;
      };
    ScanResult result;
    if (const Status s = FinishScan(so, times, &registrar, &fuser, provider, truth, &result); !s.ok()) return Fail(s);
    bar2.Update(1);
    bar2.Finish();
    nlohmann::json& j = result.report;
    j["input"] = session ? sim_model : bursts_dir;
    j["trajectory"] = trajectory;
    j["seed"] = seed;
    j["every"] = every;
    j["profile"] = profile;
    j["bin"] = bin;
    j["truth_poses"] = truth_poses;
    j["ms_render_per_burst"] = ms_render / static_cast<double>(std::max<size_t>(indices.size(), 1));
    j["peak_rss_mib"] = PeakRssMiB();
    if (seen) j["coverage_seen_pct"] = seen->SeenToothAreaPct();
    if (const Status s = WriteScanOutputs(out_dir, result); !s.ok()) return Fail(s);
    if (have_true_poses) {
      std::vector<Rigid3d> acc_truth;
      for (const int64_t k : result.pose_views) acc_truth.push_back(true_poses.at(registrar.views()[static_cast<size_t>(k)].burst_seq));
      if (const Status s = WriteTumPoses((fs::path(out_dir) / "truth_poses.txt").string(), result.pose_t_ns, acc_truth); !s.ok())
        return Fail(s);
    }
    if (!graph_path.empty()) {
      if (const Status s = WritePoseGraph(graph_path, registrar, true_poses); !s.ok()) return Fail(s);
    }
    if (json) std::printf("%s\n", j.dump().c_str());
    else {
      nlohmann::json brief = j;
      brief.erase("events");
      std::printf("%s\n", brief.dump(2).c_str());
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-fuse: %s\n", e.what());
    return 2;
  }
  return 0;
}
