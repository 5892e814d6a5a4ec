#include "pipeline/triangulate/triangulate.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>

#include "sim/render/test_scenes.h"
#include "sim/render/virtual_probe.h"

namespace d3d {
namespace {

// Truth Φ from the renderer's projector coordinate, back through the triangulator: the points must
// come back to the truth surface points (both use the same calibration, exactly).
void ExpectRoundTrip(VirtualProbe& probe, int* checked) {
  FrameTruth t;
  probe.RenderTruth(Rigid3d::Identity(), &t);
  const PhaseTriangulator tri(probe.calibration());
  cv::Mat Phi(t.depth_mm.size(), CV_32F, cv::Scalar(std::nan("")));
  for (int r = 0; r < Phi.rows; ++r)
    for (int c = 0; c < Phi.cols; ++c)
      if (t.visibility.at<uint8_t>(r, c) == 2) {
        Phi.at<float>(r, c) = static_cast<float>(
            probe.calibration().pattern.AbsolutePhase(t.projector_uv.at<cv::Vec2f>(r, c)[0]));
      }
  cv::Mat points;
  ASSERT_TRUE(tri.Triangulate(Phi, &points).ok());
  double worst = 0;
  for (int r = 0; r < Phi.rows; ++r)
    for (int c = 0; c < Phi.cols; ++c) {
      if (std::isnan(Phi.at<float>(r, c))) {
        EXPECT_TRUE(std::isnan(points.at<cv::Vec3f>(r, c)[2]));
        continue;
      }
      const float z = t.depth_mm.at<float>(r, c);
      if (z < 40 || z > 60)
        continue;  // outside the measurement volume (+margin): dropped by design
      const cv::Vec3f d = points.at<cv::Vec3f>(r, c) - t.points_in_cam.at<cv::Vec3f>(r, c);
      worst = std::max(worst, static_cast<double>(cv::norm(d)));
      ++*checked;
    }
  // Float32 Φ at ≈ 200 rad carries 1e-5 rad ≈ 1e-4 mm of depth; the solve itself is exact.
  EXPECT_LT(worst, 2e-4) << "mm";
}

TEST(Triangulate, PlaneRoundTripThroughBothDistortions) {
  RenderOptions o;
  o.texture = false;
  VirtualProbe probe(PlaneMesh({0.3, -0.2, -1}, {0, 0, 50}), MakeDefaultProbeDesign(), o);
  int checked = 0;
  ExpectRoundTrip(probe, &checked);
  EXPECT_GT(checked, 100000);
}

TEST(Triangulate, SphereRoundTrip) {
  RenderOptions o;
  o.texture = false;
  VirtualProbe probe(PlaneMesh({0, 0, -1}, {0, 0, 57}), MakeDefaultProbeDesign(), o,
                     {SceneSphere{{0.5, -0.3, 50.0}, 5.0, SurfaceLabel::kTooth}});
  int checked = 0;
  ExpectRoundTrip(probe, &checked);
  EXPECT_GT(checked, 50000);
}

TEST(Triangulate, PhaseRangeBracketsTruthAndAdmitsFewOrders) {
  const ProbeDesign design = MakeDefaultProbeDesign();
  const PhaseTriangulator tri(design.calibration);
  cv::Mat lo, hi;
  tri.PhaseRange(&lo, &hi);
  for (int r = 0; r < 480; r += 40)
    for (int c = 0; c < 640; c += 40) {
      ASSERT_FALSE(std::isnan(lo.at<float>(r, c))) << r << "," << c;
      const double mid = tri.PhaseAtDepth(c, r, 50.0);
      EXPECT_GT(mid, lo.at<float>(r, c));
      EXPECT_LT(mid, hi.at<float>(r, c));
      const double orders = (hi.at<float>(r, c) - lo.at<float>(r, c)) / (2 * M_PI);
      EXPECT_GT(orders, 4.0);
      // The marker stripes are 10 orders apart: the volume must admit fewer than that.
      EXPECT_LT(orders, design.calibration.pattern.marker_spacing_orders - 1.0);
      EXPECT_NEAR(tri.DepthForPhase(c, r, mid), 50.0, 1e-6);
    }
}

TEST(Triangulate, FastPathMatchesTheExactSolver) {
  const PhaseTriangulator tri(MakeDefaultProbeDesign().calibration);
  cv::Mat lo, hi;
  tri.PhaseRange(&lo, &hi);
  // Every pixel, a phase spread over its admissible range (the whole measurement volume).
  cv::Mat Phi(480, 640, CV_32F, cv::Scalar(std::nan("")));
  for (int r = 0; r < 480; ++r)
    for (int c = 0; c < 640; ++c) {
      const double s = ((r * 640 + c) % 97) / 96.0;
      if (std::isfinite(lo.at<float>(r, c)))
        Phi.at<float>(r, c) =
            lo.at<float>(r, c) + static_cast<float>(s) * (hi.at<float>(r, c) - lo.at<float>(r, c));
    }
  cv::Mat points;
  ASSERT_TRUE(tri.Triangulate(Phi, &points).ok());
  double worst = 0;
  int compared = 0;
  for (int r = 0; r < 480; ++r)
    for (int c = 0; c < 640; ++c) {
      const float phi = Phi.at<float>(r, c);
      if (std::isnan(phi)) continue;
      const double exact = tri.DepthForPhase(c, r, phi);
      const float fast = points.at<cv::Vec3f>(r, c)[2];
      ASSERT_EQ(std::isfinite(exact), std::isfinite(fast)) << r << "," << c;
      if (!std::isfinite(exact)) continue;
      worst = std::max(worst, std::abs(exact - fast));
      ++compared;
      if ((r * 640 + c) % 101 == 0) {  // the one-pixel call gives Triangulate's point
        const Eigen::Vector3d p = tri.PointForPhase(c, r, phi);
        const cv::Vec3f& q = points.at<cv::Vec3f>(r, c);
        ASSERT_LT((p - Eigen::Vector3d(q[0], q[1], q[2])).norm(), 1e-5) << r << "," << c;
      }
    }
  EXPECT_GT(compared, 250000);
  EXPECT_FALSE(tri.PointForPhase(-1, 0, 10.0).allFinite());
  EXPECT_FALSE(tri.PointForPhase(0, 0, std::nan("")).allFinite());
  std::printf("[ fast     ] fast path on %.1f %% of the pixels, worst |fast - exact| %.2e mm\n",
              100.0 * tri.FastPathShare(), worst);
  EXPECT_LT(worst, 1e-4) << "mm (float32 output is ~4e-6 mm at 50 mm)";
}

TEST(Triangulate, RefusesMismatchedMapsAndDropsOutOfVolume) {
  const PhaseTriangulator tri(MakeDefaultProbeDesign().calibration);
  cv::Mat points;
  EXPECT_EQ(tri.Triangulate(cv::Mat(10, 10, CV_32F), &points).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(tri.Triangulate(cv::Mat(480, 640, CV_64F), &points).code(),
            StatusCode::kInvalidArgument);
  // A phase that would put the point at 30 mm is dropped, not returned.
  EXPECT_TRUE(std::isnan(tri.DepthForPhase(320, 240, tri.PhaseAtDepth(320, 240, 30.0))));
  EXPECT_TRUE(std::isnan(tri.DepthForPhase(320, 240, std::nan(""))));
}

TEST(Triangulate, OrganisedNormalsOfAPlane) {
  const Eigen::Vector3d n = Eigen::Vector3d(0.2, 0.1, -1).normalized();
  cv::Mat points(50, 60, CV_32FC3);
  for (int r = 0; r < 50; ++r)
    for (int c = 0; c < 60; ++c) {
      const Eigen::Vector3d ray((c - 30) * 0.0005, (r - 25) * 0.0005, 1.0);
      const Eigen::Vector3d p = ray * (n.dot(Eigen::Vector3d(0, 0, 50)) / n.dot(ray));
      points.at<cv::Vec3f>(r, c) = cv::Vec3f(p.x(), p.y(), p.z());
    }
  points.at<cv::Vec3f>(10, 10) = cv::Vec3f(std::nanf(""), 0, 0);
  cv::Mat normals;
  OrganisedNormals(points, 0.5, &normals);
  const cv::Vec3f m = normals.at<cv::Vec3f>(25, 30);
  EXPECT_NEAR(m[0] * n.x() + m[1] * n.y() + m[2] * n.z(), 1.0, 1e-5);
  EXPECT_TRUE(std::isnan(normals.at<cv::Vec3f>(10, 11)[0]));  // next to a hole
  EXPECT_TRUE(std::isnan(normals.at<cv::Vec3f>(0, 0)[0]));    // border
}

// Every byte of two maps equal (NaNs included).
bool SameBits(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  for (int r = 0; r < a.rows; ++r)
    if (std::memcmp(a.ptr(r), b.ptr(r), static_cast<size_t>(a.cols) * a.elemSize()) != 0)
      return false;
  return true;
}

TEST(Triangulate, NormalsOnRowBlocksAndUpdatedAtChangedPixelsEqualTheFullPass) {
  // A wavy surface with holes and a depth step (no normal across it), 240 × 320 as a binned view.
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  cv::Mat points(240, 320, CV_32FC3);
  const float nan = std::nanf("");
  for (int r = 0; r < points.rows; ++r)
    for (int c = 0; c < points.cols; ++c) {
      const float z =
          50.0f + 0.3f * std::sin(c * 0.05f) * std::cos(r * 0.07f) + (c > 200 ? 1.0f : 0.0f);
      points.at<cv::Vec3f>(r, c) = u(rng) < 0.05f
                                       ? cv::Vec3f(nan, nan, nan)
                                       : cv::Vec3f((c - 160) * 0.02f, (r - 120) * 0.02f, z);
    }
  cv::Mat one, two;
  OrganisedNormals(points, 0.15, &one);
  OrganisedNormals(points, 0.15, &two, 2);
  EXPECT_TRUE(SameBits(one, two));
  // Rewrite ~2 % of the pixels (holes filled, points moved, points removed, borders included),
  // as model anchoring does, and update only around them.
  std::vector<int> changed;
  for (int i = 0; i < points.rows * points.cols; ++i) {
    if (u(rng) >= 0.02f) continue;
    cv::Vec3f& p = points.at<cv::Vec3f>(i / points.cols, i % points.cols);
    const int r = i / points.cols, c = i % points.cols;
    p = u(rng) < 0.2f ? cv::Vec3f(nan, nan, nan)
                      : cv::Vec3f((c - 160) * 0.02f, (r - 120) * 0.02f, 50.0f + 0.05f * u(rng));
    changed.push_back(i);
  }
  changed.push_back(0);                              // a corner
  changed.push_back(points.rows * points.cols - 1);  // the other one
  ASSERT_GT(changed.size(), 1000u);
  cv::Mat updated = one.clone(), full;
  UpdateOrganisedNormals(points, 0.15, changed, &updated);
  OrganisedNormals(points, 0.15, &full);
  EXPECT_FALSE(SameBits(one, full));  // the change did move normals
  EXPECT_TRUE(SameBits(updated, full));
  cv::Mat wrong(10, 10, CV_32FC3);
  EXPECT_THROW(UpdateOrganisedNormals(points, 0.15, changed, &wrong), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
