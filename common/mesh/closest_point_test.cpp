#include "common/mesh/closest_point.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <random>

namespace d3d {
namespace {

using Eigen::Vector3d;

// The triangle (0,0,0), (2,0,0), (0,2,0) in the z = 0 plane.
const Vector3d kA(0, 0, 0), kB(2, 0, 0), kC(0, 2, 0);

struct Case {
  Vector3d p, expected;
  int region;
};

TEST(ClosestOnTriangleTest, EveryRegion) {
  const Case cases[] = {
      {{0.5, 0.5, 1.0}, {0.5, 0.5, 0.0}, kTriangleInterior},
      {{-1.0, -1.0, 0.5}, kA, kTriangleVertexA},
      {{3.0, -0.5, -2.0}, kB, kTriangleVertexB},
      {{-0.5, 3.0, 0.0}, kC, kTriangleVertexC},
      {{1.0, -1.0, 0.3}, {1.0, 0.0, 0.0}, kTriangleEdgeAB},
      {{2.0, 2.0, -1.0}, {1.0, 1.0, 0.0}, kTriangleEdgeBC},
      {{-1.0, 1.5, 0.0}, {0.0, 1.5, 0.0}, kTriangleEdgeCA},
  };
  for (const Case& c : cases) {
    int region = -1;
    const Vector3d q = ClosestOnTriangle(c.p, kA, kB, kC, &region);
    EXPECT_EQ(region, c.region) << c.p.transpose();
    EXPECT_NEAR((q - c.expected).norm(), 0.0, 1e-12) << c.p.transpose();
    EXPECT_EQ(ClosestOnTriangle(c.p, kA, kB, kC), q)
        << "the form without region gives the same point";
  }
}

// Against brute force: no point of a fine barycentric grid over the triangle is closer to p.
TEST(ClosestOnTriangleTest, NoTrianglePointIsCloser) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  for (int trial = 0; trial < 50; ++trial) {
    const Vector3d a(u(rng), u(rng), u(rng)), b(u(rng), u(rng), u(rng)), c(u(rng), u(rng), u(rng));
    const Vector3d p(u(rng), u(rng), u(rng));
    if ((b - a).cross(c - a).norm() < 0.1) continue;
    int region = -1;
    const Vector3d q = ClosestOnTriangle(p, a, b, c, &region);
    ASSERT_GE(region, kTriangleInterior);
    ASSERT_LE(region, kTriangleEdgeCA);
    const double d = (p - q).norm();
    constexpr int kSteps = 200;
    for (int i = 0; i <= kSteps; ++i)
      for (int j = 0; i + j <= kSteps; ++j) {
        const Vector3d s = a + (b - a) * (static_cast<double>(i) / kSteps) +
                           (c - a) * (static_cast<double>(j) / kSteps);
        ASSERT_LE(d, (p - s).norm() + 1e-12) << "trial " << trial;
      }
  }
}

TEST(ClosestOnTriangleTest, PointOnTheTriangleIsItself) {
  const Vector3d p(0.4, 0.7, 0.0);
  int region = -1;
  EXPECT_NEAR((ClosestOnTriangle(p, kA, kB, kC, &region) - p).norm(), 0.0, 1e-15);
  EXPECT_EQ(region, kTriangleInterior);
  EXPECT_EQ(ClosestOnTriangle(kB, kA, kB, kC, &region), kB);
  EXPECT_EQ(region, kTriangleVertexB);
}

}  // namespace
}  // namespace d3d
