#include "pipeline/unwrap/edge_fill.h"

#include <gtest/gtest.h>

#include <cmath>

#include "pipeline/unwrap/quality_map.h"

namespace d3d {
namespace {

constexpr float kTwoPi = 6.28318530717958647692f;
constexpr uint8_t kEdge = static_cast<uint8_t>(QualityReason::kModulationEdge);

// A 1 × W row (or H × W image) with Φ = slope·x, all pixels anchored except the cut columns.
struct Scene {
  cv::Mat phi, B, reason, Phi, order, quality;
  Scene(int h, int w, float slope, float b) {
    phi.create(h, w, CV_32F);
    B = cv::Mat(h, w, CV_32F, cv::Scalar(b));
    reason = cv::Mat(h, w, CV_8U, cv::Scalar(0));
    Phi.create(h, w, CV_32F);
    order.create(h, w, CV_32S);
    quality = cv::Mat(h, w, CV_32F, cv::Scalar(0.8f));
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const float P = 20.0f + slope * x;
        Phi.at<float>(y, x) = P;
        phi.at<float>(y, x) = P - kTwoPi * std::floor(P / kTwoPi);
        order.at<int32_t>(y, x) = static_cast<int32_t>(std::floor(P / kTwoPi));
      }
  }
  void Cut(int x0, int x1) {  // columns [x0, x1) cut: no Φ, quality 0, reason edge
    for (int y = 0; y < Phi.rows; ++y)
      for (int x = x0; x < x1; ++x) {
        Phi.at<float>(y, x) = NAN;
        order.at<int32_t>(y, x) = -1;
        quality.at<float>(y, x) = 0;
        reason.at<uint8_t>(y, x) = kEdge;
      }
  }
};

TEST(EdgeFill, FillsTheCutFromTheAnchoredSideUpToPassesLayers) {
  Scene s(4, 40, 0.5f, 50);
  const cv::Mat truth = s.Phi.clone();
  s.Cut(10, 30);
  EdgeFillOptions o;
  o.passes = 3;
  EdgeFiller filler(o, UnwrapOptions{});
  EdgeFillStats st;
  ASSERT_TRUE(filler.Fill(s.phi, s.B, s.reason, {}, {}, &s.Phi, &s.order, &s.quality, &st).ok());
  // Layers 1..3 from each side: columns 10..12 and 27..29.
  EXPECT_EQ(st.pixels_filled, 4 * 6);
  for (int x = 10; x < 30; ++x) {
    const bool filled = x < 13 || x >= 27;
    EXPECT_EQ(std::isfinite(s.Phi.at<float>(1, x)), filled) << x;
    if (!filled) continue;
    EXPECT_NEAR(s.Phi.at<float>(1, x), truth.at<float>(1, x), 1e-4)
        << x;  // across order boundaries too
    EXPECT_EQ(s.order.at<int32_t>(1, x),
              static_cast<int32_t>(std::floor(truth.at<float>(1, x) / kTwoPi)))
        << x;
    EXPECT_FLOAT_EQ(s.quality.at<float>(1, x), o.quality_factor * 0.8f) << x;
  }
}

TEST(EdgeFill, StopsWhereTheModulationSteps) {
  // Beyond column 15 the modulation halves (an albedo border inside the cut): the fill from the
  // left reaches column 15 and no further; from the right it fills down to column 16.
  Scene s(3, 40, 0.4f, 60);
  for (int y = 0; y < 3; ++y)
    for (int x = 16; x < 40; ++x) s.B.at<float>(y, x) = 30;
  s.Cut(12, 20);
  EdgeFillOptions o;
  o.passes = 10;
  EdgeFiller filler(o, UnwrapOptions{});
  ASSERT_TRUE(filler.Fill(s.phi, s.B, s.reason, {}, {}, &s.Phi, &s.order, &s.quality).ok());
  for (int x = 12; x < 20; ++x) EXPECT_TRUE(std::isfinite(s.Phi.at<float>(1, x))) << x;
  // Now the right side carries a different order (a hidden step of one fringe at column 16, off
  // the middle of the cut 12..23): the left fill must not cross into it, and the right fill keeps
  // its own order.
  auto stepped = [](cv::Mat* truth) {
    Scene t(3, 40, 0.4f, 60);
    for (int y = 0; y < 3; ++y)
      for (int x = 16; x < 40; ++x) {
        t.B.at<float>(y, x) = 30;
        t.Phi.at<float>(y, x) += kTwoPi;  // same φ, one order more
        t.order.at<int32_t>(y, x) += 1;
      }
    *truth = t.Phi.clone();
    t.Cut(12, 24);
    return t;
  };
  cv::Mat truth;
  Scene t = stepped(&truth);
  ASSERT_TRUE(filler.Fill(t.phi, t.B, t.reason, {}, {}, &t.Phi, &t.order, &t.quality).ok());
  for (int x = 12; x < 24; ++x)
    EXPECT_NEAR(t.Phi.at<float>(1, x), truth.at<float>(1, x), 1e-4) << x;
  // Without the modulation test (a ratio above the step) the left side's order runs across the
  // step: the test is what separates them.
  Scene u = stepped(&truth);
  EdgeFillOptions loose = o;
  loose.max_modulation_ratio = 2.5;
  EdgeFiller loose_filler(loose, UnwrapOptions{});
  ASSERT_TRUE(loose_filler.Fill(u.phi, u.B, u.reason, {}, {}, &u.Phi, &u.order, &u.quality).ok());
  int off = 0;
  for (int x = 12; x < 24; ++x) off += std::abs(u.Phi.at<float>(1, x) - truth.at<float>(1, x)) > 1;
  EXPECT_GT(off, 0);
}

TEST(EdgeFill, RefusesDisagreeingNeighboursBackwardStepsAndTheVolume) {
  // A single cut pixel between two anchored pixels whose predictions disagree by a whole order.
  Scene s(1, 5, 0.3f, 50);
  s.Cut(2, 3);
  s.Phi.at<float>(0, 3) += kTwoPi;
  EdgeFiller filler(EdgeFillOptions{}, UnwrapOptions{});
  EdgeFillStats st;
  ASSERT_TRUE(filler.Fill(s.phi, s.B, s.reason, {}, {}, &s.Phi, &s.order, &s.quality, &st).ok());
  EXPECT_EQ(st.pixels_filled, 0);
  EXPECT_TRUE(std::isnan(s.Phi.at<float>(0, 2)));
  // Φ falling along x by more than max_reverse is a step the unwrapper would not cross (monotonic_x
  // = 1).
  Scene r(1, 6, -0.6f, 50);
  r.Cut(3, 6);
  ASSERT_TRUE(filler.Fill(r.phi, r.B, r.reason, {}, {}, &r.Phi, &r.order, &r.quality, &st).ok());
  EXPECT_EQ(st.pixels_filled, 0);
  // Outside the measurement volume: refused.
  Scene v(1, 6, 0.3f, 50);
  v.Cut(3, 6);
  cv::Mat lo(1, 6, CV_32F, cv::Scalar(0)), hi(1, 6, CV_32F, cv::Scalar(20.5f));
  ASSERT_TRUE(filler.Fill(v.phi, v.B, v.reason, lo, hi, &v.Phi, &v.order, &v.quality, &st).ok());
  EXPECT_EQ(st.pixels_filled, 0);
}

TEST(EdgeFill, OnlyCutPixelsAreFilledAndBadInputIsRefused) {
  Scene s(2, 8, 0.3f, 50);
  s.Cut(4, 8);
  for (int y = 0; y < 2; ++y)
    s.reason.at<uint8_t>(y, 4) = static_cast<uint8_t>(QualityReason::kPhaseNoise);
  EdgeFiller filler(EdgeFillOptions{}, UnwrapOptions{});
  EdgeFillStats st;
  ASSERT_TRUE(filler.Fill(s.phi, s.B, s.reason, {}, {}, &s.Phi, &s.order, &s.quality, &st).ok());
  EXPECT_EQ(st.pixels_filled, 0);  // column 4 is not a cut pixel and the rest is out of reach
  cv::Mat wrong(3, 8, CV_32F, cv::Scalar(0));
  EXPECT_FALSE(filler.Fill(s.phi, wrong, s.reason, {}, {}, &s.Phi, &s.order, &s.quality).ok());
  EXPECT_FALSE(filler.Fill(s.phi, s.B, s.reason, {}, {}, nullptr, &s.order, &s.quality).ok());
  EdgeFillOptions bad;
  bad.max_modulation_ratio = 1.0;
  EXPECT_THROW(EdgeFiller(bad, UnwrapOptions{}), std::invalid_argument);
  bad = EdgeFillOptions{};
  bad.quality_factor = 0;
  EXPECT_THROW(EdgeFiller(bad, UnwrapOptions{}), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
