#include "calib/model/camera_model.h"

#include <gtest/gtest.h>

#include <random>

namespace d3d {
namespace {

PinholeBrownConrady TestCamera() {
  PinholeBrownConrady c;
  c.width = 640;
  c.height = 480;
  c.fx = 2000;
  c.fy = 2001;
  c.cx = 321.5;
  c.cy = 238.25;
  c.k1 = -0.12;
  c.k2 = 0.35;
  c.p1 = 0.0007;
  c.p2 = -0.0004;
  c.k3 = -0.8;
  return c;
}

TEST(CameraModel, DistortMatchesOpenCvFormulaByHand) {
  const PinholeBrownConrady c = TestCamera();
  const double x = 0.05, y = -0.03, r2 = x * x + y * y;
  const double radial = 1 + c.k1 * r2 + c.k2 * r2 * r2 + c.k3 * r2 * r2 * r2;
  const Eigen::Vector2d d = c.Distort({x, y});
  EXPECT_NEAR(d.x(), x * radial + 2 * c.p1 * x * y + c.p2 * (r2 + 2 * x * x), 1e-15);
  EXPECT_NEAR(d.y(), y * radial + c.p1 * (r2 + 2 * y * y) + 2 * c.p2 * x * y, 1e-15);
}

TEST(CameraModel, ProjectAndPixelRayAreInverseOverTheImage) {
  const PinholeBrownConrady c = TestCamera();
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-0.5, 639.49), v(-0.5, 479.49), z(40, 60);
  for (int i = 0; i < 2000; ++i) {
    const Eigen::Vector2d px(u(rng), v(rng));
    const auto ray = c.PixelRay(px);
    ASSERT_TRUE(ray.has_value());
    const Eigen::Vector3d p = *ray * z(rng);
    const auto back = c.Project(p);
    ASSERT_TRUE(back.has_value());
    EXPECT_LT((*back - px).norm(), 1e-9) << px.transpose();
  }
}

TEST(CameraModel, BinnedCameraSeesAPointAtItsBlocksCentre) {
  const PinholeBrownConrady c = TestCamera();
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> x(-6, 6), y(-5, 5), z(40, 60);
  for (int factor : {2, 4}) {
    const PinholeBrownConrady b = BinnedCamera(c, factor);
    EXPECT_EQ(b.width, 640 / factor);
    EXPECT_EQ(b.height, 480 / factor);
    // Full-resolution pixel u lies in binned pixel floor(u / factor) (pixel centres at integers,
    // edges at half-integers): u = factor·u' + (factor − 1)/2.
    for (int i = 0; i < 200; ++i) {
      const Eigen::Vector3d p(x(rng), y(rng), z(rng));
      const Eigen::Vector2d full = *c.Project(p), binned = *b.Project(p);
      EXPECT_NEAR(factor * binned.x() + 0.5 * (factor - 1), full.x(), 1e-9);
      EXPECT_NEAR(factor * binned.y() + 0.5 * (factor - 1), full.y(), 1e-9);
      EXPECT_EQ(c.InImage(full), b.InImage(binned));
    }
  }
  EXPECT_EQ(BinnedCamera(c, 1).cx, c.cx);
  EXPECT_THROW(BinnedCamera(c, 0), std::invalid_argument);
  EXPECT_THROW(BinnedCamera(c, 7), std::invalid_argument);  // 640 is not a multiple of 7
}

TEST(CameraModel, RejectsPointsBehindAndBadIntrinsics) {
  const PinholeBrownConrady c = TestCamera();
  EXPECT_FALSE(c.Project({0, 0, -1}).has_value());
  EXPECT_FALSE(c.Project({0, 0, 0}).has_value());
  PinholeBrownConrady bad = c;
  bad.fx = 0;
  EXPECT_THROW(bad.Check(), std::invalid_argument);
  bad = c;
  bad.width = 0;
  EXPECT_THROW(bad.Check(), std::invalid_argument);
  EXPECT_NO_THROW(c.Check());
  EXPECT_TRUE(c.InImage({-0.4, 479.4}));
  EXPECT_FALSE(c.InImage({639.5, 0}));
}

}  // namespace
}  // namespace d3d
