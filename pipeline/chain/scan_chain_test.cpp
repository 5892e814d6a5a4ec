// The scan chain's pieces on a short virtual-probe scan (reconstruction → frame-to-model
// registration → TSDF fusion → mesh → evaluation against the scene): accurate, the report carries
// issue 5's fields, the evaluation runs with true poses and with the global best fit, and the
// outputs are written.
#include "pipeline/chain/scan_chain.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "common/mesh/mesh_io.h"
#include "pipeline/chain/view_archive.h"
#include "pipeline/register/test_surfaces.h"
#include "sim/render/probe_design.h"
#include "sim/session/sim_session.h"

namespace d3d {
namespace {

// The quadrant path's bursts 30, 32, ..., 58 through the pieces, views binned `bin` × `bin`.
struct ShortScan {
  ScanOptions o;
  ProbeCalibration view_calibration;  // of the reconstructed views
  std::unique_ptr<ScanRegistrar> reg;
  std::unique_ptr<ScanFuser> fuser;
  ScanTimes times;
  double live_voxel_mm = 0;  // > 0: the fuser's voxel (a host's coarse live volume), else o.tsdf's
};

std::unique_ptr<SimSession> QuadrantSession() {
  SimSessionOptions so;
  so.model = "typodont";
  so.trajectory = "quadrant";
  so.seed = 3;
  std::unique_ptr<SimSession> session;
  if (!SimSession::Create(so, &session).ok()) return nullptr;
  return session;
}

// undo_after > 0: after that many views, UndoLastSeconds(undo_seconds) (result in *undo), and
// then the bursts `after_undo` (the probe went back over the model).
void RunShortScan(SimSession& session, int bin, ShortScan* s, ViewArchive* kept = nullptr,
                  int undo_after = 0, double undo_seconds = 0,
                  ScanRegistrar::UndoResult* undo = nullptr,
                  const std::vector<int64_t>& after_undo = {}) {
  ScanOptions o;
  o.tracker = TrackerOptionsForStep(o.tracker, 2);
  o.tracker.odometry.map.undo_inserts = undo_after > 0 ? 30 : 0;
  s->o = ScanOptionsForBin(o, bin);
  ASSERT_NO_THROW(s->o.Check());
  ScanReconstructor recon(session.calibration(), s->o.recon, s->o.bin);
  s->view_calibration = recon.calibration();
  s->reg = std::make_unique<ScanRegistrar>(s->view_calibration.camera, s->o.tracker);
  TsdfOptions live = s->o.tsdf;
  if (s->live_voxel_mm > 0) live.voxel_mm = s->live_voxel_mm;
  s->fuser = std::make_unique<ScanFuser>(s->view_calibration.camera, live);
  ReconstructedView view;
  FramePacker packer;
  std::vector<int64_t> bursts;
  for (int64_t i = 30; i < (undo_after > 0 ? 30 + 2 * undo_after : 60); i += 2) bursts.push_back(i);
  bursts.insert(bursts.end(), after_undo.begin(), after_undo.end());
  for (const int64_t i : bursts) {
    const Burst b = session.RenderBurst(i, false);
    std::vector<cv::Mat> frames;
    for (const auto& f : b.frames) frames.push_back(f.image);
    ASSERT_TRUE(recon.Reconstruct(frames, &view).ok());
    ASSERT_EQ(view.points_in_cam.cols, session.calibration().camera.width / bin);
    if (kept != nullptr) {
      std::string blob;
      ASSERT_TRUE(packer.Pack(recon.frames_used(), &blob).ok());
      ASSERT_TRUE(kept->Add(static_cast<uint64_t>(i), blob).ok());
    }
    const TrackResult r = s->reg->Register(view, static_cast<uint64_t>(i), b.reference_ns);
    if (r.accepted) {
      ASSERT_TRUE(s->fuser->Fuse(view, r.world_from_cam).ok());
    }
    s->times.ms_recon += view.ms_total;
    ++s->times.bursts;
    if (undo_after > 0 && s->times.bursts == undo_after)
      *undo = s->reg->UndoLastSeconds(undo_seconds);
  }
  s->times.ms_register = s->reg->ms_register();
  s->times.ms_fuse = s->fuser->ms_fuse();
}

// The kept views of `scan` (all accepted ones but `skip`), one thread, in order, at their final
// poses, fused at the scan's options and cleaned as FinishScan cleans its model: what a refusion
// must give.
TriangleMesh FusedAtFinalPoses(const ShortScan& scan, const ViewArchive& kept, int64_t skip = -1) {
  ScanReconstructor again(scan.view_calibration, scan.o.recon, 1);
  ScanFuser reference(scan.view_calibration.camera, scan.o.tsdf, scan.o.free_space);
  std::vector<cv::Mat> frames;
  ReconstructedView view;
  for (int64_t k = 0; k < static_cast<int64_t>(scan.reg->views().size()); ++k) {
    Rigid3d pose;
    if (k == skip || !scan.reg->ViewPose(k, &pose)) continue;
    EXPECT_TRUE(kept.Get(scan.reg->views()[static_cast<size_t>(k)].burst_seq, &frames).ok());
    EXPECT_TRUE(again.Reconstruct(frames, &view).ok());
    EXPECT_TRUE(reference.Fuse(view, pose).ok());
  }
  TriangleMesh mesh = reference.volume().ExtractMesh();
  CleanMesh(scan.o.mesh_clean, &mesh);
  return mesh;
}

ScanTruth TruthOf(SimSession* session) {
  ScanTruth truth;
  truth.reference = &session->scene();
  truth.true_pose = [session](const ScanViewRecord& v, Rigid3d* p) {
    *p = session->trajectory().WorldFromProbe(v.reference_ns);
    return true;
  };
  return truth;
}

TEST(ScanChain, ShortScanThroughThePiecesGivesAReport) {
  std::unique_ptr<SimSession> session = QuadrantSession();
  ASSERT_TRUE(session);
  ShortScan scan;
  RunShortScan(*session, 1, &scan);
  ASSERT_FALSE(HasFatalFailure());
  const ScanOptions& o = scan.o;
  ScanRegistrar& reg = *scan.reg;
  ScanFuser& fuser = *scan.fuser;
  const ScanTimes& times = scan.times;
  EXPECT_EQ(reg.views().size(), 15u);
  EXPECT_GE(reg.accepted(), 12);
  EXPECT_EQ(fuser.fused(), reg.accepted());
  const ScanTruth truth = TruthOf(session.get());
  ScanResult with_poses;
  ASSERT_TRUE(FinishScan(o, times, &reg, &fuser, {}, truth, &with_poses).ok());
  const nlohmann::json& j = with_poses.report;
  for (const char* k :
       {"bursts", "fused", "rejected", "tracking_lost", "trueness_rms_um", "trueness_mean_um",
        "trueness_p95_um", "coverage_pct", "ate_mm", "ate_deg", "ms_per_burst"})
    EXPECT_TRUE(j.contains(k)) << k;
  EXPECT_EQ(j["bursts"], 15);
  EXPECT_LT(j["trueness_rms_um"].get<double>(), 20.0);
  EXPECT_LT(j["trueness_p95_um"].get<double>(), 45.0);
  EXPECT_LT(j["trueness_outlier_pct"].get<double>(), 2.0);
  EXPECT_GT(j["mesh_faces"].get<double>(), 10000);
  EXPECT_LT(j["ate_mm"].get<double>(), 0.1);
  EXPECT_GT(j["ms_per_burst"].get<double>(), 0.0);
  EXPECT_EQ(with_poses.poses.size(), static_cast<size_t>(reg.accepted()));

  // Without the poses: the best fit starts from the global alignment (principal axes), which a
  // short partial scan cannot pin down: only the path is checked here.
  ScanTruth no_poses;
  no_poses.reference = &session->scene();
  ScanResult global;
  ASSERT_TRUE(FinishScan(o, times, &reg, &fuser, {}, no_poses, &global).ok());
  EXPECT_EQ(global.report["best_fit_start"], "global_align");
  EXPECT_FALSE(global.report.contains("ate_mm"));
  EXPECT_TRUE(global.report.contains("trueness_rms_um"));

  const std::string dir = (std::filesystem::temp_directory_path() / "d3d_scan_chain_test").string();
  std::filesystem::remove_all(dir);
  ASSERT_TRUE(WriteScanOutputs(dir, with_poses).ok());
  for (const char* f : {"scan.ply", "scan.stl", "poses.txt", "report.json", "heatmap.png"})
    EXPECT_TRUE(std::filesystem::exists(std::filesystem::path(dir) / f)) << f;
  TriangleMesh back;
  ASSERT_TRUE(LoadMesh(dir + "/scan.ply", &back).ok());
  EXPECT_EQ(back.faces.size(), with_poses.mesh.faces.size());
  std::filesystem::remove_all(dir);
}

// The same scan from 2×2-binned frames (d3d-scan's default): views of 320 × 240 with the binned
// calibration, as many accepted, the model as true.
TEST(ScanChain, ABinnedScanIsAsTrue) {
  std::unique_ptr<SimSession> session = QuadrantSession();
  ASSERT_TRUE(session);
  ShortScan scan;
  RunShortScan(*session, 2, &scan);
  ASSERT_FALSE(HasFatalFailure());
  EXPECT_EQ(scan.view_calibration.camera.width, 320);
  EXPECT_DOUBLE_EQ(scan.view_calibration.camera.fx, session->calibration().camera.fx / 2);
  EXPECT_GE(scan.reg->accepted(), 12);
  ScanResult r;
  ASSERT_TRUE(FinishScan(scan.o, scan.times, scan.reg.get(), scan.fuser.get(), {},
                         TruthOf(session.get()), &r)
                  .ok());
  std::printf(
      "[ binned   ] accepted %lld of 15, trueness %.2f um RMS, p95 %.2f, ATE %.3f mm, %.1f ms per "
      "burst\n",
      static_cast<long long>(scan.reg->accepted()), r.report["trueness_rms_um"].get<double>(),
      r.report["trueness_p95_um"].get<double>(), r.report["ate_mm"].get<double>(),
      r.report["ms_per_burst"].get<double>());
  EXPECT_LT(r.report["trueness_rms_um"].get<double>(), 20.0);
  EXPECT_LT(r.report["trueness_p95_um"].get<double>(), 45.0);
  EXPECT_LT(r.report["ate_mm"].get<double>(), 0.1);
}

// Binned views: the tracker's and the fusion's pixel lattices shrink with the pixels, the rest of
// the options stay.
TEST(ScanChain, ScanOptionsForBinScaleThePixelLattices) {
  const ScanOptions base;
  const ScanOptions two = ScanOptionsForBin(base, 2);
  EXPECT_EQ(two.bin, 2);
  EXPECT_EQ(two.tracker.odometry.sample_stride, 1);  // 2 → 1
  EXPECT_EQ(two.tracker.odometry.map_stride, 2);     // 3 → 1.5, rounded
  EXPECT_EQ(two.tracker.keyframes.stride, 2);
  EXPECT_EQ(two.tracker.odometry.min_view_samples,
            base.tracker.odometry.min_view_samples);  // the same share of the view
  EXPECT_DOUBLE_EQ(two.tracker.keyframes.features.image_scale,
                   std::min(1.0, 2 * base.tracker.keyframes.features.image_scale));
  EXPECT_DOUBLE_EQ(two.tracker.odometry.target_scale, 2 * base.tracker.odometry.target_scale);
  EXPECT_EQ(two.tsdf.occlusion_stride,
            base.tsdf.occlusion_stride);  // kept in binned pixels (see ScanOptionsForBin)
  EXPECT_DOUBLE_EQ(two.tsdf.voxel_mm, base.tsdf.voxel_mm);
  EXPECT_EQ(two.tracker.odometry.icp.levels.size(), base.tracker.odometry.icp.levels.size());
  const ScanOptions four = ScanOptionsForBin(base, 4);
  EXPECT_EQ(four.tracker.odometry.sample_stride,
            1);  // 2 / 4 → at least 1: samples of a quarter the share
  EXPECT_EQ(four.tracker.odometry.min_view_samples, base.tracker.odometry.min_view_samples / 4);
  const ScanOptions one = ScanOptionsForBin(base, 1);
  EXPECT_EQ(one.tracker.odometry.sample_stride, base.tracker.odometry.sample_stride);
  EXPECT_EQ(one.tsdf.occlusion_stride, base.tsdf.occlusion_stride);
  EXPECT_THROW(ScanOptionsForBin(base, 0), std::invalid_argument);
  EXPECT_THROW(ScanReconstructor(MakeDefaultProbeDesign().calibration, base.recon, 7),
               std::invalid_argument);  // 640 % 7
}

TEST(ScanChain, AFuserAdoptsARefusedVolumeAndFreesItsOwn) {
  using namespace d3d::testing;
  const PinholeBrownConrady camera = TestCamera(160, 120, 500);
  const HeightField surface(7);
  auto view_at = [&](double x_mm) {
    const SyntheticView s = RenderHeightField(surface, camera, LookDown(x_mm, 0, 30), 0.0, 1);
    ReconstructedView v;
    v.points_in_cam = s.points;
    v.normals = s.normals;
    v.quality = s.quality;
    return std::make_pair(v, LookDown(x_mm, 0, 30));
  };
  TsdfOptions t;
  ScanFuser live(camera, t), refused(camera, t);
  const auto [here, here_pose] = view_at(0);
  const auto [there, there_pose] =
      view_at(4);  // the refusion sees the surface 4 mm further along x
  for (int i = 0; i < 2; ++i) ASSERT_TRUE(live.Fuse(here, here_pose).ok());
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(refused.Fuse(there, there_pose).ok());
  const double live_lo_x = live.volume().ExtractMesh().Bounds().first.x();
  const int64_t refused_voxels = refused.volume().ActiveVoxels();
  ASSERT_GT(refused_voxels, 0);
  live.AdoptVolume(std::move(refused));
  EXPECT_EQ(live.volume().ActiveVoxels(), refused_voxels);
  EXPECT_EQ(live.fused(), 2);  // the live views are still counted
  const TriangleMesh mesh = live.volume().ExtractMesh();
  ASSERT_FALSE(mesh.faces.empty());
  EXPECT_GT(mesh.Bounds().first.x(), live_lo_x + 3.0);  // the refused model, not the live one
  EXPECT_THROW(live.AdoptVolume(std::move(refused)),
               std::invalid_argument);  // nothing left to adopt
}

// The refusion at the pose graph's poses (FinishScan with a provider), from the frames a host keeps
// (ViewArchive): the volume is the one the views fused again in order at their final poses give
// (the helper thread that gets the views changes nothing), views the provider cannot find are
// skipped, and a provider error ends the scan with that error and leaves the live model alone.
TEST(ScanChain, RefusionFusesTheKeptViewsAtTheFinalPosesInOrder) {
  std::unique_ptr<SimSession> session = QuadrantSession();
  ASSERT_TRUE(session);
  ShortScan scan;
  ViewArchive kept;
  RunShortScan(*session, 2, &scan, &kept);
  ASSERT_EQ(kept.size(), 15u);
  scan.o.refuse_min_correction_mm = 0;  // any correction of the pose graph
  ScanReconstructor again(scan.view_calibration, scan.o.recon, 1);
  std::vector<cv::Mat> frames;
  int64_t asked = 0;
  const ScanViewProvider provider = [&](int64_t k, const ScanViewRecord& v,
                                        ReconstructedView* out) -> Status {
    ++asked;
    if (k == 3) return NotFound("view 3 was not kept");
    D3D_RETURN_IF_ERROR(kept.Get(v.burst_seq, &frames));
    return again.Reconstruct(frames, out);
  };
  ScanResult result;
  ASSERT_TRUE(
      FinishScan(scan.o, scan.times, scan.reg.get(), scan.fuser.get(), provider, {}, &result).ok());
  ASSERT_TRUE(result.report["fused_again_at_optimised_poses"].get<bool>())
      << "pose graph correction " << result.report["pose_graph_max_correction_mm"];
  EXPECT_EQ(asked, scan.reg->accepted());
  // The same views, one thread, in order, at the final poses.
  TriangleMesh expected = FusedAtFinalPoses(scan, kept, 3);
  ASSERT_FALSE(HasFailure());
  expected.ComputeVertexNormals();
  ASSERT_EQ(result.mesh.vertices.size(), expected.vertices.size());
  ASSERT_EQ(result.mesh.faces.size(), expected.faces.size());
  for (size_t i = 0; i < expected.vertices.size(); ++i)
    ASSERT_EQ(result.mesh.vertices[i], expected.vertices[i]) << i;

  // A provider that fails at the fifth view: that error, and the live model as it was.
  ShortScan other;
  RunShortScan(*session, 2, &other);
  other.o.refuse_min_correction_mm = 0;
  const int64_t live_voxels = other.fuser->volume().ActiveVoxels();
  const ScanViewProvider failing = [&](int64_t k, const ScanViewRecord& v,
                                       ReconstructedView* out) -> Status {
    if (k == 4) return Corrupt("view 4 is damaged");
    D3D_RETURN_IF_ERROR(kept.Get(v.burst_seq, &frames));
    return again.Reconstruct(frames, out);
  };
  const Status s =
      FinishScan(other.o, other.times, other.reg.get(), other.fuser.get(), failing, {}, &result);
  EXPECT_EQ(s.code(), StatusCode::kCorrupt) << s.ToString();
  EXPECT_EQ(other.fuser->volume().ActiveVoxels(), live_voxels);
}

// "Undo last seconds" in the chain: the views of the last 0.15 s (3 views 66.7 ms apart) are taken
// back mid-scan, the probe goes back over the model (bursts 41, 43, …: between the views kept and
// on over the undone ones) and the scan goes on, and the saved model is the kept views fused again
// at their final poses, whatever refuse_min_correction_mm says: the undone views are in none of it.
TEST(ScanChain, UndoneViewsLeaveTheSavedModel) {
  std::unique_ptr<SimSession> session = QuadrantSession();
  ASSERT_TRUE(session);
  ShortScan scan;
  ViewArchive kept;
  ScanRegistrar::UndoResult undo;
  std::vector<int64_t> again_bursts;
  for (int64_t i = 41; i < 60; i += 2) again_bursts.push_back(i);
  RunShortScan(*session, 2, &scan, &kept, 10, 0.15, &undo, again_bursts);
  ASSERT_FALSE(HasFatalFailure());
  ASSERT_TRUE(undo.ok) << undo.reason;
  EXPECT_EQ(undo.first_view, 7);
  EXPECT_EQ(undo.views_undone, 3);
  EXPECT_FALSE(undo.clamped);
  EXPECT_NEAR(undo.seconds_undone, 2 / 15.0, 1e-3);
  const ScanRegistrar& reg = *scan.reg;
  EXPECT_EQ(reg.views_undone(), 3);
  for (size_t k = 7; k < 10; ++k) EXPECT_FALSE(reg.views()[k].accepted) << k;
  // Back over the model: a re-entry confirmed by the next view, then tracking on.
  ASSERT_EQ(reg.views().size(), 20u);
  int64_t after = 0;
  for (size_t k = 10; k < reg.views().size(); ++k) after += reg.views()[k].accepted;
  EXPECT_GE(after, 8) << reg.events().dump();
  scan.o.refuse_min_correction_mm = -1;  // "never": the undo overrides it
  ScanReconstructor again(scan.view_calibration, scan.o.recon, 1);
  std::vector<cv::Mat> frames;
  std::vector<uint64_t> asked;
  const ScanViewProvider provider = [&](int64_t, const ScanViewRecord& v,
                                        ReconstructedView* out) -> Status {
    asked.push_back(v.burst_seq);
    D3D_RETURN_IF_ERROR(kept.Get(v.burst_seq, &frames));
    return again.Reconstruct(frames, out);
  };
  ScanResult no_provider;
  EXPECT_EQ(
      FinishScan(scan.o, scan.times, scan.reg.get(), scan.fuser.get(), {}, {}, &no_provider).code(),
      StatusCode::kInvalidArgument);
  ScanResult result;
  ASSERT_TRUE(FinishScan(scan.o, scan.times, scan.reg.get(), scan.fuser.get(), provider,
                         TruthOf(session.get()), &result)
                  .ok());
  EXPECT_TRUE(result.report["fused_again_at_optimised_poses"].get<bool>());
  EXPECT_EQ(result.report["views_undone"], 3);
  for (const uint64_t seq : {44u, 46u, 48u})
    EXPECT_EQ(std::count(asked.begin(), asked.end(), seq), 0) << "burst " << seq;
  EXPECT_EQ(static_cast<int64_t>(asked.size()), reg.accepted());
  EXPECT_EQ(result.poses.size(), static_cast<size_t>(reg.accepted()));
  EXPECT_LT(result.report["trueness_rms_um"].get<double>(), 20.0);
  // The kept views, one thread, in order, at the final poses: the same mesh.
  const TriangleMesh expected = FusedAtFinalPoses(scan, kept);
  ASSERT_FALSE(HasFailure());
  ASSERT_EQ(result.mesh.vertices.size(), expected.vertices.size());
  for (size_t i = 0; i < expected.vertices.size(); ++i)
    ASSERT_EQ(result.mesh.vertices[i], expected.vertices[i]) << i;
}

// A host's live volume at a coarser voxel (ScanAppOptions::live_voxel_mm) is never the result:
// with a provider the views are always fused again, at the scan's voxel, whatever
// refuse_min_correction_mm says, into the very mesh the kept views give at their final poses;
// without one, FinishScan refuses (the coarse model would pass for the scan's).
TEST(ScanChain, ACoarseLiveVolumeIsAlwaysFusedAgainAtTheScansVoxel) {
  std::unique_ptr<SimSession> session = QuadrantSession();
  ASSERT_TRUE(session);
  ShortScan scan;
  scan.live_voxel_mm = 2 * ScanOptions{}.tsdf.voxel_mm;
  ViewArchive kept;
  RunShortScan(*session, 2, &scan, &kept);
  ASSERT_FALSE(HasFatalFailure());
  ASSERT_DOUBLE_EQ(scan.fuser->volume().options().voxel_mm, scan.live_voxel_mm);
  scan.o.refuse_min_correction_mm = -1;  // "never": the coarse live volume overrides it
  ScanResult no_provider;
  const Status refused =
      FinishScan(scan.o, scan.times, scan.reg.get(), scan.fuser.get(), {}, {}, &no_provider);
  EXPECT_EQ(refused.code(), StatusCode::kInvalidArgument) << refused.ToString();
  EXPECT_NE(refused.message().find("voxel"), std::string::npos) << refused.ToString();
  ScanReconstructor again(scan.view_calibration, scan.o.recon, 1);
  std::vector<cv::Mat> frames;
  const ScanViewProvider provider = [&](int64_t, const ScanViewRecord& v,
                                        ReconstructedView* out) -> Status {
    D3D_RETURN_IF_ERROR(kept.Get(v.burst_seq, &frames));
    return again.Reconstruct(frames, out);
  };
  ScanResult result;
  ASSERT_TRUE(FinishScan(scan.o, scan.times, scan.reg.get(), scan.fuser.get(), provider,
                         TruthOf(session.get()), &result)
                  .ok());
  EXPECT_TRUE(result.report["fused_again_at_optimised_poses"].get<bool>());
  EXPECT_DOUBLE_EQ(result.report["voxel_mm"].get<double>(), scan.o.tsdf.voxel_mm);
  EXPECT_DOUBLE_EQ(scan.fuser->volume().options().voxel_mm,
                   scan.o.tsdf.voxel_mm);  // the fuser adopted the refused volume
  const TriangleMesh expected = FusedAtFinalPoses(scan, kept);
  ASSERT_FALSE(HasFailure());
  ASSERT_EQ(result.mesh.vertices.size(), expected.vertices.size());
  for (size_t i = 0; i < expected.vertices.size(); ++i)
    ASSERT_EQ(result.mesh.vertices[i], expected.vertices[i]) << i;
  EXPECT_LT(result.report["trueness_rms_um"].get<double>(), 20.0);
}

// A scan that loses the model early and goes on in a segment that never joins (a height field
// strip, pipeline/register/test_surfaces.h): FinishScan makes the larger group of views the model
// (moved back to the main frame's place) and saves the first views apart; nothing is fused at a
// guess.
TEST(ScanChain, TheLargestGroupOfViewsIsTheModelAndTheOtherIsSavedApart) {
  using namespace d3d::testing;
  const HeightField hf(31);
  const PinholeBrownConrady cam = TestCamera();
  ScanOptions o;
  o.tracker.keyframes.features.max_features = 800;
  o.tracker.segments.after_views = 2;
  ScanRegistrar reg(cam, o.tracker);
  ScanFuser fuser(cam, o.tsdf, o.free_space);
  std::vector<ReconstructedView> views;
  ScanTimes times;
  auto feed = [&](double x) {
    const SyntheticView v = RenderHeightField(hf, cam, LookDown(x, 0, 30), 0.004,
                                              static_cast<uint32_t>(views.size() + 1));
    ReconstructedView rv;
    rv.points_in_cam = v.points;
    rv.normals = v.normals;
    rv.quality = v.quality;
    rv.texture = v.texture;
    views.push_back(rv);
    const TrackResult r =
        reg.Register(rv, views.size(), static_cast<int64_t>(views.size()) * 33'000'000);
    if (r.accepted && r.in_main) {
      ASSERT_TRUE(fuser.Fuse(rv, r.world_from_cam).ok());
    }
    ++times.bursts;
  };
  for (double x = -24; x <= -20.99; x += 1.0) feed(x);  // the main model: 4 views
  for (double x = 10; x <= 20.01; x += 1.0) feed(x);    // 17 mm on: 2 refused, then a segment of 9
  ASSERT_EQ(reg.tracker().segments(), 2);
  const ScanViewProvider provider = [&](int64_t k, const ScanViewRecord&, ReconstructedView* out) {
    *out = views[static_cast<size_t>(k)];
    return Status::Ok();
  };
  ScanResult result;
  ASSERT_TRUE(FinishScan(o, times, &reg, &fuser, provider, {}, &result).ok());
  EXPECT_EQ(result.report["model_segment"].get<int>(), 1);
  EXPECT_EQ(result.report["views_in_model"].get<int>(), 9);
  EXPECT_EQ(result.report["views_apart"].get<int>(), 4);
  ASSERT_EQ(result.apart.size(), 1u);
  EXPECT_EQ(result.apart[0].segment, 0);
  EXPECT_EQ(result.apart[0].views, 4);
  EXPECT_FALSE(result.apart[0].mesh.faces.empty());
  EXPECT_FALSE(result.mesh.faces.empty());
  for (const Rigid3d& p : result.poses)
    EXPECT_LT(std::abs(p.translation().x()), 100.0);  // not 2 m off
  for (const Eigen::Vector3d& v : result.mesh.vertices) ASSERT_LT(std::abs(v.x()), 100.0);
}

TEST(ScanChain, EmptyModelIsAnError) {
  SimSessionOptions so;
  std::unique_ptr<SimSession> session;
  ASSERT_TRUE(SimSession::Create(so, &session).ok());
  ScanOptions o;
  ScanRegistrar reg(session->calibration().camera, o.tracker);
  ScanFuser fuser(session->calibration().camera, o.tsdf);
  ScanResult r;
  const Status s = FinishScan(o, {}, &reg, &fuser, {}, {}, &r);
  EXPECT_EQ(s.code(), StatusCode::kInternal);
  EXPECT_THROW(TrackerOptionsForStep({}, 0.5), std::invalid_argument);
}

// Bursts `every` apart: the motion check allows `every` times the per-view step (d3d-fuse --every
// and a live host gate a view the same way), and the first ICP level gathers over min(3,
// 0.8·√every) mm.
TEST(ScanChain, TrackerOptionsForStepScaleTheGates) {
  const TrackerOptions base;
  const TrackerOptions six = TrackerOptionsForStep(base, 6);
  EXPECT_DOUBLE_EQ(six.motion.max_step_mm, 6 * base.motion.max_step_mm);
  EXPECT_DOUBLE_EQ(six.motion.max_step_deg, 6 * base.motion.max_step_deg);
  EXPECT_NEAR(six.odometry.icp.levels[0].max_distance_mm, 0.8 * std::sqrt(6.0), 1e-12);
  EXPECT_DOUBLE_EQ(TrackerOptionsForStep(base, 100).odometry.icp.levels[0].max_distance_mm, 3.0);
  const TrackerOptions one = TrackerOptionsForStep(base, 1);
  EXPECT_DOUBLE_EQ(one.motion.max_step_mm, base.motion.max_step_mm);
  EXPECT_DOUBLE_EQ(one.motion.max_step_deg, base.motion.max_step_deg);
}

}  // namespace
}  // namespace d3d
