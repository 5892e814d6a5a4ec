#include "pipeline/register/features.h"

#include <gtest/gtest.h>

#include "pipeline/register/test_surfaces.h"

namespace d3d {
namespace {

using namespace d3d::testing;

TEST(Features, TextureAndRangeSiftRecoverAKnownMotion) {
  const HeightField hf(21);
  const auto cam = TestCamera(480, 360, 1500);
  const Rigid3d wa = LookDown(0, 0, 30), wb = LookDown(2.0, 0.8, 30.5, 0.08, -0.06, 0.35);
  const auto va = RenderHeightField(hf, cam, wa, 0.003, 1),
             vb = RenderHeightField(hf, cam, wb, 0.003, 2);
  const ViewFeatures fa = ExtractViewFeatures(va.points, va.texture),
                     fb = ExtractViewFeatures(vb.points, vb.texture);
  ASSERT_GT(fa.texture_points.size(), 20u);
  const FeatureAlignResult r = AlignByFeatures(fb, fa);
  ASSERT_TRUE(r.ok) << r.reason;
  const Rigid3d truth = wa.inverse() * wb;
  EXPECT_LT(RotationAngleRad(r.target_from_source, truth) * 180 / M_PI, 0.5);
  EXPECT_LT(TranslationDistanceMm(r.target_from_source, truth), 0.1);
}

// SIFT on the half-size images (the tracker's image_scale) finds the same keypoints as on the full
// ones: the features of one view at both scales align it onto itself (a keypoint mapped back to the
// wrong pixels, e.g. without the factor 2, lifts to the wrong 3-D point and this fails).
TEST(Features, HalfScaleKeypointsMapBackToTheirPixels) {
  const HeightField hf(23);
  const auto cam = TestCamera(480, 360, 1500);
  const auto v = RenderHeightField(hf, cam, LookDown(0, 0, 30), 0.003, 1);
  FeatureOptions full, half;
  full.image_scale = 1.0;
  half.image_scale = 0.5;
  const ViewFeatures ff = ExtractViewFeatures(v.points, v.texture, full),
                     fh = ExtractViewFeatures(v.points, v.texture, half);
  ASSERT_GT(fh.texture_points.size(), 20u);
  const FeatureAlignResult r = AlignByFeatures(fh, ff, half);
  ASSERT_TRUE(r.ok) << r.reason;
  EXPECT_GT(r.inliers, 20);
  EXPECT_LT(RotationAngleRad(r.target_from_source, Rigid3d::Identity()) * 180 / M_PI, 0.1);
  EXPECT_LT(TranslationDistanceMm(r.target_from_source, Rigid3d::Identity()), 0.02);
  FeatureOptions bad = half;
  bad.image_scale = 0.0;
  EXPECT_THROW(bad.Check(), std::invalid_argument);
}

TEST(Features, DisjointViewsFailCleanly) {
  const HeightField hf(22);
  const auto cam = TestCamera(480, 360, 1500);
  const auto va = RenderHeightField(hf, cam, LookDown(-15, 0, 30), 0.003, 1);
  const auto vb = RenderHeightField(hf, cam, LookDown(15, 0, 30), 0.003, 2);
  const FeatureAlignResult r = AlignByFeatures(ExtractViewFeatures(vb.points, vb.texture),
                                               ExtractViewFeatures(va.points, va.texture));
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.reason.find("features:"), std::string::npos);
}

}  // namespace
}  // namespace d3d
