// d3d-bench-register: our registration and fusion side by side with Open3D's (Debian
// libopen3d-dev 0.16) on the same data, in one run:
//  1. Stanford bunny pairs from identity: initial alignment by SIFT on range images and by FPFH
//     (ours), each + ICP: pose error against bun.conf (deg, mm) and ms; a table on stderr.
//  2. ICP on the same pairs from the same initial pose: ours (combined metric, grid, k-d tree and
//     projective association, 1 and 2 threads) vs Open3D's point-to-plane ICP: ms and final error
//     (RMS displacement of the source points between the estimated and the true transform).
//  3. TSDF integration of the same virtual-probe views: ours (OpenVDB) vs Open3D's
//     ScalableTSDFVolume: ms per view.
// Speed is measured here, never in tests. Prints a table and, with --json, one JSON object.
#include <open3d/camera/PinholeCameraIntrinsic.h>
#include <open3d/geometry/Image.h>
#include <open3d/geometry/KDTreeSearchParam.h>
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/RGBDImage.h>
#include <open3d/pipelines/integration/ScalableTSDFVolume.h>
#include <open3d/pipelines/registration/CorrespondenceChecker.h>
#include <open3d/pipelines/registration/Feature.h>
#include <open3d/pipelines/registration/Registration.h>
#include <open3d/pipelines/registration/TransformationEstimation.h>
#include <open3d/utility/Logging.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>

#include "common/options/option_registry.h"
#include "pipeline/chain/scan_chain.h"
#include "pipeline/fuse/free_space.h"
#include "pipeline/fuse/tsdf.h"
#include "pipeline/recon/reconstruct.h"
#include "pipeline/register/pairwise.h"
#include "pipeline/register/range_grid_io.h"
#include "pipeline/register/tracker.h"
#include "sim/session/sim_session.h"

using namespace d3d;
namespace o3r = open3d::pipelines::registration;

namespace {

double Now() {
  return std::chrono::duration<double, std::milli>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

double PointRmsUm(const SurfacePoints& s, const Rigid3d& a, const Rigid3d& b) {
  double e = 0;
  for (const auto& p : s.points) e += (a * p.cast<double>() - b * p.cast<double>()).squaredNorm();
  return 1000 * std::sqrt(e / static_cast<double>(std::max<size_t>(1, s.size())));
}

open3d::geometry::PointCloud ToO3d(const SurfacePoints& s, bool normals) {
  open3d::geometry::PointCloud pc;
  for (size_t i = 0; i < s.size(); ++i) {
    pc.points_.push_back(s.points[i].cast<double>());
    if (normals) pc.normals_.push_back(s.normals[i].cast<double>());
  }
  return pc;
}

struct IcpCase {
  std::string name;
  SurfacePoints source, target;
  cv::Mat target_points, target_normals;  // organised (empty: no projective association)
  PinholeIntrinsics k;
  Rigid3d truth, init;
  IcpOptions ours;
  double o3d_max_distance_mm = 1.0;
};

nlohmann::json RunIcpCase(const IcpCase& c, int repeats) {
  nlohmann::json j;
  j["pair"] = c.name;
  j["source_points"] = c.source.size();
  j["target_points"] = c.target.size();
  j["initial_error_um"] = PointRmsUm(c.source, c.init, c.truth);
  enum class Assoc { kKdTree, kGrid, kProjective };
  std::vector<double> gates;
  for (const IcpLevel& l : c.ours.levels) gates.push_back(l.max_distance_mm);
  auto time_ours = [&](Assoc assoc, int threads) {
    IcpOptions o = c.ours;
    o.threads = threads;
    IcpResult r;
    double best = 1e30;
    for (int k = 0; k < repeats; ++k) {
      const double t0 = Now();
      if (assoc == Assoc::kProjective) {
        ProjectiveTarget t(c.target_points, c.target_normals, c.k, Rigid3d::Identity(), 1);
        r = RegisterIcp(c.source, t, c.init, o);
      } else if (assoc == Assoc::kGrid) {
        GridTarget t;
        t.Build(c.target, gates);
        r = RegisterIcp(c.source, t, c.init, o);
      } else {
        KdTreeTarget t(c.target);
        r = RegisterIcp(c.source, t, c.init, o);
      }
      best = std::min(best, Now() - t0);
    }
    return std::pair{r, best};
  };
  for (int threads : {1, 2}) {
    for (const auto& [assoc, name] :
         {std::pair{Assoc::kKdTree, "kdtree"}, std::pair{Assoc::kGrid, "grid"},
          std::pair{Assoc::kProjective, "projective"}}) {
      if (assoc == Assoc::kProjective && c.target_points.empty()) continue;
      const auto [r, ms] = time_ours(assoc, threads);
      j[std::string("ours_") + name + "_t" + std::to_string(threads)] = {
          {"ms", ms},
          {"error_um", PointRmsUm(c.source, r.target_from_source, c.truth)},
          {"ok", r.ok},
          {"iterations", r.iterations},
          {"rmse_um", r.rmse_mm * 1000}};
    }
  }
  const auto src = ToO3d(c.source, false), tgt = ToO3d(c.target, true);
  o3r::RegistrationResult res;
  double best = 1e30;
  for (int k = 0; k < repeats; ++k) {
    const double t0 = Now();
    res = o3r::RegistrationICP(src, tgt, c.o3d_max_distance_mm, c.init.matrix(),
                               o3r::TransformationEstimationPointToPlane(),
                               o3r::ICPConvergenceCriteria(1e-6, 1e-6, 30));
    best = std::min(best, Now() - t0);
  }
  Rigid3d T(res.transformation_);
  j["open3d_point_to_plane"] = {{"ms", best},
                                {"error_um", PointRmsUm(c.source, T, c.truth)},
                                {"fitness", res.fitness_},
                                {"rmse_um", res.inlier_rmse_ * 1000}};
  return j;
}

Rigid3d Perturb(const Rigid3d& T, double deg, double mm) {
  Rigid3d d = Rigid3d::Identity();
  d.linear() = Eigen::AngleAxisd(deg * M_PI / 180, Eigen::Vector3d(0.4, -0.7, 0.6).normalized())
                   .toRotationMatrix();
  d.translation() = Eigen::Vector3d(0.5, 0.3, -0.8).normalized() * mm;
  return d * T;
}

struct Options {
  std::string data = std::string(D3D_SHARED_DATA_DIR);
  int repeats = 3, tsdf_views = 20;
  bool json = false;
};

void DeclareOptions(OptionRegistry* r, Options* o) {
  r->Add("--data", &o->data, "../shared/data");
  r->Add("--repeats", &o->repeats, "timing repeats (best kept)");
  r->Add("--tsdf-views", &o->tsdf_views, "views fused in the TSDF comparison");
  r->Flag("--json", &o->json, "print one JSON object");
}

// Our pairwise registration of range grid S onto T from identity (initial alignment by `method`,
// then ICP): its error against `truth` and times, as JSON and as a line of the table on stderr.
nlohmann::json OursFromIdentity(const std::string& pair, const cv::Mat& S, const cv::Mat& T,
                                const Rigid3d& truth, InitialAlignment method) {
  const double t0 = Now();
  const PairwiseResult r =
      RegisterPair(S, cv::Mat(), T, cv::Mat(), RangeScanPairwiseOptions(method));
  const double ms = Now() - t0;
  nlohmann::json pj = {{"pair", pair},
                       {"method", ToString(method)},
                       {"ok", r.ok},
                       {"reason", r.reason},
                       {"feature_matches", r.initial.matches},
                       {"feature_inliers", r.initial.inliers},
                       {"ms_features", r.ms_features},
                       {"ms_icp", r.ms_icp},
                       {"ms_total", ms}};
  if (method == InitialAlignment::kFpfh)
    pj["fpfh_keypoints"] = {r.fpfh.source_keypoints, r.fpfh.target_keypoints};
  if (r.initial.ok) {
    pj["initial_error_deg"] = RotationAngleRad(r.initial.target_from_source, truth) * 180 / M_PI;
    pj["initial_error_mm"] = TranslationDistanceMm(r.initial.target_from_source, truth);
  }
  if (r.ok) {
    pj["error_deg"] = RotationAngleRad(r.target_from_source, truth) * 180 / M_PI;
    pj["error_mm"] = TranslationDistanceMm(r.target_from_source, truth);
  }
  std::fprintf(
      stderr,
      "%-16s %-12s %-3s %7.3f deg %7.3f mm  features %5.0f ms  icp %5.0f ms  total %5.0f ms  %s\n",
      pair.c_str(), ToString(method), r.ok ? "ok" : "no",
      r.ok ? pj["error_deg"].get<double>() : NAN, r.ok ? pj["error_mm"].get<double>() : NAN,
      r.ms_features, r.ms_icp, ms, r.reason.c_str());
  return pj;
}

// The reference: Open3D's FPFH + RANSAC at the voxel, radii and thresholds of our FPFH options `o`
// (initial alignment only), as JSON and as a line of the table on stderr.
nlohmann::json Open3dFpfhRansac(const std::string& pair, const cv::Mat& S, const cv::Mat& T,
                                const Rigid3d& truth, const PairwiseOptions& o) {
  const double t0 = Now();
  const double v = o.fpfh.voxel_mm;
  const auto sd = ToO3d(SampleOrganised(S, GridNormals(S, o.max_gap_mm), cv::Mat(), 1), true)
                      .VoxelDownSample(v);
  const auto td = ToO3d(SampleOrganised(T, GridNormals(T, o.max_gap_mm), cv::Mat(), 1), true)
                      .VoxelDownSample(v);
  const open3d::geometry::KDTreeSearchParamHybrid nparam(o.fpfh.normal_radius_mm, 30);
  sd->EstimateNormals(nparam, false);
  td->EstimateNormals(nparam, false);
  const open3d::geometry::KDTreeSearchParamHybrid fparam(o.fpfh.feature_radius_mm,
                                                         o.fpfh.max_neighbours);
  const auto fs = o3r::ComputeFPFHFeature(*sd, fparam), ft = o3r::ComputeFPFHFeature(*td, fparam);
  const o3r::CorrespondenceCheckerBasedOnEdgeLength edge(1 - o.fpfh.ransac.max_edge_ratio_error);
  const o3r::CorrespondenceCheckerBasedOnDistance dist(o.fpfh.ransac.inlier_threshold_mm);
  const auto res = o3r::RegistrationRANSACBasedOnFeatureMatching(
      *sd, *td, *fs, *ft, o.fpfh.mutual, o.fpfh.ransac.inlier_threshold_mm,
      o3r::TransformationEstimationPointToPoint(false), 3, {edge, dist},
      o3r::RANSACConvergenceCriteria(o.fpfh.ransac.max_iterations, o.fpfh.ransac.confidence));
  const double ms = Now() - t0;
  const Rigid3d T3(res.transformation_);
  const double deg = RotationAngleRad(T3, truth) * 180 / M_PI,
               mm = TranslationDistanceMm(T3, truth);
  std::fprintf(
      stderr,
      "%-16s %-12s     %7.3f deg %7.3f mm  features %5.0f ms  (initial alignment only, no ICP)\n",
      pair.c_str(), "open3d-fpfh", deg, mm, ms);
  return {{"pair", pair},
          {"method", "open3d-fpfh-ransac (initial only)"},
          {"fitness", res.fitness_},
          {"initial_error_deg", deg},
          {"initial_error_mm", mm},
          {"ms_features", ms}};
}

// 1. The Stanford bunny pairs from identity (ours by SIFT and by FPFH, Open3D's FPFH + RANSAC) into
// out["bunny_pairs_from_identity"], and each pair's ICP case from a perturbed truth (2.) into
// *cases. Nothing when the data set is not under `data`.
void CompareBunnyPairs(const std::string& data, nlohmann::json* out, std::vector<IcpCase>* cases) {
  const std::string dir = data + "/range_scans/stanford_bunny";
  if (!std::filesystem::exists(dir + "/bun.conf")) return;
  std::map<std::string, Rigid3d> conf;
  if (!LoadRangeScanPoses(dir + "/bun.conf", &conf).ok()) conf.clear();
  nlohmann::json pairs = nlohmann::json::array();
  for (auto [s, t] : std::vector<std::pair<std::string, std::string>>{{"bun045", "bun000"},
                                                                      {"bun315", "bun000"},
                                                                      {"bun090", "bun045"},
                                                                      {"bun270", "bun315"},
                                                                      {"bun180", "bun090"},
                                                                      {"bun180", "bun270"}}) {
    cv::Mat S, T;
    if (!LoadRangeGridPly(dir + "/" + s + ".ply", 1000, &S).ok() ||
        !LoadRangeGridPly(dir + "/" + t + ".ply", 1000, &T).ok())
      continue;
    const Rigid3d truth = conf.at(t).inverse() * conf.at(s);
    // Initial alignment by SIFT (range images) and by FPFH, each followed by the same ICP.
    for (InitialAlignment method : {InitialAlignment::kSift, InitialAlignment::kFpfh})
      pairs.push_back(OursFromIdentity(s + "->" + t, S, T, truth, method));
    const PairwiseOptions o = RangeScanPairwiseOptions(InitialAlignment::kFpfh);
    pairs.push_back(Open3dFpfhRansac(s + "->" + t, S, T, truth, o));
    IcpCase c;
    c.name = s + "->" + t;
    c.source = SampleOrganised(S, GridNormals(S, 2.0), cv::Mat(), 1);
    c.target = SampleOrganised(T, GridNormals(T, 2.0), cv::Mat(), 1);
    c.truth = truth;
    c.init = Perturb(truth, 3.0, 2.0);
    c.ours = o.icp;
    c.o3d_max_distance_mm = 5.0;
    cases->push_back(std::move(c));
  }
  (*out)["bunny_pairs_from_identity"] = pairs;
}

// `count` consecutive bursts of the virtual probe from burst 300 on, reconstructed, and their true
// poses. False when a reconstruction fails.
bool ReconstructViews(SimSession* session, int count, std::vector<ReconstructedView>* views,
                      std::vector<Rigid3d>* poses) {
  const ProbeCalibration& calib = session->calibration();
  Reconstructor recon(calib);
  const int64_t start = 300;
  for (int i = 0; i < count; ++i) {
    const Burst b = session->RenderBurst(start + i, false);
    std::vector<cv::Mat> imgs;
    for (int f = 0; f < calib.pattern.steps; ++f)
      imgs.push_back(b.frames[static_cast<size_t>(f)].image);
    ReconstructedView v;
    if (!recon.Reconstruct(imgs, &v).ok()) return false;
    views->push_back(v);
    poses->push_back(session->trajectory().WorldFromProbe(b.reference_ns));
  }
  return true;
}

// The ICP cases on the virtual probe's views: a burst pair from identity, and the tracker's
// frame-to-model ICP.
void AddVirtualProbeCases(const ProbeCalibration& calib,
                          const std::vector<ReconstructedView>& views,
                          const std::vector<Rigid3d>& poses, std::vector<IcpCase>* cases) {
  {  // Two bursts 1/30 s apart, every valid pixel (~140k source and ~130k target samples at 640 ×
     // 480).
    IcpCase c;
    c.name = "virtual-probe bursts 300->301";
    const SurfacePoints all =
        SampleOrganised(views[1].points_in_cam, views[1].normals, cv::Mat(), 1);
    c.source = all.Subsample(std::max<int>(1, static_cast<int>(all.size() / 100000)));
    c.target = SampleOrganised(views[0].points_in_cam, views[0].normals, cv::Mat(), 1);
    c.target_points = views[0].points_in_cam;
    c.target_normals = views[0].normals;
    c.k = {calib.camera.fx, calib.camera.fy,    calib.camera.cx,
           calib.camera.cy, calib.camera.width, calib.camera.height};
    c.truth = poses[0].inverse() * poses[1];
    c.init = Rigid3d::Identity();  // no motion prediction
    c.ours.levels = {{16, 12, 1.0, 0.7}, {4, 8, 0.3, 0.9}, {1, 6, 0.1, 1.0}};
    {  // stop as the tracker does (pipeline/register/odometry.h: DefaultTrackerIcp): same final
       // error here, 20 vs 25 iterations
      const IcpOptions tr = DefaultTrackerIcp();
      c.ours.min_delta_translation_mm = tr.min_delta_translation_mm;
      c.ours.min_delta_rotation_rad = tr.min_delta_rotation_rad;
      c.ours.min_relative_error_change = tr.min_relative_error_change;
    }
    c.o3d_max_distance_mm = 1.0;
    cases->push_back(std::move(c));
  }
  for (const double every : {1.0, 6.0}) {
    // The tracker's frame-to-model ICP (DefaultTrackerIcp, its sample caps in d3d-scan, the first
    // gate of TrackerOptionsForStep: 0.8 mm lossless, 1.96 mm for a live host's views 6 bursts
    // apart) on a model-like target (every 3rd pixel, ~the tracking model's 0.08 mm spacing),
    // started 0.3 mm / 0.5 deg off as from a motion prediction.
    const size_t to =
        static_cast<size_t>(std::min<double>(every, static_cast<double>(views.size() - 1)));
    IcpCase c;
    c.name = "virtual-probe bursts 300->" + std::to_string(300 + to) + ", tracker ICP";
    c.source = SampleOrganised(views[to].points_in_cam, views[to].normals, views[to].quality, 2);
    c.target = SampleOrganised(views[0].points_in_cam, views[0].normals, cv::Mat(), 3);
    c.truth = poses[0].inverse() * poses[to];
    c.init = Perturb(c.truth, 0.5, 0.3);
    c.ours = TrackerOptionsForStep(TrackerOptions{}, every).odometry.icp;
    for (auto [level, cap] : {std::pair{0, 1600}, std::pair{1, 4000}, std::pair{2, 8000}})
      c.ours.levels[static_cast<size_t>(level)].max_samples = cap;
    c.o3d_max_distance_mm = c.ours.levels[0].max_distance_mm;
    cases->push_back(std::move(c));
  }
}

// 3. TSDF integration of the views at their true poses, ours vs Open3D's ScalableTSDFVolume, into
// out["tsdf"]. False when ours refuses a view.
bool CompareTsdf(const ProbeCalibration& calib, const std::vector<ReconstructedView>& views,
                 const std::vector<Rigid3d>& poses, nlohmann::json* out) {
  TsdfOptions to;
  TsdfVolume ours(to);
  double t0 = Now();
  for (size_t i = 0; i < views.size(); ++i)
    if (!ours.Integrate(views[i].points_in_cam, views[i].normals, views[i].quality, calib.camera,
                        poses[i])
             .ok())
      return false;
  const double ours_ms = (Now() - t0) / static_cast<double>(views.size());
  t0 = Now();
  const TriangleMesh m = ours.ExtractMesh();
  const double ours_mesh_ms = Now() - t0;
  open3d::pipelines::integration::ScalableTSDFVolume o3d(
      to.voxel_mm, to.truncation_mm, open3d::pipelines::integration::TSDFVolumeColorType::NoColor,
      16, 4);
  const open3d::camera::PinholeCameraIntrinsic K(calib.camera.width, calib.camera.height,
                                                 calib.camera.fx, calib.camera.fy, calib.camera.cx,
                                                 calib.camera.cy);
  std::vector<std::shared_ptr<open3d::geometry::RGBDImage>> rgbd;
  for (const auto& v : views) {
    open3d::geometry::Image depth, colour;
    depth.Prepare(v.points_in_cam.cols, v.points_in_cam.rows, 1, 4);
    colour.Prepare(v.points_in_cam.cols, v.points_in_cam.rows, 3, 1);
    for (int r = 0; r < v.points_in_cam.rows; ++r)
      for (int c = 0; c < v.points_in_cam.cols; ++c) {
        const float z = v.points_in_cam.at<cv::Vec3f>(r, c)[2];
        *depth.PointerAt<float>(c, r) = std::isfinite(z) ? z : 0.0f;
      }
    rgbd.push_back(
        open3d::geometry::RGBDImage::CreateFromColorAndDepth(colour, depth, 1.0, 100.0, false));
  }
  t0 = Now();
  for (size_t i = 0; i < views.size(); ++i) o3d.Integrate(*rgbd[i], K, poses[i].inverse().matrix());
  const double o3d_ms = (Now() - t0) / static_cast<double>(views.size());
  t0 = Now();
  const auto om = o3d.ExtractTriangleMesh();
  const double o3d_mesh_ms = Now() - t0;
  (*out)["tsdf"] = {{"views", views.size()},
                    {"voxel_mm", to.voxel_mm},
                    {"ours_ms_per_view", ours_ms},
                    {"ours_mesh_ms", ours_mesh_ms},
                    {"ours_faces", m.faces.size()},
                    {"ours_memory_mib", static_cast<double>(ours.MemoryBytes()) / (1 << 20)},
                    {"open3d_ms_per_view", o3d_ms},
                    {"open3d_mesh_ms", o3d_mesh_ms},
                    {"open3d_faces", om->triangles_.size()}};
  return true;
}

// 4. The fusion's free-space test (pipeline/fuse/free_space.h), each view against the earlier
// ones (every view a reference, the nearest 6 tested): the cost it adds to a fused view, into
// out["free_space"].
void MeasureFreeSpace(const ProbeCalibration& calib, const std::vector<ReconstructedView>& views,
                      const std::vector<Rigid3d>& poses, nlohmann::json* out) {
  FreeSpaceOptions fo;
  fo.reference_every = 1;
  FreeSpaceTest test(calib.camera, fo);
  cv::Mat rejected;
  int64_t n = 0;
  const double t0 = Now();
  for (size_t i = 0; i < views.size(); ++i)
    n += test.TestAndRemember(views[i].points_in_cam, poses[i], &rejected);
  (*out)["free_space"] = {{"views", views.size()},
                          {"ms_per_view", (Now() - t0) / static_cast<double>(views.size())},
                          {"rejected_points", n}};
}

}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options(
      "d3d-bench-register: our ICP and TSDF vs Open3D's on the same data (bunny scans, "
      "virtual-probe views).");
  Options o;
  DeclareOptions(&options, &o);
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;
  nlohmann::json out;
  open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
  // 1. Bunny pairs from identity (features + ICP) and 2. ICP vs Open3D from a perturbed truth.
  std::vector<IcpCase> cases;
  CompareBunnyPairs(o.data, &out, &cases);
  SimSessionOptions so;
  std::unique_ptr<SimSession> session;
  if (!SimSession::Create(so, &session).ok()) return 1;
  const ProbeCalibration& calib = session->calibration();
  std::vector<ReconstructedView> views;
  std::vector<Rigid3d> poses;
  if (!ReconstructViews(session.get(), std::max(2, o.tsdf_views), &views, &poses)) return 1;
  AddVirtualProbeCases(calib, views, poses, &cases);
  nlohmann::json icp = nlohmann::json::array();
  for (const auto& c : cases) icp.push_back(RunIcpCase(c, o.repeats));
  out["icp_vs_open3d"] = icp;
  if (!CompareTsdf(calib, views, poses, &out)) return 1;
  MeasureFreeSpace(calib, views, poses, &out);
  std::printf("%s\n", o.json ? out.dump().c_str() : out.dump(2).c_str());
  return 0;
}
