// Camera calibration on synthetic views with known truth (projected targets + seeded noise).
#include "calib/camera/camera_calibration.h"

#include <gtest/gtest.h>

#include <random>

namespace d3d {
namespace {

std::vector<Eigen::Vector3d> Grid(int cols, int rows, double s) {
  std::vector<Eigen::Vector3d> p;
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) p.emplace_back(c * s, r * s, 0.0);
  return p;
}

// A pose that looks at the target centre from distance z with the target tilted by `tilt` about
// a random in-plane axis and rolled by `roll`.
Rigid3d LookPose(const Eigen::Vector3d& centre, double z, double tilt, double axis_angle,
                 double roll, const Eigen::Vector2d& shift = {0, 0}) {
  const Eigen::Vector3d axis(std::cos(axis_angle), std::sin(axis_angle), 0);
  const Eigen::Matrix3d R =
      (Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(tilt, axis))
          .toRotationMatrix();
  Rigid3d p = Rigid3d::Identity();
  p.linear() = R;
  p.translation() = Eigen::Vector3d(shift.x(), shift.y(), z) - R * centre;
  return p;
}

struct Synthetic {
  PinholeBrownConrady camera;
  std::vector<Rigid3d> poses;
  std::vector<TargetView> views;
};

Synthetic MakeViews(const PinholeBrownConrady& cam, int n, double noise_px, uint64_t seed,
                    double tilt_deg = 30, double radius_mm = 0.0, double spacing_mm = 1.2) {
  Synthetic s;
  s.camera = cam;
  const auto pts = Grid(9, 7, spacing_mm);
  const Eigen::Vector3d centre(4 * spacing_mm, 3 * spacing_mm, 0);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  std::normal_distribution<double> noise(0, noise_px);
  for (int i = 0; i < n; ++i) {
    const Rigid3d pose =
        LookPose(centre, 50 + 3 * u(rng), tilt_deg * M_PI / 180 * (0.5 + 0.5 * std::abs(u(rng))),
                 M_PI * u(rng), 0.25 * u(rng), {0.8 * u(rng), 0.6 * u(rng)});
    TargetView v;
    v.name = "view" + std::to_string(i);
    for (const auto& p : pts) {
      Eigen::Vector2d uv = ProjectTargetFeature(cam, pose, p, radius_mm);
      uv += Eigen::Vector2d(noise(rng), noise(rng));
      v.object_points.push_back(p);
      v.image_points.push_back(uv);
    }
    s.poses.push_back(pose);
    s.views.push_back(v);
  }
  return s;
}

// The virtual probe's camera: a narrow field (fx = 2000 px on 640 × 480).
const PinholeBrownConrady kProbeCam{640,    480,  2000, 2000,    322.7, 236.9,
                                    -0.045, 0.12, 2e-4, -1.5e-4, 0};
// A wide-angle camera with strong distortion (like OpenCV's sample images).
const PinholeBrownConrady kWideCam{640,   480, 536,    536,   342.3, 235.6,
                                   -0.27, 0.1, 1.5e-3, -3e-4, -0.02};

TEST(TsaiPlanarPose, ExactWithoutNoiseOrDistortion) {
  PinholeBrownConrady cam = kProbeCam;
  cam.cx = 319.5;
  cam.cy = 239.5;
  cam.k1 = cam.k2 = cam.p1 = cam.p2 = 0;
  const Synthetic s = MakeViews(cam, 4, 0.0, 7);
  for (size_t i = 0; i < s.views.size(); ++i) {
    const TsaiPoseResult t = TsaiPlanarPose(s.views[i], cam.cx, cam.cy, 1.0);
    ASSERT_TRUE(t.ok) << t.reason;
    EXPECT_NEAR(t.f_px, 2000.0, 1e-6);
    EXPECT_LT(RotationAngleRad(t.device_from_target, s.poses[i]), 1e-9);
    EXPECT_LT(TranslationDistanceMm(t.device_from_target, s.poses[i]), 1e-7);
  }
}

TEST(TsaiPlanarPose, FrontoParallelViewDoesNotVote) {
  PinholeBrownConrady cam = kProbeCam;
  cam.k1 = cam.k2 = cam.p1 = cam.p2 = 0;
  const Synthetic s = MakeViews(cam, 1, 0.0, 3, 0.0);
  const TsaiPoseResult t = TsaiPlanarPose(s.views[0], 319.5, 239.5, 1.0);
  EXPECT_TRUE(t.ok);
  EXPECT_EQ(t.f_px, 0.0);
}

TEST(CalibrateCamera, RecoversProbeCameraFromNoisyViews) {
  // 0.03 px per coordinate: the centroid noise of the virtual probe's circle images. The narrow
  // field (±9°) cannot tell k3 from k1, k2: fixed at 0, as for the probe.
  const Synthetic s = MakeViews(kProbeCam, 15, 0.03, 11, 40);
  CameraCalibrationOptions o;
  o.fix_k3 = true;
  const CameraCalibrationResult r = CalibrateCamera(s.views, 640, 480, o);
  ASSERT_TRUE(r.ok) << r.reason;
  std::printf(
      "probe camera: rms %.4f px (start %.3f px); fx %.3f fy %.3f cx %.3f cy %.3f k1 %.5f k2 %.4f  "
      "sigma(fx) %.3f px\n",
      r.rms_px, r.initial_rms_px, r.camera.fx, r.camera.fy, r.camera.cx, r.camera.cy, r.camera.k1,
      r.camera.k2, r.sigma[0]);
  EXPECT_NEAR(r.rms_px, 0.03 * std::sqrt(2.0),
              0.005);  // the noise (2-D RMS): nothing left unexplained
  EXPECT_NEAR(r.camera.fx, kProbeCam.fx, 0.001 * kProbeCam.fx);
  EXPECT_NEAR(r.camera.fy, kProbeCam.fy, 0.001 * kProbeCam.fy);
  EXPECT_NEAR(r.camera.cx, kProbeCam.cx, 1.0);
  EXPECT_NEAR(r.camera.cy, kProbeCam.cy, 1.0);
  // The true values lie within 4 of the reported standard deviations.
  EXPECT_LT(std::abs(r.camera.fx - kProbeCam.fx), 4 * r.sigma[0]);
  EXPECT_LT(std::abs(r.camera.cx - kProbeCam.cx), 4 * r.sigma[2]);
  for (size_t i = 0; i < s.poses.size(); ++i) {
    EXPECT_LT(RotationAngleRad(r.views[i].device_from_target, s.poses[i]), 1e-3);
    EXPECT_LT(TranslationDistanceMm(r.views[i].device_from_target, s.poses[i]), 0.1);
  }
}

TEST(CalibrateCamera, RecoversWideAngleDistortion) {
  // A target that fills this camera's view at 50 mm: 9 × 7 points 5 mm apart.
  const Synthetic s = MakeViews(kWideCam, 12, 0.1, 5, 35, 0.0, 5.0);
  const CameraCalibrationResult r = CalibrateCamera(s.views, 640, 480);
  ASSERT_TRUE(r.ok) << r.reason;
  // Check the distortion where it matters: the displacement it causes across the image.
  double max_diff = 0;
  for (double x = -0.4; x <= 0.4; x += 0.1)  // the part of the image the views cover
    for (double y = -0.3; y <= 0.3; y += 0.1) {
      const Eigen::Vector2d a = kWideCam.Distort({x, y}) * kWideCam.fx,
                            b = r.camera.Distort({x, y}) * r.camera.fx;
      max_diff = std::max(max_diff, ((a + Eigen::Vector2d(kWideCam.cx, kWideCam.cy)) -
                                     (b + Eigen::Vector2d(r.camera.cx, r.camera.cy)))
                                        .norm());
    }
  std::printf(
      "wide camera: rms %.4f px, fx %.2f (true %.2f), k1 %.4f (true %.4f), max pixel-map "
      "difference %.3f px\n",
      r.rms_px, r.camera.fx, kWideCam.fx, r.camera.k1, kWideCam.k1, max_diff);
  EXPECT_NEAR(r.rms_px, 0.1 * std::sqrt(2.0), 0.02);
  EXPECT_NEAR(r.camera.fx, kWideCam.fx, 0.005 * kWideCam.fx);
  EXPECT_LT(max_diff, 0.3);
}

TEST(CalibrateCamera, CircleCentreModelRemovesPerspectiveBias) {
  // Large circles close to a wide-angle camera (like OpenCV's acircles images): the centroid of
  // the imaged ellipse is up to ~1 px from the image of the circle's centre.
  const double radius = 1.5;
  const Synthetic s = MakeViews(kWideCam, 12, 0.0, 9, 40, radius, 5.0);
  CameraCalibrationOptions with;
  with.circle_radius_mm = radius;
  const CameraCalibrationResult a = CalibrateCamera(s.views, 640, 480, with);
  const CameraCalibrationResult b = CalibrateCamera(s.views, 640, 480);
  ASSERT_TRUE(a.ok) << a.reason;
  ASSERT_TRUE(b.ok) << b.reason;
  std::printf(
      "circle centres: conic model rms %.5f px fx %.4f; point model rms %.5f px fx %.4f (true "
      "%.1f)\n",
      a.rms_px, a.camera.fx, b.rms_px, b.camera.fx, kWideCam.fx);
  EXPECT_LT(a.rms_px, 1e-4);
  EXPECT_NEAR(a.camera.fx, kWideCam.fx, 1e-3);
  EXPECT_GT(b.rms_px, 100 * a.rms_px);
  EXPECT_GT(std::abs(b.camera.fx - kWideCam.fx), 100 * std::abs(a.camera.fx - kWideCam.fx));
}

TEST(CalibrateCamera, FixedAspectRatioKeepsFxEqualFy) {
  const Synthetic s = MakeViews(kWideCam, 8, 0.1, 21, 35, 0.0, 5.0);
  CameraCalibrationOptions o;
  o.fix_aspect_ratio = true;
  const CameraCalibrationResult r = CalibrateCamera(s.views, 640, 480, o);
  ASSERT_TRUE(r.ok) << r.reason;
  EXPECT_DOUBLE_EQ(r.camera.fx, r.camera.fy);
}

TEST(CalibrateCamera, DegenerateInputFailsWithTheCause) {
  const Synthetic two = MakeViews(kProbeCam, 2, 0.05, 1);
  CameraCalibrationResult r = CalibrateCamera(two.views, 640, 480);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.reason.find("too few views"), std::string::npos) << r.reason;

  const Synthetic flat = MakeViews(kProbeCam, 10, 0.05, 2, 0.5);
  r = CalibrateCamera(flat.views, 640, 480);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.reason.find("fronto-parallel"), std::string::npos) << r.reason;

  // Barely tilted views: Tsai gets a vote, but the refinement cannot pin f down.
  const Synthetic shallow = MakeViews(kProbeCam, 6, 0.3, 4, 4.0);
  CameraCalibrationOptions o;
  o.min_tilt_deg = 1.0;
  r = CalibrateCamera(shallow.views, 640, 480, o);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.reason.find("ill-conditioned"), std::string::npos) << r.reason;

  TargetView tiny = two.views[0];
  tiny.object_points.resize(4);
  tiny.image_points.resize(4);
  std::vector<TargetView> views = MakeViews(kProbeCam, 4, 0.05, 1).views;
  views.push_back(tiny);
  r = CalibrateCamera(views, 640, 480);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.reason.find("features"), std::string::npos) << r.reason;
}

}  // namespace
}  // namespace d3d
