#include "pipeline/unwrap/quality_map.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace d3d {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// Wrapped linear ramp Φ = a·x + b·y + c, wrapped to [0, 2π).
cv::Mat Ramp(int w, int h, double a, double b, double c = 0.3) {
  cv::Mat phi(h, w, CV_32FC1);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const double v = a * x + b * y + c;
      phi.at<float>(y, x) = static_cast<float>(v - 2 * M_PI * std::floor(v / (2 * M_PI)));
    }
  }
  return phi;
}

cv::Mat Const(int w, int h, float v) { return cv::Mat(h, w, CV_32FC1, cv::Scalar(v)); }

bool AllFinite(const cv::Mat& m) { return cv::checkRange(m, true, nullptr, -1e30, 1e30); }

TEST(QualityMap, SmoothRampHasModulationQuality) {
  const cv::Mat phi = Ramp(40, 30, 0.27, 0.05);
  cv::Mat q, why;
  QualityOptions opt;
  ASSERT_TRUE(ComputeQualityMap(phi, Const(40, 30, 12.0f), cv::Mat(), opt, &q, &why).ok());
  ASSERT_EQ(q.type(), CV_32FC1);
  // Interior and border pixels: D = 0 (a linear ramp has zero second differences).
  for (int y = 0; y < 30; ++y) {
    for (int x = 0; x < 40; ++x) {
      EXPECT_NEAR(q.at<float>(y, x), 12.0 / opt.full_modulation, 1e-4) << x << "," << y;
      EXPECT_EQ(why.at<uint8_t>(y, x), static_cast<uint8_t>(QualityReason::kUsable));
    }
  }
  // Full modulation: quality 1.
  ASSERT_TRUE(ComputeQualityMap(phi, Const(40, 30, 100.0f), cv::Mat(), opt, &q).ok());
  EXPECT_NEAR(q.at<float>(10, 10), 1.0f, 1e-4);
}

TEST(QualityMap, AcceptsAtan2RangeLikeZeroTo2Pi) {
  cv::Mat phi = Ramp(30, 20, 0.4, 0.1);
  cv::Mat shifted = phi.clone();
  for (auto it = shifted.begin<float>(); it != shifted.end<float>(); ++it) {
    if (*it >= M_PI) *it -= static_cast<float>(2 * M_PI);  // (−π, π]
  }
  cv::Mat q1, q2;
  ASSERT_TRUE(ComputeQualityMap(phi, Const(30, 20, 30.0f), cv::Mat(), {}, &q1).ok());
  ASSERT_TRUE(ComputeQualityMap(shifted, Const(30, 20, 30.0f), cv::Mat(), {}, &q2).ok());
  EXPECT_LT(cv::norm(q1, q2, cv::NORM_INF), 1e-3);
}

TEST(QualityMap, NoiseLowersQuality) {
  cv::Mat phi = Ramp(64, 64, 0.27, 0.0);
  cv::Mat noisy = phi.clone();
  cv::RNG rng(3);
  for (auto it = noisy.begin<float>(); it != noisy.end<float>(); ++it) {
    float v = *it + static_cast<float>(rng.gaussian(0.3));
    v -= static_cast<float>(2 * M_PI * std::floor(v / (2 * M_PI)));
    *it = v >= 2 * M_PI ? 0.0f : v;
  }
  cv::Mat q0, q1;
  ASSERT_TRUE(ComputeQualityMap(phi, Const(64, 64, 40.0f), cv::Mat(), {}, &q0).ok());
  ASSERT_TRUE(ComputeQualityMap(noisy, Const(64, 64, 40.0f), cv::Mat(), {}, &q1).ok());
  EXPECT_NEAR(cv::mean(q0)[0], 1.0, 1e-4);
  // σ = 0.3 rad: E[D²] = 12σ² = 1.08 = 3·laplace_ref², so Q_L ≈ 1/4 on average or masked.
  EXPECT_LT(cv::mean(q1)[0], 0.5);
  EXPECT_TRUE(AllFinite(q1));
}

TEST(QualityMap, MarksPhaseJumpOfDepthStep) {
  // A step of 2.4 fringes at x = 20: the wrapped difference there is 0.27 + 0.4·2π.
  cv::Mat phi(20, 40, CV_32FC1);
  for (int y = 0; y < 20; ++y) {
    for (int x = 0; x < 40; ++x) {
      double v = 0.27 * x + (x >= 20 ? 2.4 * 2 * M_PI : 0.0);
      phi.at<float>(y, x) = static_cast<float>(v - 2 * M_PI * std::floor(v / (2 * M_PI)));
    }
  }
  cv::Mat q, why;
  ASSERT_TRUE(ComputeQualityMap(phi, Const(40, 20, 40.0f), cv::Mat(), {}, &q, &why).ok());
  for (int y = 0; y < 20; ++y) {
    EXPECT_EQ(q.at<float>(y, 19), 0.0f);
    EXPECT_EQ(q.at<float>(y, 20), 0.0f);
    EXPECT_EQ(why.at<uint8_t>(y, 19), static_cast<uint8_t>(QualityReason::kPhaseNoise));
    EXPECT_NEAR(q.at<float>(y, 10), 1.0f, 1e-4);
    EXPECT_NEAR(q.at<float>(y, 30), 1.0f, 1e-4);
  }
}

TEST(QualityMap, MarksModulationEdge) {
  // Smooth phase, B steps from 40 to 20 DN between rows 9 and 10 (tooth → gingiva albedo): the
  // pixels beside the step are cut; a slow B gradient (10 % per pixel) is not.
  const cv::Mat phi = Ramp(40, 20, 0.27, 0.05);
  cv::Mat b(20, 40, CV_32FC1);
  for (int y = 0; y < 20; ++y) {
    for (int x = 0; x < 40; ++x)
      b.at<float>(y, x) = (y < 10 ? 40.0f : 20.0f) * std::pow(1.05f, x * 0.5f);
  }
  cv::Mat q, why;
  ASSERT_TRUE(ComputeQualityMap(phi, b, cv::Mat(), {}, &q, &why).ok());
  for (int x = 0; x < 40; ++x) {
    EXPECT_EQ(q.at<float>(9, x), 0.0f);
    EXPECT_EQ(q.at<float>(10, x), 0.0f);
    EXPECT_EQ(why.at<uint8_t>(9, x), static_cast<uint8_t>(QualityReason::kModulationEdge));
    EXPECT_GT(q.at<float>(5, x), 0.9f);
    EXPECT_GT(q.at<float>(15, x), 0.5f);
  }
  // Off: no cut.
  QualityOptions off;
  off.modulation_edge_ratio = 0;
  ASSERT_TRUE(ComputeQualityMap(phi, b, cv::Mat(), off, &q, &why).ok());
  EXPECT_GT(q.at<float>(9, 20), 0.5f);
  EXPECT_GT(q.at<float>(10, 20), 0.5f);
}

TEST(QualityMap, BridgesOnePixelGapsOfAModulationEdge) {
  // One dark pixel (B 20 in 40) at (9, 19): its four neighbours see a B step across themselves and
  // are edge pixels; the pixel itself sees equal neighbours (a one-pixel gap between edge pixels)
  // and is bridged only with modulation_edge_close.
  const cv::Mat phi = Ramp(40, 20, 0.27, 0.05);
  cv::Mat b = Const(40, 20, 40.0f);
  b.at<float>(9, 19) = 20.0f;
  cv::Mat q, why;
  ASSERT_TRUE(ComputeQualityMap(phi, b, cv::Mat(), {}, &q, &why).ok());
  EXPECT_EQ(why.at<uint8_t>(9, 18), static_cast<uint8_t>(QualityReason::kModulationEdge));
  EXPECT_EQ(why.at<uint8_t>(9, 20), static_cast<uint8_t>(QualityReason::kModulationEdge));
  EXPECT_EQ(why.at<uint8_t>(9, 19), static_cast<uint8_t>(QualityReason::kUsable));
  QualityOptions bridge;
  bridge.modulation_edge_close = 1;
  ASSERT_TRUE(ComputeQualityMap(phi, b, cv::Mat(), bridge, &q, &why).ok());
  EXPECT_EQ(why.at<uint8_t>(9, 19), static_cast<uint8_t>(QualityReason::kModulationEdge));
  EXPECT_EQ(q.at<float>(9, 19), 0.0f);
  EXPECT_EQ(why.at<uint8_t>(2, 5), static_cast<uint8_t>(QualityReason::kUsable));  // far: untouched
}

TEST(QualityMap, Masks) {
  const int w = 20, h = 10;
  cv::Mat phi = Ramp(w, h, 0.3, 0.1);
  cv::Mat b = Const(w, h, 30.0f);
  cv::Mat valid(h, w, CV_8UC1, cv::Scalar(255));
  cv::Mat peak(h, w, CV_8UC1, cv::Scalar(200));
  phi.at<float>(1, 1) = kNaN;    // invalid (NaN phase)
  valid.at<uint8_t>(1, 3) = 0;   // invalid (mask)
  b.at<float>(1, 5) = 1.0f;      // shadow
  b.at<float>(1, 7) = 3.0f;      // low modulation
  peak.at<uint8_t>(1, 9) = 255;  // saturated
  b.at<float>(1, 11) = kNaN;     // invalid (NaN modulation)
  // An isolated pixel: all four neighbours invalid.
  valid.at<uint8_t>(6, 14) = valid.at<uint8_t>(8, 14) = valid.at<uint8_t>(7, 13) =
      valid.at<uint8_t>(7, 15) = 0;
  cv::Mat q, why;
  ASSERT_TRUE(ComputeQualityMap(phi, b, valid, peak, {}, &q, &why).ok());
  auto reason = [&](int y, int x) { return static_cast<QualityReason>(why.at<uint8_t>(y, x)); };
  EXPECT_EQ(reason(1, 1), QualityReason::kInvalid);
  EXPECT_EQ(reason(1, 3), QualityReason::kInvalid);
  EXPECT_EQ(reason(1, 5), QualityReason::kShadow);
  EXPECT_EQ(reason(1, 7), QualityReason::kLowModulation);
  EXPECT_EQ(reason(1, 9), QualityReason::kSaturated);
  EXPECT_EQ(reason(1, 11), QualityReason::kInvalid);
  EXPECT_EQ(reason(7, 14), QualityReason::kIsolated);
  EXPECT_EQ(reason(5, 5), QualityReason::kUsable);
  for (auto [y, x] : {std::pair{1, 1}, {1, 3}, {1, 5}, {1, 7}, {1, 9}, {1, 11}, {7, 14}}) {
    EXPECT_EQ(q.at<float>(y, x), 0.0f);
  }
  EXPECT_GT(q.at<float>(5, 5), 0.9f);
  EXPECT_TRUE(AllFinite(q));
  // Without the peak image, saturation is not tested; a CV_32F peak works as well.
  ASSERT_TRUE(ComputeQualityMap(phi, b, valid, {}, &q, &why).ok());
  EXPECT_EQ(reason(1, 9), QualityReason::kUsable);
  cv::Mat peak32;
  peak.convertTo(peak32, CV_32F);
  ASSERT_TRUE(ComputeQualityMap(phi, b, valid, peak32, {}, &q, &why).ok());
  EXPECT_EQ(reason(1, 9), QualityReason::kSaturated);
}

TEST(QualityMap, AllInvalidGivesZeros) {
  cv::Mat phi(8, 8, CV_32FC1, cv::Scalar(kNaN));
  cv::Mat q;
  ASSERT_TRUE(ComputeQualityMap(phi, Const(8, 8, 50.0f), cv::Mat(), {}, &q).ok());
  EXPECT_EQ(cv::countNonZero(q), 0);
}

TEST(QualityMap, BadInputs) {
  const cv::Mat phi = Ramp(10, 8, 0.3, 0.0);
  const cv::Mat b = Const(10, 8, 20.0f);
  cv::Mat q;
  EXPECT_EQ(ComputeQualityMap(cv::Mat(), b, cv::Mat(), {}, &q).code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(ComputeQualityMap(phi, Const(9, 8, 1.0f), cv::Mat(), {}, &q).code(),
            StatusCode::kInvalidArgument);
  cv::Mat b64;
  b.convertTo(b64, CV_64F);
  EXPECT_EQ(ComputeQualityMap(phi, b64, cv::Mat(), {}, &q).code(), StatusCode::kInvalidArgument);
  cv::Mat phi64;
  phi.convertTo(phi64, CV_64F);
  EXPECT_EQ(ComputeQualityMap(phi64, b, cv::Mat(), {}, &q).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(ComputeQualityMap(phi, b, cv::Mat(8, 10, CV_32FC1), {}, &q).code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(ComputeQualityMap(phi, b, cv::Mat(7, 10, CV_8UC1), {}, &q).code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(ComputeQualityMap(phi, b, cv::Mat(), cv::Mat(8, 10, CV_16UC1), {}, &q).code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(ComputeQualityMap(phi, b, cv::Mat(), {}, nullptr).code(), StatusCode::kInvalidArgument);
  cv::Mat alias = phi.clone();
  EXPECT_EQ(ComputeQualityMap(alias, b, cv::Mat(), {}, &alias).code(),
            StatusCode::kInvalidArgument);
  QualityOptions bad;
  bad.min_modulation = 50.0;  // > full_modulation
  EXPECT_EQ(ComputeQualityMap(phi, b, cv::Mat(), bad, &q).code(), StatusCode::kInvalidArgument);
  EXPECT_THROW(bad.Check(), std::invalid_argument);
  bad = {};
  bad.laplace_ref = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(bad.Check(), std::invalid_argument);
  EXPECT_NO_THROW(QualityOptions{}.Check());
}

TEST(QualityMap, NonContinuousInputs) {
  cv::Mat big = Ramp(50, 40, 0.3, 0.05);
  cv::Mat roi = big(cv::Rect(5, 5, 30, 20));
  cv::Mat bbig = Const(50, 40, 30.0f);
  cv::Mat q_roi, q_copy;
  ASSERT_TRUE(ComputeQualityMap(roi, bbig(cv::Rect(5, 5, 30, 20)), cv::Mat(), {}, &q_roi).ok());
  ASSERT_TRUE(ComputeQualityMap(roi.clone(), Const(30, 20, 30.0f), cv::Mat(), {}, &q_copy).ok());
  EXPECT_EQ(cv::norm(q_roi, q_copy, cv::NORM_INF), 0.0);
}

}  // namespace
}  // namespace d3d
