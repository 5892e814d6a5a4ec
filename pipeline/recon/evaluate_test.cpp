#include "pipeline/recon/evaluate.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "sim/render/test_scenes.h"
#include "sim/render/virtual_probe.h"

namespace d3d {
namespace {

TEST(EvaluateCloud, KnownOffsetsAlongTheNormalAndWrongOrders) {
  const Eigen::Vector3d n = Eigen::Vector3d(0.2, -0.1, -1).normalized(), a = n.unitOrthogonal();
  const TriangleMesh plane = PlaneMesh(n, {0, 0, 50});
  RenderOptions opt;
  opt.texture = false;
  VirtualProbe probe(plane, MakeDefaultProbeDesign(), opt);
  FrameTruth t;
  probe.RenderTruth(Rigid3d::Identity(), &t);
  // Move every lit truth point by +10 µm along the normal (toward the camera) and slide it
  // sideways by 30 µm within the plane (must not count), and give 1 in 1000 a wrong order.
  const auto& spec = probe.calibration().pattern;
  cv::Mat points(t.depth_mm.size(), CV_32FC3, cv::Scalar::all(std::nan(""))),
      Phi(t.depth_mm.size(), CV_32F, cv::Scalar(std::nan("")));
  const Eigen::Vector3d toward = n.dot(Eigen::Vector3d(0, 0, 50)) > 0 ? -n : n;
  int lit = 0;
  for (int r = 0; r < points.rows; ++r)
    for (int c = 0; c < points.cols; ++c) {
      if (t.visibility.at<uint8_t>(r, c) != 2) continue;
      const cv::Vec3f& q = t.points_in_cam.at<cv::Vec3f>(r, c);
      const Eigen::Vector3d p = Eigen::Vector3d(q[0], q[1], q[2]) + 0.010 * toward + 0.030 * a;
      points.at<cv::Vec3f>(r, c) = cv::Vec3f(p.x(), p.y(), p.z());
      // Noise of 0.2 rad everywhere (across wraps too: not an order error), and a whole period off
      // on 1 in 1000.
      const double true_phase = spec.AbsolutePhase(t.projector_uv.at<cv::Vec2f>(r, c)[0]);
      Phi.at<float>(r, c) = static_cast<float>(true_phase + ((r + c) % 2 ? 0.2 : -0.2) +
                                               ((lit++ % 1000 == 0) ? 2 * M_PI : 0.0));
    }
  points.at<cv::Vec3f>(0, 0) =
      cv::Vec3f(std::nanf(""), std::nanf(""), std::nanf(""));  // one pixel without a point
  --lit;
  cv::Mat err;
  const CloudErrors e = EvaluateCloud(points, Phi, t, plane, spec, &err);
  EXPECT_EQ(e.points, lit);
  EXPECT_NEAR(e.rms_um, 10.0, 0.05);
  EXPECT_NEAR(e.mean_um, 10.0, 0.05);
  EXPECT_NEAR(e.p95_um, 10.0, 0.05);
  EXPECT_NEAR(e.order_error_pct, 0.1, 0.01);
  EXPECT_NEAR(e.tooth_valid_pct, 100.0, 1e-3);
  const cv::Mat heat = ErrorHeatMap(err, 25.0);
  EXPECT_EQ(heat.type(), CV_8UC3);
  int nan_r = -1, nan_c = -1;  // a pixel without a point is drawn black
  for (int r = 0; r < err.rows && nan_r < 0; ++r)
    for (int c = 0; c < err.cols; ++c)
      if (std::isnan(err.at<float>(r, c))) {
        nan_r = r;
        nan_c = c;
        break;
      }
  ASSERT_GE(nan_r, 0);
  EXPECT_EQ(heat.at<cv::Vec3b>(nan_r, nan_c), cv::Vec3b(0, 0, 0));
}

TEST(EvaluateCloud, BinnedTruthSeesTheSurfaceAtTheBinnedPixel) {
  // A tilted plane's truth binned 2×2: each binned pixel's point lies on the plane and on the ray
  // of that pixel of the binned camera (BinnedCamera), its projector pixel is the block's mean, and
  // a block with one unlit pixel is not lit.
  const Eigen::Vector3d n = Eigen::Vector3d(0.25, -0.1, -1).normalized(), p0(0, 0, 50);
  RenderOptions opt;
  opt.texture = false;
  VirtualProbe probe(PlaneMesh(n, p0), MakeDefaultProbeDesign(), opt);
  FrameTruth t;
  probe.RenderTruth(Rigid3d::Identity(), &t);
  t.visibility.at<uint8_t>(241, 321) = 1;  // block (120, 160): one pixel unlit
  const FrameTruth b = BinnedTruth(t, 2);
  ASSERT_EQ(b.points_in_cam.size(), cv::Size(320, 240));
  const PinholeBrownConrady cam = BinnedCamera(probe.calibration().camera, 2);
  int checked = 0;
  for (int y = 0; y < 240; y += 7)
    for (int x = 0; x < 320; x += 7) {
      if (b.visibility.at<uint8_t>(y, x) != 2) continue;
      const cv::Vec3f& q = b.points_in_cam.at<cv::Vec3f>(y, x);
      const Eigen::Vector3d p(q[0], q[1], q[2]);
      EXPECT_LT(std::abs(n.dot(p - p0)) * 1000, 0.01) << y << " " << x;  // µm
      const Eigen::Vector2d uv = *cam.Project(p);
      EXPECT_LT((uv - Eigen::Vector2d(x, y)).norm(), 0.01) << y << " " << x;
      const cv::Vec2f pu = b.projector_uv.at<cv::Vec2f>(y, x);
      cv::Vec2f mean(0, 0);
      for (int dy = 0; dy < 2; ++dy)
        for (int dx = 0; dx < 2; ++dx)
          mean += t.projector_uv.at<cv::Vec2f>(2 * y + dy, 2 * x + dx) * 0.25f;
      EXPECT_NEAR(pu[0], mean[0], 1e-3);
      ++checked;
    }
  EXPECT_GT(checked, 1000);
  EXPECT_EQ(b.visibility.at<uint8_t>(120, 160), 1);
  EXPECT_TRUE(std::isnan(b.projector_uv.at<cv::Vec2f>(120, 160)[0]));
  EXPECT_TRUE(std::isfinite(b.points_in_cam.at<cv::Vec3f>(120, 160)[2]));  // still a surface
  EXPECT_THROW(BinnedTruth(t, 7), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
