#include "pipeline/register/surface_points.h"

#include <gtest/gtest.h>

#include <limits>
#include <random>

namespace d3d {
namespace {

// An organised view whose pixel (r, c) holds the point (c, r, 10) mm, NaN at random pixels.
void View(std::mt19937* rng, int rows, int cols, cv::Mat* points, cv::Mat* normals,
          cv::Mat* quality) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::uniform_real_distribution<float> u(0, 1);
  points->create(rows, cols, CV_32FC3);
  normals->create(rows, cols, CV_32FC3);
  quality->create(rows, cols, CV_32F);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const bool hole = u(*rng) < 0.2f;
      points->at<cv::Vec3f>(r, c) =
          hole ? cv::Vec3f(nan, nan, nan)
               : cv::Vec3f(static_cast<float>(c), static_cast<float>(r), 10);
      normals->at<cv::Vec3f>(r, c) = cv::Vec3f(0, 0, -1);
      quality->at<float>(r, c) = 1.5f * u(*rng) - 0.25f;  // some outside [0, 1]: clamped
    }
}

TEST(SurfacePoints, SampleOrganisedVisitsRowsInterleavedAndRefillsABuffer) {
  std::mt19937 rng(7);
  SurfacePoints reused;  // one buffer for every view, as the tracker passes it
  for (const int stride : {1, 2, 3}) {
    cv::Mat P, N, Q;
    View(&rng, 23, 17, &P, &N, &Q);
    const SurfacePoints s = SampleOrganised(P, N, Q, stride);
    // Expected: rows 0, 2·stride, … then stride, 3·stride, …; columns on the lattice (odd lattice
    // rows offset by stride/2); holes skipped.
    std::vector<Eigen::Vector3f> want;
    std::vector<float> want_w;
    for (int first = 0; first <= stride; first += stride)
      for (int r = first; r < P.rows; r += 2 * stride)
        for (int c = (r / stride) % 2 ? stride / 2 : 0; c < P.cols; c += stride) {
          const cv::Vec3f p = P.at<cv::Vec3f>(r, c);
          if (!std::isfinite(p[0])) continue;
          want.emplace_back(p[0], p[1], p[2]);
          want_w.push_back(std::clamp(Q.at<float>(r, c), 0.0f, 1.0f));
        }
    EXPECT_EQ(s.points, want) << "stride " << stride;
    EXPECT_EQ(s.weights, want_w) << "stride " << stride;
    ASSERT_EQ(s.normals.size(), s.points.size());
    SampleOrganised(P, N, Q, stride, &reused);
    EXPECT_EQ(reused.points, s.points) << "stride " << stride;
    EXPECT_EQ(reused.normals, s.normals) << "stride " << stride;
    EXPECT_EQ(reused.weights, s.weights) << "stride " << stride;
  }
  cv::Mat P, N, Q;
  View(&rng, 8, 8, &P, &N, &Q);
  SampleOrganised(P, N, cv::Mat(), 1, &reused);  // no quality: the last view's weights go too
  EXPECT_TRUE(reused.weights.empty());
  EXPECT_EQ(reused.points.size(), reused.normals.size());
}

}  // namespace
}  // namespace d3d
