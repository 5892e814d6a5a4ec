// d3d-fuse: the whole offline chain on the virtual probe or a folder of bursts:
// burst → reconstruction (pipeline/recon) → frame-to-model registration with loss detection and
// relocalisation (pipeline/register) → TSDF fusion (pipeline/fuse) → pose graph with loop
// closures → mesh (PLY, STL, mm) → evaluation against the scene (pipeline/eval) when it is known.
#include <sys/resource.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "common/burst/burst_io.h"
#include "common/core/progress.h"
#include "common/mesh/mesh_io.h"
#include "firmware/sim/session/sim_session.h"
#include "pipeline/eval/evaluate_scan.h"
#include "pipeline/fuse/tsdf.h"
#include "pipeline/recon/reconstruct.h"
#include "pipeline/register/tracker.h"
#include "pipeline/scan/scan_chain.h"

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

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"d3d-fuse: registers and fuses a scan into one mesh (mm) and evaluates it when the truth is known.\n"
               "Input: the virtual probe (--sim MODEL) or a folder of bursts written by d3d-sim (--bursts DIR).\n"
               "Output: DIR/scan.ply, DIR/scan.stl, DIR/poses.txt (TUM, mm), DIR/report.json, DIR/heatmap.png,\n"
               "DIR/truth_poses.txt (the true poses of the fused views, scene frame, when the source knows them)."};
  std::string sim_model, bursts_dir, trajectory = "full-arch", out_dir, association = "kdtree", trace_path;
  uint32_t seed = 1;
  int every = 1;
  int64_t max_bursts = -1, first = 0;
  double voxel_mm = 0.05, truncation_mm = 0.2;
  float min_mesh_weight = TsdfOptions{}.min_mesh_weight;
  double max_rmse_um = TrackerOptions{}.icp.max_rmse_mm * 1000;
  bool json = false, no_eval = false, no_loops = false, quiet = false, no_refuse = false, truth_poses = false;
  app.add_option("--sim", sim_model, "scan with the virtual probe: 'typodont' or a mesh file (PLY/STL/OBJ, mm)");
  app.add_option("--bursts", bursts_dir, "a d3d-sim output folder (calibration.json, bursts/NNNNNN/, scene.ply)");
  app.add_option("--trajectory", trajectory, "--sim: full-arch | quadrant | tooth | a TUM file")->capture_default_str();
  app.add_option("--seed", seed, "--sim: seed of hand motion and sensor noise")->capture_default_str();
  app.add_option("--out", out_dir, "output folder")->required();
  app.add_option("--every", every, "use every N-th burst (a lower burst rate, for quick runs)")->capture_default_str();
  app.add_option("--first", first, "first burst index")->capture_default_str();
  app.add_option("--max-bursts", max_bursts, "stop after this many bursts used (default: all)");
  app.add_option("--association", association, "ICP data association: kdtree (default: the more accurate) | projective")->capture_default_str();
  app.add_option("--voxel", voxel_mm, "TSDF voxel (mm)")->capture_default_str();
  app.add_option("--truncation", truncation_mm, "TSDF truncation (mm)")->capture_default_str();
  app.add_option("--max-rmse-um", max_rmse_um, "tracking: a view whose ICP residual (RMS, um) is above this is refused")
      ->capture_default_str();
  app.add_option("--min-mesh-weight", min_mesh_weight, "mesh only where the fused weight (sum of point qualities) is at least this")
      ->capture_default_str();
  app.add_flag("--no-eval", no_eval, "skip the evaluation against the scene");
  app.add_flag("--no-loops", no_loops, "no loop-closure detection / pose graph");
  app.add_flag("--quiet", quiet, "no progress bar");
  app.add_flag("--no-refuse", no_refuse,
               "keep the model fused at the tracked poses (default: when the pose graph moves a view by more than\n"
               "10 um, the accepted bursts are reconstructed again and fused at the optimised poses)");
  app.add_flag("--truth-poses", truth_poses,
               "debug: no registration; every view is fused at its true pose (from the virtual probe or the bursts'\n"
               "truth), which measures the fusion-only error floor");
  app.add_option("--trace", trace_path,
                 "debug: write one line per burst (burst, accepted, state, icp rmse um, overlap, eigen ratio,\n"
                 "correspondences, new keyframe, loops, true step error um / deg) to this file");
  app.add_flag("--json", json, "print report.json as one line on stdout");
  CLI11_PARSE(app, argc, argv);
  if (sim_model.empty() == bursts_dir.empty()) {
    std::fprintf(stderr, "d3d-fuse: give exactly one of --sim MODEL or --bursts DIR\n");
    return 2;
  }
  if (every < 1 || (association != "projective" && association != "kdtree")) {
    std::fprintf(stderr, "d3d-fuse: --every must be >= 1 and --association projective|kdtree\n");
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
    Reconstructor recon(calib);
    TrackerOptions to;
    to.association = association == "kdtree" ? Association::kKdTree : Association::kProjective;
    to.detect_loops = !no_loops;
    to.icp.max_rmse_mm = max_rmse_um / 1000.0;
    // A lower burst rate means larger steps between views.
    to.max_step_mm *= 1.0;
    to.icp.levels[0].max_distance_mm = std::min(3.0, 0.8 * std::sqrt(static_cast<double>(every)));
    Tracker tracker(calib.camera, to);
    TsdfOptions fo;
    fo.voxel_mm = voxel_mm;
    fo.truncation_mm = truncation_mm;
    fo.min_mesh_weight = min_mesh_weight;
    TsdfVolume tsdf(fo);
    ProgressBar bar("d3d-fuse", static_cast<int64_t>(indices.size()), !quiet);
    double ms_render = 0, ms_recon = 0, ms_register = 0, ms_fuse = 0;
    int64_t fused = 0, rejected = 0, lost_events = 0, relocalised = 0;
    std::vector<int64_t> t_ns;
    std::vector<Rigid3d> true_poses;
    std::vector<bool> accepted;
    nlohmann::json events = nlohmann::json::array();
    TrackingState prev_state = TrackingState::kInitialising;
    ReconstructedView view;
    std::ofstream trace;
    if (!trace_path.empty()) {
      trace.open(trace_path);
      trace << "# burst accepted state rmse_um overlap eigen_ratio correspondences keyframe loops err_mm err_deg\n";
    }
    Rigid3d first_truth_from_est = Rigid3d::Identity();
    bool have_first = false;
    for (size_t k = 0; k < indices.size(); ++k) {
      const auto t0 = std::chrono::steady_clock::now();
      Burst b;
      if (session) {
        b = session->RenderBurst(indices[k], false);
      } else if (const Status s = ReadBurstDir(burst_dirs[static_cast<size_t>(indices[k])], false, &b); !s.ok()) {
        return Fail(s);
      }
      const auto t1 = std::chrono::steady_clock::now();
      std::vector<cv::Mat> frames;
      for (int f = 0; f < calib.pattern.steps && f < static_cast<int>(b.frames.size()); ++f) frames.push_back(b.frames[static_cast<size_t>(f)].image);
      if (const Status s = recon.Reconstruct(frames, &view); !s.ok()) return Fail(s);
      const auto t2 = std::chrono::steady_clock::now();
      // True pose at the burst's reference time (middle of the burst), when the source knows it.
      Rigid3d truth_pose = Rigid3d::Identity();
      if (session) truth_pose = session->trajectory().WorldFromProbe(b.reference_ns);
      else if (!b.frames.empty())
        truth_pose = InterpolateRigid(b.frames.front().truth.world_from_probe, b.frames.back().truth.world_from_probe, 0.5);
      TrackResult r;
      if (truth_poses) {
        r.accepted = true;
        r.state = TrackingState::kTracking;
        r.world_from_cam = truth_pose;
      } else {
        r = tracker.Track(view.points_in_cam, view.normals, view.quality, view.texture);
      }
      const auto t3 = std::chrono::steady_clock::now();
      if (r.accepted) {
        if (const Status s = tsdf.Integrate(view.points_in_cam, view.normals, view.quality, calib.camera, r.world_from_cam); !s.ok())
          return Fail(s);
        ++fused;
      } else {
        ++rejected;
      }
      const auto t4 = std::chrono::steady_clock::now();
      if (r.state == TrackingState::kLost && prev_state != TrackingState::kLost) ++lost_events;
      if (r.state == TrackingState::kRelocalised) ++relocalised;
      if (r.state != TrackingState::kTracking || !r.accepted) {
        events.push_back({{"burst", indices[k]}, {"state", TrackingStateName(r.state)}, {"fused", r.accepted}, {"reason", r.reason}});
        if (!quiet) std::fprintf(stderr, "\nburst %lld: %s%s%s\n", static_cast<long long>(indices[k]), TrackingStateName(r.state),
                                 r.reason.empty() ? "" : ": ", r.reason.c_str());
      }
      prev_state = r.state;
      t_ns.push_back(b.reference_ns);
      true_poses.push_back(truth_pose);
      if (trace.is_open()) {
        // Pose error against the truth, both frames tied at the first accepted view.
        double err_mm = NAN, err_deg = NAN;
        if (r.accepted && !have_first) {
          first_truth_from_est = truth_pose * r.world_from_cam.inverse();
          have_first = true;
        }
        if (r.accepted) {
          const Rigid3d e = first_truth_from_est * r.world_from_cam;
          err_mm = TranslationDistanceMm(e, truth_pose);
          err_deg = RotationAngleRad(e, truth_pose) * 180 / M_PI;
        }
        char line[512];
        std::snprintf(line, sizeof line, "%lld %d %s %.2f %.3f %.5f %d %d %d %.4f %.4f\n", static_cast<long long>(indices[k]),
                      r.accepted ? 1 : 0, TrackingStateName(r.state), r.icp.rmse_mm * 1000, r.icp.overlap, r.icp.eigen_ratio,
                      r.icp.correspondences, r.new_keyframe ? 1 : 0, r.loops_added, err_mm, err_deg);
        trace << line;
      }
      accepted.push_back(r.accepted);
      using ms = std::chrono::duration<double, std::milli>;
      ms_render += ms(t1 - t0).count();
      ms_recon += ms(t2 - t1).count();
      ms_register += ms(t3 - t2).count();
      ms_fuse += ms(t4 - t3).count();
      bar.Update(static_cast<int64_t>(k + 1));
    }
    bar.Finish();
    // Pose graph: loop closures. The TSDF holds the views at their tracked poses; the correction
    // the graph finds is reported (a large one means the model has a step).
    PoseGraphSummary pg;
    double max_correction_mm = 0;
    std::vector<Rigid3d> tracked(indices.size(), Rigid3d::Identity());
    for (size_t k = 0; k < indices.size(); ++k) {
      if (truth_poses) tracked[k] = true_poses[k];
      else tracker.ViewPose(static_cast<int64_t>(k), &tracked[k]);
    }
    if (!truth_poses && !no_loops && tracker.graph().num_nodes() > 1) {
      if (const Status s = tracker.Optimize({}, &pg); !s.ok()) return Fail(s);
      for (size_t k = 0; k < indices.size(); ++k) {
        Rigid3d p;
        if (tracker.ViewPose(static_cast<int64_t>(k), &p)) max_correction_mm = std::max(max_correction_mm, TranslationDistanceMm(p, tracked[k]));
      }
    }
    // Second pass: the accepted bursts fused again at the optimised poses (offline path; the
    // bursts are rendered / read again rather than kept in memory).
    std::unique_ptr<TsdfVolume> refused;
    double ms_refuse = 0;
    if (!no_loops && !no_refuse && max_correction_mm > 0.01) {
      const auto tr0 = std::chrono::steady_clock::now();
      refused = std::make_unique<TsdfVolume>(fo);
      ProgressBar bar2("d3d-fuse: fusing at optimised poses", static_cast<int64_t>(indices.size()), !quiet);
      for (size_t k = 0; k < indices.size(); ++k) {
        Rigid3d pose;
        if (!tracker.ViewPose(static_cast<int64_t>(k), &pose)) continue;
        Burst b;
        if (session) b = session->RenderBurst(indices[k], false);
        else if (const Status s = ReadBurstDir(burst_dirs[static_cast<size_t>(indices[k])], false, &b); !s.ok()) return Fail(s);
        std::vector<cv::Mat> frames;
        for (int f = 0; f < calib.pattern.steps && f < static_cast<int>(b.frames.size()); ++f) frames.push_back(b.frames[static_cast<size_t>(f)].image);
        if (const Status s = recon.Reconstruct(frames, &view); !s.ok()) return Fail(s);
        if (const Status s = refused->Integrate(view.points_in_cam, view.normals, view.quality, calib.camera, pose); !s.ok()) return Fail(s);
        bar2.Update(static_cast<int64_t>(k + 1));
      }
      bar2.Finish();
      ms_refuse = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - tr0).count();
      for (size_t k = 0; k < indices.size(); ++k) tracker.ViewPose(static_cast<int64_t>(k), &tracked[k]);
    }
    const TsdfVolume& model = refused ? *refused : tsdf;
    const auto tm0 = std::chrono::steady_clock::now();
    TriangleMesh mesh = model.ExtractMesh();
    const double ms_mesh = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - tm0).count();
    if (mesh.faces.empty()) return Fail(Status(StatusCode::kInternal, "the fused model is empty (no view was accepted)"));
    mesh.ComputeVertexNormals();
    if (const Status s = SavePlyBinary((fs::path(out_dir) / "scan.ply").string(), mesh); !s.ok()) return Fail(s);
    if (const Status s = SaveStlBinary((fs::path(out_dir) / "scan.stl").string(), mesh); !s.ok()) return Fail(s);
    std::vector<int64_t> acc_t;
    std::vector<Rigid3d> acc_est, acc_truth;
    for (size_t k = 0; k < indices.size(); ++k) {
      if (!accepted[k]) continue;
      acc_t.push_back(t_ns[k]);
      acc_est.push_back(tracked[k]);
      acc_truth.push_back(true_poses[k]);
    }
    if (const Status s = WriteTumPoses((fs::path(out_dir) / "poses.txt").string(), acc_t, acc_est); !s.ok()) return Fail(s);
    if (acc_truth.size() == acc_est.size() && !acc_truth.empty() && acc_truth.front().matrix() != Rigid3d::Identity().matrix())
      if (const Status s = WriteTumPoses((fs::path(out_dir) / "truth_poses.txt").string(), acc_t, acc_truth); !s.ok()) return Fail(s);
    const double n = static_cast<double>(indices.size());
    nlohmann::json j;
    j["input"] = session ? sim_model : bursts_dir;
    j["trajectory"] = trajectory;
    j["seed"] = seed;
    j["every"] = every;
    j["truth_poses"] = truth_poses;
    j["bursts"] = indices.size();
    j["fused"] = fused;
    j["rejected"] = rejected;
    j["tracking_lost"] = lost_events;
    j["relocalised"] = relocalised;
    j["unrecovered"] = tracker.state() == TrackingState::kLost ? 1 : 0;
    j["final_state"] = TrackingStateName(tracker.state());
    j["keyframes"] = tracker.keyframes().size();
    j["loop_edges"] = tracker.loop_edges();
    j["pose_graph_max_correction_mm"] = max_correction_mm;
    j["pose_graph_disagreeing_edges"] = pg.disagreeing_edges.size();
    j["ms_per_burst"] = (ms_recon + ms_register + ms_fuse) / n;
    j["ms_render_per_burst"] = ms_render / n;
    j["ms_recon_per_burst"] = ms_recon / n;
    j["ms_register_per_burst"] = ms_register / n;
    j["ms_fuse_per_burst"] = ms_fuse / n;
    j["ms_mesh"] = ms_mesh;
    j["voxel_mm"] = voxel_mm;
    j["refused_at_optimised_poses"] = refused != nullptr;
    j["ms_refuse_total"] = ms_refuse;
    j["tsdf_active_voxels"] = model.ActiveVoxels();
    j["tsdf_memory_mib"] = static_cast<double>(tsdf.MemoryBytes() + (refused ? refused->MemoryBytes() : 0)) / (1024.0 * 1024.0);
    j["peak_rss_mib"] = PeakRssMiB();
    j["mesh_vertices"] = mesh.vertices.size();
    j["mesh_faces"] = mesh.faces.size();
    j["events"] = events;
    const bool have_truth = !scene.faces.empty() && !acc_est.empty() && acc_truth.front().matrix() != Rigid3d::Identity().matrix();
    if (have_truth && !no_eval) {
      cv::Mat heatmap;
      EvaluateScanAgainstScene(mesh, scene, acc_est, acc_truth, EvaluateOptions{}, &j, &heatmap);
      cv::imwrite((fs::path(out_dir) / "heatmap.png").string(), heatmap);
    }
    std::ofstream(fs::path(out_dir) / "report.json") << j.dump(2) << "\n";
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
