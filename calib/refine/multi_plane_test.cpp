// Multi-plane refinement on synthetic views: features with noise give a stereo start; dense
// decoded samples (exact geometry + 0.02 px decoding noise) then pull the system to the truth.
#include "calib/refine/multi_plane.h"

#include <gtest/gtest.h>

#include <random>

#include "calib/projector/test_system.h"

namespace d3d {
namespace {

const PinholeBrownConrady& kCam = testing::kTestCam;
const PinholeBrownConrady& kProj = testing::kTestProj;
Rigid3d CamFromProj() { return testing::TestCamFromProj(); }

TEST(MultiPlane, TriangulateColumnInvertsTheProjection) {
  const Eigen::Vector3d X(1.2, -0.7, 51.3);
  const Eigen::Vector2d cam = *kCam.Project(X);
  const Eigen::Vector2d proj = *kProj.Project(CamFromProj().inverse() * X);
  Eigen::Vector3d p;
  ASSERT_TRUE(TriangulateColumn(kCam, kProj, CamFromProj(), cam, proj.x(), &p));
  EXPECT_LT((p - X).norm(), 1e-7);
}

TEST(MultiPlane, RefinementMakesTheMeasuredPlanesFlat) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  std::normal_distribution<double> cn(0, 0.03), pn(0, 0.08), dn(0, 0.02);
  const Rigid3d proj_from_cam = CamFromProj().inverse();
  std::vector<StereoView> views;
  std::vector<std::vector<PlaneSample>> dense;
  std::vector<Rigid3d> truth;
  const int n = 10;
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * (i + 0.5 * (u(rng) + 1)) / n;
    const Eigen::Matrix3d R = Eigen::AngleAxisd((22 + 10 * u(rng)) * M_PI / 180,
                                                Eigen::Vector3d(std::cos(a), std::sin(a), 0))
                                  .toRotationMatrix();
    Rigid3d pose = Rigid3d::Identity();
    pose.linear() = R;
    pose.translation() = Eigen::Vector3d(0.5 * u(rng), 0.5 * u(rng), 50 + 3 * u(rng)) -
                         R * Eigen::Vector3d(4.8, 3.6, 0);
    truth.push_back(pose);
    StereoView v;
    for (int r = 0; r < 7; ++r)
      for (int c = 0; c < 9; ++c) {
        const Eigen::Vector3d X(c * 1.2, r * 1.2, 0);
        v.object_points.push_back(X);
        v.camera_px.push_back(*kCam.Project(pose * X) + Eigen::Vector2d(cn(rng), cn(rng)));
        v.projector_px.push_back(*kProj.Project(proj_from_cam * pose * X) +
                                 Eigen::Vector2d(pn(rng), pn(rng)));
        v.projector_valid.push_back(1);
      }
    views.push_back(v);
    std::vector<PlaneSample> d;
    const Eigen::Vector3d nrm = R.col(2), t = pose.translation();
    for (int y = 20; y < 480; y += 16)
      for (int x = 20; x < 640; x += 16) {
        const Eigen::Vector3d ray = *kCam.PixelRay(Eigen::Vector2d(x, y));
        const Eigen::Vector3d X = ray * (nrm.dot(t) / nrm.dot(ray));
        const auto uv = kProj.Project(proj_from_cam * X);
        if (!uv || !kProj.InImage(*uv)) continue;
        d.push_back({Eigen::Vector2d(x, y), *uv + Eigen::Vector2d(dn(rng), dn(rng))});
      }
    dense.push_back(d);
  }
  StereoCalibrationOptions so;
  so.camera.fix_k3 = true;
  so.projector.fix_k3 = true;
  const StereoCalibrationResult start = CalibrateStereo(views, 640, 480, 912, 1140, so);
  ASSERT_TRUE(start.ok) << start.reason;
  const MultiPlaneResult r = RefineMultiPlane(views, dense, start, so);
  ASSERT_TRUE(r.ok) << r.reason;
  std::printf(
      "multi-plane: %d samples; dense rms %.4f -> %.4f px; plane fit %.2f -> %.2f um; target plane "
      "%.2f -> %.2f um\n",
      r.samples, r.dense_rms_before_px, r.dense_rms_after_px, r.plane_fit_rms_before_um,
      r.plane_fit_rms_after_um, r.target_plane_rms_before_um, r.target_plane_rms_after_um);
  std::printf(
      "  proj fx %.2f -> %.2f (true 2100); cam_from_proj rot %.2e -> %.2e rad, t %.4f -> %.4f mm\n",
      start.projector.fx, r.projector.fx, RotationAngleRad(start.cam_from_proj, CamFromProj()),
      RotationAngleRad(r.cam_from_proj, CamFromProj()),
      TranslationDistanceMm(start.cam_from_proj, CamFromProj()),
      TranslationDistanceMm(r.cam_from_proj, CamFromProj()));
  EXPECT_LT(r.dense_rms_after_px, r.dense_rms_before_px);
  EXPECT_NEAR(r.dense_rms_after_px, 0.02 * std::sqrt(2.0), 0.01);  // down to the decoding noise
  EXPECT_LE(r.target_plane_rms_after_um, r.target_plane_rms_before_um);
  // The floor: 0.02 px of decoding noise is 0.02 × 24 µm / tan 12° ≈ 2.3 µm of depth per point.
  EXPECT_LT(r.target_plane_rms_after_um, 2.6);
  EXPECT_LT(RotationAngleRad(r.cam_from_proj, CamFromProj()),
            0.5 * RotationAngleRad(start.cam_from_proj, CamFromProj()));
  EXPECT_LT(TranslationDistanceMm(r.cam_from_proj, CamFromProj()), 0.02);
  EXPECT_NEAR(r.projector.fx, kProj.fx, 0.001 * kProj.fx);
}

}  // namespace
}  // namespace d3d
