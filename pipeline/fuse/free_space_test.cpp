#include "pipeline/fuse/free_space.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>

#include "pipeline/register/test_surfaces.h"

namespace d3d {
namespace {

PinholeBrownConrady Camera() { return testing::TestCamera(160, 120, 400); }  // 20 × 15 mm at 50 mm

// A camera at (x, y, 0) in the world, turned by `tilt_rad` about the world y axis, looking along
// +z.
Rigid3d WorldFromCam(double x, double y, double tilt_rad = 0) {
  Rigid3d p = Rigid3d::Identity();
  p.linear() = Eigen::AngleAxisd(tilt_rad, Eigen::Vector3d::UnitY()).toRotationMatrix();
  p.translation() = Eigen::Vector3d(x, y, 0);
  return p;
}

// Ray-casts a scene (world frame) given as the distance along a world ray (nullopt-free: +inf =
// nothing) into an organised H×W CV_32FC3 cloud in the camera frame (lens without distortion).
using Scene = std::function<double(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir)>;
cv::Mat Render(const PinholeBrownConrady& cam, const Rigid3d& world_from_cam, const Scene& scene) {
  cv::Mat pts(cam.height, cam.width, CV_32FC3, cv::Scalar::all(std::nanf("")));
  for (int v = 0; v < cam.height; ++v)
    for (int u = 0; u < cam.width; ++u) {
      const Eigen::Vector3d ray_in_cam((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1);
      const Eigen::Vector3d dir = world_from_cam.linear() * ray_in_cam;
      const double t = scene(world_from_cam.translation(), dir);
      if (!std::isfinite(t)) continue;
      const Eigen::Vector3d p = ray_in_cam * t;
      pts.at<cv::Vec3f>(v, u) = cv::Vec3f(static_cast<float>(p.x()), static_cast<float>(p.y()),
                                          static_cast<float>(p.z()));
    }
  return pts;
}

// Moves a view's points in `patch` to `scale` of their depth (along their rays).
void ScalePatch(cv::Mat* points, const cv::Rect& patch, float scale) {
  for (int v = patch.y; v < patch.y + patch.height; ++v)
    for (int u = patch.x; u < patch.x + patch.width; ++u) points->at<cv::Vec3f>(v, u) *= scale;
}

// A step: the plane z = 50 mm for x < 0, z = 45 mm for x ≥ 0, and the wall x = 0 between them.
double Step(const Eigen::Vector3d& o, const Eigen::Vector3d& d) {
  double best = std::numeric_limits<double>::infinity();
  auto plane_z = [&](double z, bool want_positive_x) {
    const double t = (z - o.z()) / d.z();
    if (t > 0 && ((o.x() + t * d.x() >= 0) == want_positive_x)) best = std::min(best, t);
  };
  plane_z(50, false);
  plane_z(45, true);
  if (std::abs(d.x()) > 1e-12) {
    const double t = -o.x() / d.x();
    const double z = o.z() + t * d.z();
    if (t > 0 && z >= 45 && z <= 50) best = std::min(best, t);
  }
  return best;
}

TEST(FreeSpace, APatchInFrontOfWhatEarlierViewsSawIsRejected) {
  // Six views of a plane at z = 50 mm; then a view of it in which a 30 × 20 px patch lies 2.5 mm
  // nearer (a region unwrapped orders too near). The patch is rejected, the rest of that view is
  // not.
  const PinholeBrownConrady cam = Camera();
  FreeSpaceOptions o;
  o.reference_every = 1;
  FreeSpaceTest test(cam, o);
  const Scene plane = [](const Eigen::Vector3d& origin, const Eigen::Vector3d& dir) {
    return (50 - origin.z()) / dir.z();
  };
  cv::Mat rejected;
  for (int i = 0; i < 6; ++i) {
    const Rigid3d pose = WorldFromCam(-2.5 + i, 0.3 * i);
    EXPECT_EQ(test.TestAndRemember(Render(cam, pose, plane), pose, &rejected), 0) << "view " << i;
  }
  EXPECT_EQ(test.references(), 6);
  const Rigid3d pose = WorldFromCam(0.4, 0.5);
  cv::Mat pts = Render(cam, pose, plane);
  const cv::Rect patch(60, 40, 30, 20);
  ScalePatch(&pts, patch, 47.5f / 50.0f);
  const int64_t n = test.TestAndRemember(pts, pose, &rejected);
  EXPECT_EQ(n, patch.area());
  EXPECT_EQ(cv::countNonZero(rejected(patch)), patch.area());
  // A patch 0.5 mm nearer (within the margin: noise, a pose error) stays.
  FreeSpaceTest again(cam, o);
  for (int i = 0; i < 6; ++i) {
    const Rigid3d p = WorldFromCam(-2.5 + i, 0.3 * i);
    (void)again.TestAndRemember(Render(cam, p, plane), p, &rejected);
  }
  cv::Mat near = Render(cam, pose, plane);
  ScalePatch(&near, patch, 49.5f / 50.0f);
  EXPECT_EQ(again.TestAndRemember(near, pose, &rejected), 0);
}

TEST(FreeSpace, ASurfaceSeenAnewFromAnotherSideIsKept) {
  // References from straight above a 5-mm step; then oblique views (20–35°) that see its wall,
  // which no reference saw: nothing of a consistent scene is rejected, edges included. (The
  // references are taken every 6th view by default; here every view, so the oblique ones join.)
  const PinholeBrownConrady cam = Camera();
  FreeSpaceOptions o;
  o.reference_every = 1;
  FreeSpaceTest test(cam, o);
  cv::Mat rejected;
  for (int i = 0; i < 8; ++i) {
    const Rigid3d pose = WorldFromCam(-4 + i, 0.2 * i);
    EXPECT_EQ(test.TestAndRemember(Render(cam, pose, Step), pose, &rejected), 0)
        << "reference " << i;
  }
  int wall_points = 0;
  for (const double tilt_deg : {-20.0, -35.0, 20.0, 35.0}) {
    const double tilt = tilt_deg * M_PI / 180;
    const Rigid3d pose = WorldFromCam(-50 * std::sin(tilt) + 1, 0, tilt);  // aimed at the step
    const cv::Mat pts = Render(cam, pose, Step);
    for (int v = 0; v < pts.rows; ++v)
      for (int u = 0; u < pts.cols; ++u) {
        const cv::Vec3f p = pts.at<cv::Vec3f>(v, u);
        if (!std::isfinite(p[2])) continue;
        const Eigen::Vector3d w = pose * Eigen::Vector3d(p[0], p[1], p[2]);
        wall_points += std::abs(w.x()) < 1e-6 && w.z() > 45.2 && w.z() < 49.8;
      }
    EXPECT_EQ(test.TestAndRemember(pts, pose, &rejected), 0) << "tilt " << tilt_deg;
    // Registered 0.1 mm off (more than a scan's pose error): the step's edges still get no vote.
    for (const double dx : {-0.1, 0.1}) {
      Rigid3d off = pose;
      off.translation().x() += dx;
      EXPECT_EQ(test.TestAndRemember(pts, off, &rejected), 0)
          << "tilt " << tilt_deg << ", " << dx << " mm off";
    }
  }
  EXPECT_GT(wall_points, 200);  // the oblique views did see the wall
}

TEST(FreeSpace, KeepsOnlyTheNewestReferencesAndCanBeTurnedOff) {
  const PinholeBrownConrady cam = Camera();
  const Scene plane = [](const Eigen::Vector3d& origin, const Eigen::Vector3d& dir) {
    return (50 - origin.z()) / dir.z();
  };
  FreeSpaceOptions o;
  o.reference_every = 2;
  o.max_references = 3;
  FreeSpaceTest test(cam, o);
  cv::Mat rejected;
  const cv::Mat pts = Render(cam, WorldFromCam(0, 0), plane);
  for (int i = 0; i < 11; ++i) (void)test.TestAndRemember(pts, WorldFromCam(0, 0), &rejected);
  EXPECT_EQ(test.references(), 3);  // views 0, 2, …, 10: the newest three kept
  // Off: a patch well in front of every reference is fused.
  FreeSpaceOptions off = o;
  off.enabled = false;
  FreeSpaceTest none(cam, off);
  for (int i = 0; i < 6; ++i) (void)none.TestAndRemember(pts, WorldFromCam(0, 0), &rejected);
  cv::Mat ghost = pts * (45.0 / 50.0);
  EXPECT_EQ(none.TestAndRemember(ghost, WorldFromCam(0, 0), &rejected), 0);
  EXPECT_EQ(none.references(), 0);
  // On, the same patch is rejected.
  // (All but the border: a reference's 3 × 3 cells must lie inside its grid.)
  EXPECT_GT(test.TestAndRemember(ghost, WorldFromCam(0, 0), &rejected),
            0.9 * cam.width * cam.height);
  EXPECT_THROW(FreeSpaceTest(cam, FreeSpaceOptions{true, 0}), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
