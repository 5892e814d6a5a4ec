#include "sim/render/ray_caster.h"

#include <gtest/gtest.h>

#include <random>

namespace d3d {
namespace {

TriangleMesh Quad(double half, double z) {
  TriangleMesh m;
  m.vertices = {{-half, -half, z}, {half, -half, z}, {half, half, z}, {-half, half, z}};
  m.faces = {{0, 1, 2}, {0, 2, 3}};
  return m;
}

TEST(RayCaster, PlaneHitsAreExactInDouble) {
  const RayCaster caster(Quad(100, 50));
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> d(-0.3, 0.3);
  for (int i = 0; i < 1000; ++i) {
    const Eigen::Vector3d origin(d(rng), d(rng), d(rng));
    const Eigen::Vector3d dir(d(rng), d(rng), 1.0);
    const auto hit = caster.Intersect(origin, dir);
    ASSERT_TRUE(hit.has_value());
    EXPECT_NEAR(hit->point.z(), 50.0, 1e-11);
    EXPECT_NEAR(hit->t, (50.0 - origin.z()) / dir.z(), 1e-11);
    EXPECT_LT((hit->point - (origin + hit->t * dir)).norm(), 1e-11);
    EXPECT_NEAR(hit->geometric_normal.z(), -1.0, 1e-12);  // faces the origin
  }
  EXPECT_FALSE(caster.Intersect({0, 0, 0}, {0, 0, -1}).has_value());
}

TEST(RayCaster, SphereHitsAreExactAndLabelled) {
  const Eigen::Vector3d c(1.0, -2.0, 48.0);
  const RayCaster caster(TriangleMesh{}, {SceneSphere{c, 6.0, SurfaceLabel::kGingiva}});
  for (double x = -0.08; x <= 0.08; x += 0.01) {
    const Eigen::Vector3d dir(x, -0.04, 1.0);
    const auto hit = caster.Intersect(Eigen::Vector3d::Zero(), dir);
    ASSERT_TRUE(hit.has_value()) << x;
    EXPECT_NEAR((hit->point - c).norm(), 6.0, 1e-11);
    EXPECT_EQ(hit->label, SurfaceLabel::kGingiva);
    EXPECT_LT(hit->geometric_normal.dot(dir), 0.0);
  }
}

TEST(RayCaster, OcclusionAndEmptyScene) {
  const RayCaster caster(Quad(10, 50));
  EXPECT_TRUE(caster.Occluded({0, 0, 0}, {0, 0, 1}, 1e-3, 100));
  EXPECT_FALSE(caster.Occluded({0, 0, 0}, {0, 0, 1}, 1e-3, 49.9));
  EXPECT_FALSE(caster.Occluded({0, 0, 0}, {1, 0, 0}, 1e-3, 100));
  EXPECT_THROW(RayCaster(TriangleMesh{}), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
