#include "calib/projector/projector_mapping.h"

#include <gtest/gtest.h>

#include <random>

namespace d3d {
namespace {

// Frames of an N-step multi-frequency set over a known projector coordinate map c(x, y), with
// offset A, modulation B·albedo and seeded noise.
std::vector<cv::Mat> Frames(const cv::Mat& coord, const cv::Mat& albedo,
                            const PhaseDecodeOptions& o, double noise, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> n(0.0, noise);
  std::vector<cv::Mat> frames;
  for (double T : o.periods_px)
    for (int s = 0; s < o.steps; ++s) {
      cv::Mat f(coord.size(), CV_8U);
      for (int r = 0; r < coord.rows; ++r)
        for (int c = 0; c < coord.cols; ++c) {
          const double p =
              0.5 + 0.5 * std::cos(2 * M_PI * coord.at<float>(r, c) / T - 2 * M_PI * s / o.steps);
          const double v = albedo.at<float>(r, c) * (20 + 200 * p) + n(rng);
          f.at<uint8_t>(r, c) = static_cast<uint8_t>(std::clamp(std::lround(v), 0L, 255L));
        }
      frames.push_back(f);
    }
  return frames;
}

// A smooth projective map camera → projector (a plane seen by both).
Eigen::Vector2d Truth(double x, double y) {
  const double w = 1.0 + 1e-4 * x - 5e-5 * y;
  return {(1.05 * x + 0.03 * y + 40.0) / w, (-0.02 * x + 1.1 * y + 60.0) / w};
}

TEST(DecodeProjectorCoordinate, RecoversAbsoluteCoordinates) {
  PhaseDecodeOptions o;
  cv::Mat u(120, 160, CV_32F), v(120, 160, CV_32F), albedo(120, 160, CV_32F, cv::Scalar(1.0f));
  for (int r = 0; r < u.rows; ++r)
    for (int c = 0; c < u.cols; ++c) {
      const Eigen::Vector2d t = Truth(c * 5.0, r * 8.0);  // spans ~850 × 1000 projector px
      u.at<float>(r, c) = static_cast<float>(t.x());
      v.at<float>(r, c) = static_cast<float>(t.y());
    }
  ProjectorCoordinateMap mu, mv;
  ASSERT_TRUE(DecodeProjectorCoordinate(Frames(u, albedo, o, 1.0, 1), o, &mu).ok());
  ASSERT_TRUE(DecodeProjectorCoordinate(Frames(v, albedo, o, 1.0, 2), o, &mv).ok());
  double sq = 0, worst = 0;
  for (int r = 0; r < u.rows; ++r)
    for (int c = 0; c < u.cols; ++c) {
      const double e = mu.coord_px.at<float>(r, c) - u.at<float>(r, c);
      sq += e * e;
      worst = std::max(worst, std::abs(e));
    }
  const double rms = std::sqrt(sq / u.total());
  std::printf("decoded u: RMS %.4f px, worst %.3f px\n", rms, worst);
  EXPECT_LT(rms, 0.05);
  EXPECT_LT(worst, 0.5);  // no fringe-order errors
  std::vector<cv::Mat> too_few(3, cv::Mat(10, 10, CV_8U));
  EXPECT_FALSE(DecodeProjectorCoordinate(too_few, o, &mu).ok());
}

TEST(MapFeaturesToProjector, InterpolatesAcrossDarkBlobs) {
  PhaseDecodeOptions o;
  const int W = 320, H = 240;
  cv::Mat u(H, W, CV_32F), v(H, W, CV_32F), albedo(H, W, CV_32F, cv::Scalar(1.0f));
  std::vector<Eigen::Vector2d> centres;
  for (int j = 0; j < 3; ++j)
    for (int i = 0; i < 4; ++i) centres.emplace_back(60.3 + 65 * i, 50.7 + 65 * j);
  for (int r = 0; r < H; ++r)
    for (int c = 0; c < W; ++c) {
      const Eigen::Vector2d t = Truth(c, r);
      u.at<float>(r, c) = static_cast<float>(t.x());
      v.at<float>(r, c) = static_cast<float>(t.y());
      for (const auto& q : centres)
        if ((Eigen::Vector2d(c, r) - q).norm() < 12) albedo.at<float>(r, c) = 0.06f;  // black print
    }
  ProjectorCoordinateMap mu, mv;
  ASSERT_TRUE(DecodeProjectorCoordinate(Frames(u, albedo, o, 1.0, 3), o, &mu).ok());
  ASSERT_TRUE(DecodeProjectorCoordinate(Frames(v, albedo, o, 1.0, 4), o, &mv).ok());
  FeatureMappingOptions fo;
  fo.window_radius_px = 30;
  const auto mapped = MapFeaturesToProjector(mu, mv, centres, fo);
  double sq = 0;
  for (size_t i = 0; i < centres.size(); ++i) {
    ASSERT_TRUE(mapped[i].ok) << mapped[i].reason;
    sq += (mapped[i].projector_px - Truth(centres[i].x(), centres[i].y())).squaredNorm();
  }
  const double rms = std::sqrt(sq / centres.size());
  std::printf("mapped features: RMS %.4f projector px\n", rms);
  EXPECT_LT(rms, 0.02);
  // A feature at the border has too few samples: a reason, not a value.
  const auto border = MapFeaturesToProjector(mu, mv, {Eigen::Vector2d(-25, -25)}, fo);
  EXPECT_FALSE(border[0].ok);
  EXPECT_FALSE(border[0].reason.empty());
}

}  // namespace
}  // namespace d3d
