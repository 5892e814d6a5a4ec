#include "pipeline/register/fpfh.h"

#include <gtest/gtest.h>

#include <functional>
#include <random>

#include "pipeline/register/test_surfaces.h"

namespace d3d {
namespace {

Rigid3d Pose(double deg, const Eigen::Vector3d& axis, const Eigen::Vector3d& t) {
  Rigid3d T = Rigid3d::Identity();
  T.linear() = Eigen::AngleAxisd(deg * M_PI / 180, axis.normalized()).toRotationMatrix();
  T.translation() = t;
  return T;
}

using Height = std::function<double(double, double)>;

// Samples of the surface z = h(x, y) (world, mm) on a square lattice of `step` mm over
// [x0, x1] × [y0, y1], offset by `phase` (so two views do not share samples), with Gaussian noise
// of noise_mm along z, expressed in a view frame: p_view = view_from_world · p_world. Normals from
// central differences of h.
SurfacePoints SampleSurface(const Height& h, double x0, double x1, double y0, double y1,
                            double step, double phase, double noise_mm, uint32_t seed,
                            const Rigid3d& view_from_world) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> N(0, 1);
  SurfacePoints s;
  const double e = 1e-3;
  for (double x = x0 + phase; x <= x1; x += step)
    for (double y = y0 + phase; y <= y1; y += step) {
      const Eigen::Vector3d p(x, y, h(x, y) + noise_mm * N(rng));
      const Eigen::Vector3d n = Eigen::Vector3d(-(h(x + e, y) - h(x - e, y)) / (2 * e),
                                                -(h(x, y + e) - h(x, y - e)) / (2 * e), 1)
                                    .normalized();
      s.points.push_back((view_from_world * p).cast<float>());
      s.normals.push_back((view_from_world.linear() * n).cast<float>());
    }
  return s;
}

// Scales for the synthetic relief (bumps 0.8–2.5 mm wide): 0.5 mm voxels.
FpfhOptions SmallScaleOptions() {
  FpfhOptions o;
  o.voxel_mm = 0.5;
  o.normal_radius_mm = 1.0;
  o.feature_radius_mm = 2.5;
  o.ransac.inlier_threshold_mm = 0.75;
  o.ransac.min_sample_spread_mm = 2.0;
  o.ransac.min_inlier_spread_mm = 0.5;
  o.ambiguity_mm = 1.0;
  return o;
}

struct Case {
  FpfhAlignResult result;
  Rigid3d truth;
};

// Source and target views of the same world surface, each over its own x range, 0.25 mm lattice.
Case Align(const Height& h, double sx0, double sx1, double tx0, double tx1, double y_half,
           const FpfhOptions& o) {
  const Rigid3d source_from_world = Pose(20, {0.3, -0.5, 1}, {2, -1, 40});
  const Rigid3d target_from_world = Pose(-35, {-0.2, 1, 0.4}, {-3, 4, 38});
  const SurfacePoints s =
      SampleSurface(h, sx0, sx1, -y_half, y_half, 0.25, 0.0, 0.01, 1, source_from_world);
  const SurfacePoints t =
      SampleSurface(h, tx0, tx1, -y_half, y_half, 0.25, 0.11, 0.01, 2, target_from_world);
  return {AlignByFpfh(ComputeFpfh(s, o), ComputeFpfh(t, o), o),
          target_from_world * source_from_world.inverse()};
}

TEST(DarbouxPairFeature, ZeroOnAPlaneAndInvariantToRigidMotionAndOrder) {
  const Eigen::Vector3f up(0, 0, 1);
  EXPECT_LT(DarbouxPairFeature({0, 0, 0}, up, {1, 2, 0}, up).norm(), 1e-6f);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> U(-1, 1);
  for (int k = 0; k < 20; ++k) {
    const Eigen::Vector3f p1(U(rng), U(rng), U(rng)), p2(U(rng), U(rng), U(rng));
    const Eigen::Vector3f n1 = Eigen::Vector3f(U(rng), U(rng), U(rng)).normalized(),
                          n2 = Eigen::Vector3f(U(rng), U(rng), U(rng)).normalized();
    const Eigen::Vector3f f = DarbouxPairFeature(p1, n1, p2, n2);
    const Eigen::Isometry3f T = Pose(70, {1, -2, 0.5}, {5, 1, -3}).cast<float>();
    EXPECT_LT((DarbouxPairFeature(T * p1, T.linear() * n1, T * p2, T.linear() * n2) - f).norm(),
              1e-4f);
    EXPECT_LT((DarbouxPairFeature(p2, n2, p1, n1) - f).norm(),
              1e-5f);  // the source is chosen, not given
    EXPECT_LE(std::abs(f.x()), 1.0f);
    EXPECT_LE(std::abs(f.y()), 1.0f);
    EXPECT_LE(std::abs(f.z()), static_cast<float>(M_PI));
  }
  // Two normals tilted towards each other by the same angle: φ = u·d, θ = the angle between them.
  const float a = 0.3f;
  const Eigen::Vector3f f = DarbouxPairFeature({0, 0, 0}, {std::sin(a), 0, std::cos(a)}, {1, 0, 0},
                                               {-std::sin(a), 0, std::cos(a)});
  EXPECT_NEAR(std::abs(f.y()), std::sin(a), 1e-6);
  EXPECT_NEAR(std::abs(f.z()), 2 * a, 1e-5);
  EXPECT_NEAR(f.x(), 0, 1e-6);
}

TEST(VoxelDownsample, CentroidsAndMeanNormalsPerVoxel) {
  SurfacePoints s;
  s.points = {{0.1f, 0.1f, 0.1f}, {0.3f, 0.5f, 0.9f}, {1.5f, 0.2f, 0.2f}, {-0.5f, 0.5f, 0.5f}};
  s.normals = {{0, 0, 1}, {0, 1, 0}, {1, 0, 0}, {0, 0, -1}};
  const SurfacePoints d = VoxelDownsample(s, 1.0);
  ASSERT_EQ(d.size(), 3u);
  EXPECT_LT((d.points[0] - Eigen::Vector3f(0.2f, 0.3f, 0.5f)).norm(), 1e-6f);
  EXPECT_LT((d.normals[0] - Eigen::Vector3f(0, 1, 1).normalized()).norm(), 1e-6f);
  EXPECT_LT((d.points[2] - Eigen::Vector3f(-0.5f, 0.5f, 0.5f)).norm(), 1e-6f);
  EXPECT_THROW(VoxelDownsample(s, 0), std::invalid_argument);
}

TEST(ComputeFpfh, BlocksSumToOneHundredAndNormalsAreRequired) {
  const testing::HeightField hf(5, 30);
  const SurfacePoints s = SampleSurface([&](double x, double y) { return hf.Height(x, y); }, -10,
                                        10, -8, 8, 0.25, 0, 0.0, 1, Rigid3d::Identity());
  const FpfhFeatures f = ComputeFpfh(s, SmallScaleOptions());
  ASSERT_GT(f.size(), 500u);
  ASSERT_EQ(f.descriptors.size(), f.size());
  for (const FpfhDescriptor& d : f.descriptors) {
    for (int b = 0; b < 3; ++b)
      EXPECT_NEAR(d.segment<kFpfhBins>(b * kFpfhBins).sum(), 100.0f, 1e-3f);
    EXPECT_GE(d.minCoeff(), 0.0f);
  }
  SurfacePoints no_normals = s;
  no_normals.normals.clear();
  EXPECT_THROW(ComputeFpfh(no_normals, SmallScaleOptions()), std::invalid_argument);
  FpfhOptions bad = SmallScaleOptions();
  bad.voxel_mm = 0;
  EXPECT_THROW(bad.Check(), std::invalid_argument);
}

TEST(AlignByFpfh, RecoversAKnownTransformWithPartialOverlap) {
  const testing::HeightField hf(7, 40);
  const Height h = [&](double x, double y) { return hf.Height(x, y); };
  // Source x ∈ [−15, 6], target x ∈ [−6, 15]: 12 of 21 mm shared.
  const Case c = Align(h, -15, 6, -6, 15, 8, SmallScaleOptions());
  ASSERT_TRUE(c.result.ok) << c.result.reason;
  EXPECT_LT(RotationAngleRad(c.result.target_from_source, c.truth) * 180 / M_PI, 0.5);
  EXPECT_LT(TranslationDistanceMm(c.result.target_from_source, c.truth), 0.1);
  EXPECT_GT(c.result.overlap, 0.4);
  EXPECT_GE(c.result.inliers, 30);
  std::printf("partial overlap: %d/%d inliers, %.3f deg, %.3f mm, overlap %.2f, rival %d\n",
              c.result.inliers, c.result.matches,
              RotationAngleRad(c.result.target_from_source, c.truth) * 180 / M_PI,
              TranslationDistanceMm(c.result.target_from_source, c.truth), c.result.overlap,
              c.result.rival_inliers);
}

TEST(AlignByFpfh, FailsCleanlyOnAPlane) {
  const Case c = Align([](double, double) { return 0.0; }, -15, 6, -6, 15, 8, SmallScaleOptions());
  EXPECT_FALSE(c.result.ok);
  EXPECT_EQ(c.result.reason.rfind("fpfh: ", 0), 0u) << c.result.reason;
  std::printf("plane: %s\n", c.result.reason.c_str());
}

// A surface of revolution (paraboloid bowl with a concentric ripple): any rotation about its axis
// fits; the descriptors only tell the radius.
TEST(AlignByFpfh, FailsCleanlyOnASurfaceOfRevolution) {
  const Height bowl = [](double x, double y) {
    const double r = std::hypot(x, y);
    return 0.03 * r * r + 0.4 * std::sin(1.5 * r);
  };
  const Case c = Align(bowl, -12, 12, -12, 12, 12, SmallScaleOptions());
  EXPECT_FALSE(c.result.ok);
  EXPECT_FALSE(c.result.reason.empty());
  std::printf("surface of revolution: %s\n", c.result.reason.c_str());
}

// Two-fold symmetric relief h(x, y) = f(x, y) + f(−x, −y), both views covering the symmetric
// square: the true pose and the one turned 180° about z explain the data equally well.
TEST(AlignByFpfh, FailsAsAmbiguousOnASymmetricScene) {
  const testing::HeightField hf(9, 40);
  const Height sym = [&](double x, double y) {
    return 0.5 * (hf.Height(x, y) + hf.Height(-x, -y));
  };
  const Case c = Align(sym, -10, 10, -10, 10, 10, SmallScaleOptions());
  EXPECT_FALSE(c.result.ok);
  EXPECT_NE(c.result.reason.find("ambiguous"), std::string::npos) << c.result.reason;
  std::printf("symmetric: %s\n", c.result.reason.c_str());
  // Without the ambiguity check one of the two poses comes back.
  FpfhOptions unchecked = SmallScaleOptions();
  unchecked.ambiguity_ratio = 0;
  const Case u = Align(sym, -10, 10, -10, 10, 10, unchecked);
  ASSERT_TRUE(u.result.ok) << u.result.reason;
}

// Hand-made features: source keypoints on a relief with a unique descriptor each; the target holds
// them at the true pose (30 of them with their own descriptor, the rest with unrelated ones) and a
// second copy 60 mm away, turned 180°, where 25 others keep their descriptor: a second consensus of
// 25 vs 30 inliers, far from the first. With the copy's normals turned with it, it explains the
// data as well (a symmetric scene): ambiguous. With its normals inside out, the verification
// cannot hold it, so it is no rival and the true pose comes back.
FpfhAlignResult AlignWithARivalCopy(bool rival_inside_out, Rigid3d* truth) {
  const testing::HeightField hf(9, 40);
  const SurfacePoints surface =
      SampleSurface([&](double x, double y) { return hf.Height(x, y); }, -10, 10, -10, 10, 1.0, 0.0,
                    0.0, 1, Rigid3d::Identity());
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> U(0, 100);
  const auto random_descriptor = [&] {
    FpfhDescriptor d;
    for (int k = 0; k < kFpfhSize; ++k) d[k] = U(rng);
    return d;
  };
  FpfhFeatures source, target;
  *truth = Pose(25, {0.2, 1, -0.3}, {4, -2, 30});
  const Rigid3d copy = *truth * Pose(180, {1, 0, 0.2}, {60, 0, 0});
  const int n = static_cast<int>(surface.size());
  std::vector<FpfhDescriptor> own(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) {
    own[static_cast<size_t>(i)] = random_descriptor();
    source.points.push_back(surface.points[static_cast<size_t>(i)]);
    source.normals.push_back(surface.normals[static_cast<size_t>(i)]);
    source.descriptors.push_back(own[static_cast<size_t>(i)]);
  }
  for (int pass = 0; pass < 2; ++pass) {
    const Rigid3d& pose = pass == 0 ? *truth : copy;
    const float normal_sign = pass == 1 && rival_inside_out ? -1.0f : 1.0f;
    for (int i = 0; i < n; ++i) {
      const bool kept = pass == 0 ? i % 7 == 0 && i / 7 < 30 : i % 7 == 3 && i / 7 < 25;
      target.points.push_back(
          (pose * surface.points[static_cast<size_t>(i)].cast<double>()).cast<float>());
      target.normals.push_back(
          normal_sign *
          (pose.linear() * surface.normals[static_cast<size_t>(i)].cast<double>()).cast<float>());
      target.descriptors.push_back(kept ? own[static_cast<size_t>(i)] : random_descriptor());
    }
  }
  return AlignByFpfh(source, target, SmallScaleOptions());
}

TEST(AlignByFpfh, ARivalConsensusCountsOnlyIfTheVerificationHoldsIt) {
  Rigid3d truth;
  const FpfhAlignResult symmetric = AlignWithARivalCopy(false, &truth);
  EXPECT_FALSE(symmetric.ok);
  EXPECT_NE(symmetric.reason.find("ambiguous"), std::string::npos) << symmetric.reason;
  EXPECT_TRUE(symmetric.rival_verified);
  // Both poses come back, for a caller with more evidence to settle between them.
  const Rigid3d copy = truth * Pose(180, {1, 0, 0.2}, {60, 0, 0});
  EXPECT_LT(TranslationDistanceMm(symmetric.target_from_source, truth), 0.05);
  EXPECT_LT(TranslationDistanceMm(symmetric.rival_target_from_source, copy), 0.05);
  EXPECT_LT(RotationAngleRad(symmetric.rival_target_from_source, copy) * 180 / M_PI, 0.1);
  const FpfhAlignResult inside_out = AlignWithARivalCopy(true, &truth);
  ASSERT_TRUE(inside_out.ok) << inside_out.reason;
  EXPECT_GE(inside_out.rival_inliers,
            0.6 * inside_out.inliers);  // large enough to have refused before
  EXPECT_FALSE(inside_out.rival_verified);
  EXPECT_LT(TranslationDistanceMm(inside_out.target_from_source, truth), 0.05);
  EXPECT_LT(RotationAngleRad(inside_out.target_from_source, truth) * 180 / M_PI, 0.1);
}

}  // namespace
}  // namespace d3d
