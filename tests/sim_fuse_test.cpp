// A short scan with the virtual probe through the whole chain: reconstruction → frame-to-model
// registration → TSDF fusion → mesh → evaluation against the scene, with the true poses.
#include <gtest/gtest.h>

#include "firmware/sim/session/sim_session.h"
#include "pipeline/eval/evaluate_scan.h"
#include "pipeline/fuse/tsdf.h"
#include "pipeline/recon/reconstruct.h"
#include "pipeline/register/tracker.h"

namespace d3d {
namespace {

TEST(SimFuse, ShortTypodontScanIsAccurate) {
  SimSessionOptions so;
  so.model = "typodont";
  so.trajectory = "quadrant";
  so.seed = 3;
  std::unique_ptr<SimSession> session;
  ASSERT_TRUE(SimSession::Create(so, &session).ok());
  const ProbeCalibration& calib = session->calibration();
  Reconstructor recon(calib);
  Tracker tracker(calib.camera);
  TsdfVolume tsdf;
  std::vector<Rigid3d> est, truth;
  ReconstructedView view;
  for (int64_t i = 30; i < 70; i += 2) {  // 15 bursts/s for 1.3 s
    const Burst b = session->RenderBurst(i, false);
    std::vector<cv::Mat> frames;
    for (int f = 0; f < calib.pattern.steps; ++f) frames.push_back(b.frames[static_cast<size_t>(f)].image);
    ASSERT_TRUE(recon.Reconstruct(frames, &view).ok());
    const TrackResult r = tracker.Track(view.points_in_cam, view.normals, view.quality, view.texture);
    if (view.points < 5000) continue;  // the probe sees nothing yet (lifted / out of range)
    ASSERT_TRUE(r.accepted) << "burst " << i << ": " << r.reason;
    ASSERT_TRUE(tsdf.Integrate(view.points_in_cam, view.normals, view.quality, calib.camera, r.world_from_cam).ok());
    est.push_back(r.world_from_cam);
    truth.push_back(session->trajectory().WorldFromProbe(b.reference_ns));
  }
  ASSERT_GE(est.size(), 15u);
  const TriangleMesh mesh = tsdf.ExtractMesh();
  ASSERT_GT(mesh.faces.size(), 10000u);
  Rigid3d world_from_model;
  const AteReport ate = AbsoluteTrajectoryError(est, truth, &world_from_model);
  const MeshClosestPoint ref(session->scene());
  const TruenessReport t = EvaluateTrueness(mesh, ref, world_from_model);
  std::printf("short scan: %zu faces, trueness rms %.1f um, mean %.1f um, p95 %.1f um, ATE %.4f mm\n", mesh.faces.size(),
              t.rms_um, t.mean_um, t.p95_um, ate.rmse_mm);
  EXPECT_LT(t.rms_um, 20.0);
  EXPECT_LT(t.p95_um, 45.0);
  EXPECT_LT(ate.rmse_mm, 0.1);
  EXPECT_LT(t.outlier_pct, 2.0);
}

}  // namespace
}  // namespace d3d
