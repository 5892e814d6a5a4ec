#include "tools/fuse/offline_scan.h"

#include <tbb/concurrent_queue.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <thread>

#include "common/burst/burst_io.h"
#include "common/core/process_stats.h"
#include "common/core/progress.h"
#include "common/mesh/mesh_io.h"
#include "common/pack/frame_pack.h"
#include "pipeline/recon/evaluate.h"
#include "tools/d3d/report_head.h"

namespace fs = std::filesystem;

namespace d3d {
namespace {

using Ms = std::chrono::duration<double, std::milli>;

void PrintPose(std::FILE* f, const Rigid3d& p) { std::fprintf(f, " %s", TumPoseFields(p).c_str()); }

// --pose-graph: the keyframes' nodes (their pose in the graph: optimised, or the tracked one when
// the graph was not optimised (--no-loops); and the true one when known) and every edge
// with its measurement and information, for offline study of what bends the arch.
Status WritePoseGraph(const std::string& path, const ScanRegistrar& registrar,
                      const std::map<uint64_t, Rigid3d>& true_poses) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) return IoError("cannot write '" + path + "'");
  std::fprintf(
      f,
      "# node <node> <view> <burst> <graph t q> [<true t q>]\n"
      "# edge <from> <to> <loop> <measured from_from_to t q> <information 6x6 row-major>\n");
  const Tracker& tracker = registrar.tracker();
  for (const Keyframe& kf : tracker.keyframes()) {
    const uint64_t burst = registrar.views()[static_cast<size_t>(kf.view)].burst_seq;
    std::fprintf(f, "node %d %lld %llu", kf.node, static_cast<long long>(kf.view),
                 static_cast<unsigned long long>(burst));
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
          item.status = Status(StatusCode::kInternal, std::string("loading burst ") +
                                                          std::to_string(index) + ": " + e.what());
        }
        item.ms = Ms(std::chrono::steady_clock::now() - t0).count();
        const bool failed = !item.status.ok();
        while (!stop_.load() && !queue_.try_push(std::move(item)))
          std::this_thread::sleep_for(std::chrono::microseconds(200));
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

// --trace: one line per burst, the registration's figures and, with the truth, the pose error
// (both frames tied at the first accepted view) and the registered view's error.
class BurstTrace {
 public:
  // Opens `path` (nothing when empty); `with_truth`: the views' truth maps are rendered for it.
  BurstTrace(const std::string& path, bool with_truth) : with_truth_(with_truth) {
    if (path.empty()) return;
    out_.open(path);
    out_ << "# burst accepted state rmse_um overlap eigen_ratio correspondences keyframe loops "
            "err_mm err_deg"
            " view_rms_um view_order_error_pct tooth_valid_pct in_model reentry_keyframes "
            "reentry_agreeing"
            " reentry_seen_through prediction_offset_mm prediction_offset_deg loop_shift_mm\n";
  }
  bool open() const { return out_.is_open(); }
  bool with_truth() const { return open() && with_truth_; }

  void Write(int64_t index, const TrackResult& r, const Rigid3d& truth_pose, const Burst& b,
             const ReconstructedView& view, const TriangleMesh& scene,
             const ProbeCalibration& calib, int bin) {
    double err_mm = NAN, err_deg = NAN;
    if (r.accepted && !have_first_) {
      first_truth_from_est_ = truth_pose * r.world_from_cam.inverse();
      have_first_ = true;
    }
    // Accepted views, and the pose a refused re-entry was checked at.
    if (have_first_ && (r.accepted || r.reentry.keyframes > 0)) {
      const Rigid3d e = first_truth_from_est_ * r.world_from_cam;
      err_mm = TranslationDistanceMm(e, truth_pose);
      err_deg = RotationAngleRad(e, truth_pose) * 180 / M_PI;
    }
    // The view as registered (with any model-anchored parts) against the renderer's truth.
    CloudErrors ve;
    ve.rms_um = ve.order_error_pct = ve.tooth_valid_pct = NAN;
    if (with_truth() && b.reference_truth.has_maps())
      ve = EvaluateCloud(view.points_in_cam, view.unwrap.Phi,
                         bin > 1 ? BinnedTruth(b.reference_truth, bin) : b.reference_truth, scene,
                         calib.pattern);
    char line[640];
    std::snprintf(line, sizeof line,
                  "%lld %d %s %.2f %.3f %.5f %d %d %d %.4f %.4f %.2f %.4f %.1f %d %d %lld %lld "
                  "%.4f %.4f %.4f\n",
                  static_cast<long long>(index), r.accepted ? 1 : 0, TrackingStateName(r.state),
                  r.icp.rmse_mm * 1000, r.icp.overlap, r.icp.eigen_ratio, r.icp.correspondences,
                  r.new_keyframe ? 1 : 0, r.loops_added, err_mm, err_deg, ve.rms_um,
                  ve.order_error_pct, ve.tooth_valid_pct, r.in_model ? 1 : 0, r.reentry.keyframes,
                  static_cast<long long>(r.reentry.agreeing),
                  static_cast<long long>(r.reentry.seen_through), r.prediction_offset_mm,
                  r.prediction_offset_deg, r.loop_shift_mm);
    out_ << line;
  }

 private:
  std::ofstream out_;
  bool with_truth_ = false;
  Rigid3d first_truth_from_est_ = Rigid3d::Identity();
  bool have_first_ = false;
};

std::vector<cv::Mat> FramesOf(const Burst& b) {
  std::vector<cv::Mat> frames;
  for (const BurstFrame& f : b.frames) frames.push_back(f.image);
  return frames;
}

}  // namespace

Status OfflineSource::Open(const OfflineScanArgs& args, OfflineSource* out) {
  int64_t n_total = 0;
  if (!args.sim_model.empty()) {
    SimSessionOptions so;
    so.model = args.sim_model;
    so.trajectory = args.trajectory;
    so.seed = args.seed;
    D3D_RETURN_IF_ERROR(SimSession::Create(so, &out->session));
    out->calibration = out->session->calibration();
    out->scene = out->session->scene();
    n_total = out->session->NumBursts();
  } else {
    D3D_RETURN_IF_ERROR(ProbeCalibration::Load(
        (fs::path(args.bursts_dir) / "calibration.json").string(), &out->calibration));
    for (const auto& e : fs::directory_iterator(fs::path(args.bursts_dir) / "bursts"))
      if (e.is_directory()) out->burst_dirs.push_back(e.path().string());
    std::sort(out->burst_dirs.begin(), out->burst_dirs.end());
    n_total = static_cast<int64_t>(out->burst_dirs.size());
    const fs::path scene_path = fs::path(args.bursts_dir) / "scene.ply";
    if (fs::exists(scene_path) && !LoadMesh(scene_path.string(), &out->scene).ok())
      out->scene = TriangleMesh{};
    if (!out->scene.face_colors.empty() && out->scene.face_labels.empty())
      LabelFacesFromColors(&out->scene);
  }
  for (int64_t i = args.first; i < n_total; i += args.every) {
    if (args.max_bursts >= 0 && static_cast<int64_t>(out->indices.size()) >= args.max_bursts) break;
    out->indices.push_back(i);
  }
  return Status::Ok();
}

Status OfflineSource::Load(int64_t index, bool with_truth, Burst* out) const {
  if (session) {
    *out = session->RenderBurst(index, with_truth);
    return Status::Ok();
  }
  return ReadBurstDir(burst_dirs[static_cast<size_t>(index)], false, out);
}

Rigid3d OfflineSource::TruePose(const Burst& b) const {
  if (session) return session->trajectory().WorldFromProbe(b.reference_ns);
  if (b.frames.empty()) return Rigid3d::Identity();
  return InterpolateRigid(b.frames.front().truth.world_from_probe,
                          b.frames.back().truth.world_from_probe, 0.5);
}

Status RunOfflineScan(const OfflineScanArgs& args, const OfflineSource& source,
                      const ScanFlags& flags, const ScanOptions& so, ScanResult* result) {
  const ProbeCalibration& calib = source.calibration;
  const TriangleMesh& scene = source.scene;
  const std::vector<int64_t>& indices = source.indices;
  ScanReconstructor recon(calib, so.recon, so.bin);
  const ProbeCalibration& view_calib = recon.calibration();  // of the (binned) views
  ScanRegistrar registrar(view_calib, so.tracker, so.anchor, so.recon.normal_max_gap_mm);
  LiveVolumeOptions live;
  live.voxel_mm =
      flags.refuse ? flags.live_voxel_mm : 0.0;  // without refusion the live volume is the model
  live.Check();
  ScanFuser fuser(view_calib.camera, live.Of(so.tsdf), so.free_space);
  BurstTrace trace(args.trace_path, source.session != nullptr && !scene.faces.empty());
  // Burst `index` of the source, rendered or read (with truth maps for the trace's figures).
  const auto load_burst = [&](int64_t index, Burst* b) {
    return source.Load(index, trace.with_truth(), b);
  };
  // The accepted views' frames as reconstructed (binned), kept for the end of the scan (refusion,
  // segments apart) instead of rendering or reading their bursts again: zstd, in an unnamed
  // temporary file in the output folder (memory when that cannot be made).
  ViewArchive kept;
  FramePacker packer;
  std::string packed;
  if (const Status s = kept.SpillTo(args.out_dir); !s.ok() && !args.quiet)
    std::fprintf(stderr, "d3d-fuse: keeping the views' frames in memory: %s\n",
                 s.ToString().c_str());
  ProgressBar bar("d3d-fuse", static_cast<int64_t>(indices.size()), !args.quiet);
  ScanTimes times;
  double ms_render = 0;
  std::map<uint64_t, Rigid3d> true_poses;  // by burst index
  ReconstructedView view;
  std::optional<SeenSurface> seen;
  if (args.coverage_ceiling && source.session && !scene.faces.empty())
    seen.emplace(scene, calib.depth_min_mm, calib.depth_max_mm, so.tsdf.max_incidence_deg);
  // The coverage ceiling renders truth maps with the probe on this thread: no prefetching then.
  std::optional<BurstPrefetcher> prefetch;
  if (!seen) prefetch.emplace(indices, load_burst);
  for (size_t k = 0; k < indices.size(); ++k) {
    const auto t0 = std::chrono::steady_clock::now();
    Burst b;
    double ms_load = 0;
    D3D_RETURN_IF_ERROR(prefetch ? prefetch->Next(&b, &ms_load) : load_burst(indices[k], &b));
    const auto t1 = std::chrono::steady_clock::now();
    if (!prefetch) ms_load = Ms(t1 - t0).count();
    D3D_RETURN_IF_ERROR(recon.Reconstruct(FramesOf(b), &view));
    const auto t2 = std::chrono::steady_clock::now();
    const Rigid3d truth_pose = source.TruePose(b);
    true_poses[static_cast<uint64_t>(indices[k])] = truth_pose;
    if (seen) {
      if (b.reference_truth.has_maps()) {
        seen->Add(b.reference_truth);  // already rendered for the trace, at the same pose
      } else {
        FrameTruth seen_truth;
        source.session->probe().RenderTruth(truth_pose, &seen_truth);
        seen->Add(seen_truth);
      }
    }
    TrackResult r;
    if (args.truth_poses) {
      registrar.RegisterAtPose(static_cast<uint64_t>(indices[k]), b.reference_ns, truth_pose);
      r.accepted = true;
      r.state = TrackingState::kTracking;
      r.world_from_cam = truth_pose;
    } else {
      r = registrar.Register(view, static_cast<uint64_t>(indices[k]), b.reference_ns);
    }
    if (r.accepted && r.in_main)  // a segment apart is fused at the end, on its own or joined
      D3D_RETURN_IF_ERROR(fuser.Fuse(view, r.world_from_cam));
    if (r.accepted) {
      D3D_RETURN_IF_ERROR(packer.Pack(recon.frames_used(), &packed));
      // A failed spill write keeps the blob in memory: nothing is lost.
      (void)kept.Add(static_cast<uint64_t>(indices[k]), packed);
    }
    if (!args.quiet && (r.state != TrackingState::kTracking || !r.accepted))
      std::fprintf(stderr, "\nburst %lld: %s%s%s\n", static_cast<long long>(indices[k]),
                   TrackingStateName(r.state), r.reason.empty() ? "" : ": ", r.reason.c_str());
    if (trace.open()) trace.Write(indices[k], r, truth_pose, b, view, scene, calib, so.bin);
    ms_render += ms_load;
    times.ms_recon += Ms(t2 - t1).count();
    bar.Update(static_cast<int64_t>(k + 1));
  }
  bar.Finish();
  times.bursts = static_cast<int64_t>(indices.size());
  times.ms_register = registrar.ms_register();
  times.ms_fuse = fuser.ms_fuse();
  // Pose graph, refusion at the optimised poses (the kept frames reconstructed again: the same
  // views bit for bit), mesh, evaluation and report.
  ProgressBar bar2("d3d-fuse: pose graph, refusion, mesh, evaluation", 1, !args.quiet);
  const ScanViewProvider provider = KeptViewProvider(kept, view_calib, so.recon);
  ScanTruth truth;
  if (!args.no_eval && !scene.faces.empty()) truth.reference = &scene;
  const bool have_true_poses =
      source.session != nullptr ||
      (!true_poses.empty() && true_poses.begin()->second.matrix() != Rigid3d::Identity().matrix());
  if (have_true_poses)
    truth.true_pose = [&](const ScanViewRecord& record, Rigid3d* world_from_cam) {
      const auto it = true_poses.find(record.burst_seq);
      if (it == true_poses.end()) return false;
      *world_from_cam = it->second;
      return true;
    };
  D3D_RETURN_IF_ERROR(FinishScan(so, times, &registrar, &fuser, provider, truth, result));
  bar2.Update(1);
  bar2.Finish();
  nlohmann::json& j = result->report;
  ReportHead head = ToolReportHead("d3d-fuse");
  // What trueness and coverage were measured against: the virtual probe's scene, or the burst
  // folder's scene.ply (d3d-sim writes it).
  if (!scene.faces.empty())
    head.reference = source.session ? "the virtual probe's scene: " + args.sim_model
                                    : (fs::path(args.bursts_dir) / "scene.ply").string();
  AddReportHead(head, &j);
  j["input"] = source.session ? args.sim_model : args.bursts_dir;
  j["trajectory"] = args.trajectory;
  j["seed"] = args.seed;
  j["every"] = args.every;
  j["profile"] = flags.profile;
  j["bin"] = flags.bin;
  j["truth_poses"] = args.truth_poses;
  j["ms_render_per_burst"] = ms_render / static_cast<double>(std::max<size_t>(indices.size(), 1));
  j["peak_rss_mib"] = PeakRssMiB();
  if (seen) j["coverage_seen_pct"] = seen->SeenToothAreaPct();
  D3D_RETURN_IF_ERROR(WriteScanOutputs(args.out_dir, *result));
  if (have_true_poses) {
    std::vector<Rigid3d> acc_truth;
    for (const int64_t k : result->pose_views)
      acc_truth.push_back(true_poses.at(registrar.views()[static_cast<size_t>(k)].burst_seq));
    D3D_RETURN_IF_ERROR(WriteTumPoses((fs::path(args.out_dir) / "truth_poses.txt").string(),
                                      result->pose_t_ns, acc_truth));
  }
  if (!args.graph_path.empty())
    D3D_RETURN_IF_ERROR(WritePoseGraph(args.graph_path, registrar, true_poses));
  return Status::Ok();
}

}  // namespace d3d
