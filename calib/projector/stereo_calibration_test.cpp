// Stereo calibration of a camera and a projector on synthetic features with known truth.
#include "calib/projector/stereo_calibration.h"

#include <gtest/gtest.h>

#include <random>

#include "calib/projector/test_system.h"

namespace d3d {
namespace {

const PinholeBrownConrady& kCam = testing::kTestCam;
const PinholeBrownConrady& kProj = testing::kTestProj;
Rigid3d CamFromProj() { return testing::TestCamFromProj(); }

std::vector<StereoView> MakeViews(int n, double cam_noise, double proj_noise, double radius,
                                  uint64_t seed, std::vector<Rigid3d>* truth_poses) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  std::normal_distribution<double> cn(0, cam_noise), pn(0, proj_noise);
  const Rigid3d proj_from_cam = CamFromProj().inverse();
  std::vector<StereoView> views;
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * (i + 0.5 * (u(rng) + 1)) / n;
    const Eigen::Matrix3d R = (Eigen::AngleAxisd(0.2 * u(rng), Eigen::Vector3d::UnitZ()) *
                               Eigen::AngleAxisd((22 + 10 * u(rng)) * M_PI / 180,
                                                 Eigen::Vector3d(std::cos(a), std::sin(a), 0)))
                                  .toRotationMatrix();
    Rigid3d pose = Rigid3d::Identity();
    pose.linear() = R;
    pose.translation() = Eigen::Vector3d(0.5 * u(rng), 0.5 * u(rng), 50 + 3 * u(rng)) -
                         R * Eigen::Vector3d(4.8, 3.6, 0);
    truth_poses->push_back(pose);
    StereoView v;
    v.name = std::to_string(i);
    for (int r = 0; r < 7; ++r)
      for (int c = 0; c < 9; ++c) {
        const Eigen::Vector3d X(c * 1.2, r * 1.2, 0);
        v.object_points.push_back(X);
        v.camera_px.push_back(ProjectTargetFeature(kCam, pose, X, radius) +
                              Eigen::Vector2d(cn(rng), cn(rng)));
        v.projector_px.push_back(ProjectTargetFeature(kProj, proj_from_cam * pose, X, 0.0) +
                                 Eigen::Vector2d(pn(rng), pn(rng)));
        v.projector_valid.push_back((r * 9 + c) % 17 != 5);  // a few features not mapped
      }
    views.push_back(v);
  }
  return views;
}

TEST(CalibrateStereo, RecoversBothDevicesAndTheExtrinsics) {
  std::vector<Rigid3d> poses;
  const double radius = 0.3;
  const auto views = MakeViews(15, 0.03, 0.05, radius, 3, &poses);
  StereoCalibrationOptions o;
  o.camera.circle_radius_mm = radius;
  o.camera.fix_k3 = true;
  o.projector.fix_k3 = true;
  const StereoCalibrationResult r = CalibrateStereo(views, 640, 480, 912, 1140, o);
  ASSERT_TRUE(r.ok) << r.reason;
  const double rot = RotationAngleRad(r.cam_from_proj, CamFromProj()),
               tr = TranslationDistanceMm(r.cam_from_proj, CamFromProj());
  std::printf(
      "stereo: cam rms %.4f proj rms %.4f px; fx %.2f proj fx %.2f; cam_from_proj %.2e rad %.4f mm "
      "(start %.2e rad %.4f mm)\n",
      r.camera_rms_px, r.projector_rms_px, r.camera.fx, r.projector.fx, rot, tr,
      RotationAngleRad(r.initial_cam_from_proj, CamFromProj()),
      TranslationDistanceMm(r.initial_cam_from_proj, CamFromProj()));
  EXPECT_NEAR(r.camera_rms_px, 0.03 * std::sqrt(2.0), 0.006);
  EXPECT_NEAR(r.projector_rms_px, 0.05 * std::sqrt(2.0), 0.01);
  EXPECT_NEAR(r.camera.fx, kCam.fx, 0.001 * kCam.fx);
  EXPECT_NEAR(r.projector.fx, kProj.fx, 0.001 * kProj.fx);
  std::printf("        sigma rot %.2e rad, t %.4f mm; proj cx %.2f (true %.2f) sigma %.2f\n",
              std::max({r.extrinsic_sigma[0], r.extrinsic_sigma[1], r.extrinsic_sigma[2]}),
              std::max({r.extrinsic_sigma[3], r.extrinsic_sigma[4], r.extrinsic_sigma[5]}),
              r.projector.cx, kProj.cx, r.projector_sigma[2]);
  // The rotation is correlated with the projector's principal point (1 px ≈ 0.5 mrad at f = 2100):
  // the narrow fields leave it to ~1 mrad, which the 3-D measurement does not see (the pair moves
  // together); translation to 10 µm.
  EXPECT_LT(rot, 3e-3);
  EXPECT_LT(tr, 0.02);
  EXPECT_LT(
      rot, 4 * std::max({r.extrinsic_sigma[0], r.extrinsic_sigma[1], r.extrinsic_sigma[2]}) + 1e-6);
}

TEST(CalibrateStereo, ProjectorWithoutFeaturesFailsWithTheCause) {
  std::vector<Rigid3d> poses;
  auto views = MakeViews(6, 0.03, 0.05, 0.0, 4, &poses);
  for (auto& v : views) std::fill(v.projector_valid.begin(), v.projector_valid.end(), 0);
  const StereoCalibrationResult r = CalibrateStereo(views, 640, 480, 912, 1140);
  EXPECT_FALSE(r.ok);
  EXPECT_EQ(r.reason.rfind("projector:", 0), 0u) << r.reason;
}

}  // namespace
}  // namespace d3d
