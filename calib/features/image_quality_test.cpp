#include "calib/features/image_quality.h"

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>
#include <random>

#include "calib/features/synthetic_target.h"

namespace d3d {
namespace {

cv::Mat Board(double blur, double noise, uint64_t seed = 3) {
  CalibrationTarget t;
  EXPECT_TRUE(ParseTarget("chessboard:9x6:10", &t).ok());
  PinholeBrownConrady cam{640, 480, 800, 800, 320, 240, 0, 0, 0, 0, 0};
  Rigid3d pose = Rigid3d::Identity();
  pose.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 1, 0).normalized()).toRotationMatrix();
  pose.translation() = Eigen::Vector3d(-40, -25, 180);
  SyntheticImageOptions o;
  o.blur_sigma_px = blur;
  o.noise_dn = noise;
  o.seed = seed;
  o.supersample = 3;
  return RenderSyntheticTarget(t, cam, pose, o);
}

TEST(ImageQuality, MeasuresBlurAndNoise) {
  const ImageQuality sharp = AssessImage(Board(0.8, 1.0));
  EXPECT_TRUE(sharp.accepted) << sharp.reason;
  EXPECT_NEAR(sharp.edge_blur_px, 0.9, 0.35);  // blur σ 0.8 plus the pixel's footprint
  EXPECT_NEAR(sharp.noise_dn, 1.0, 0.3);
  const ImageQuality noisy = AssessImage(Board(0.8, 4.0));
  EXPECT_NEAR(noisy.noise_dn, 4.0, 0.6);
  EXPECT_TRUE(noisy.accepted);
  const ImageQuality blurred = AssessImage(Board(3.0, 1.0));
  EXPECT_NEAR(blurred.edge_blur_px, 3.0, 0.6);
}

TEST(ImageQuality, RejectsWithReasons) {
  const ImageQuality blurred = AssessImage(Board(4.0, 1.0));
  EXPECT_FALSE(blurred.accepted);
  EXPECT_NE(blurred.reason.find("blurred"), std::string::npos) << blurred.reason;
  const ImageQuality noisy = AssessImage(Board(0.8, 10.0));
  EXPECT_FALSE(noisy.accepted);
  EXPECT_NE(noisy.reason.find("noisy"), std::string::npos) << noisy.reason;
  const ImageQuality flat = AssessImage(cv::Mat(100, 100, CV_8U, cv::Scalar(128)));
  EXPECT_FALSE(flat.accepted);
  EXPECT_NE(flat.reason.find("contrast"), std::string::npos) << flat.reason;
}

}  // namespace
}  // namespace d3d
