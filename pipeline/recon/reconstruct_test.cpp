#include "pipeline/recon/reconstruct.h"

#include <gtest/gtest.h>

#include <cmath>

#include "firmware/sim/render/test_scenes.h"
#include "firmware/sim/render/virtual_probe.h"
#include "pipeline/recon/evaluate.h"

namespace d3d {
namespace {


std::vector<cv::Mat> Frames(const Burst& b) {
  std::vector<cv::Mat> f;
  for (int k = 0; k < 4; ++k) f.push_back(b.frames[static_cast<size_t>(k)].image);
  return f;
}

int64_t NonFinitePointsWithFiniteParts(const cv::Mat& points) {
  int64_t bad = 0;
  for (int r = 0; r < points.rows; ++r)
    for (int c = 0; c < points.cols; ++c) {
      const cv::Vec3f& p = points.at<cv::Vec3f>(r, c);
      const bool any = std::isfinite(p[0]) || std::isfinite(p[1]) || std::isfinite(p[2]);
      const bool all = std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
      bad += any && !all;
    }
  return bad;
}

TEST(Reconstruct, TiltedPlaneEndToEnd) {
  const TriangleMesh plane = PlaneMesh({0.25, -0.1, -1}, {0, 0, 50});
  // A matte (powdered) plane: on a flat wet surface the mirror glint saturates a disk of ~5 mm,
  // rightly rejected by the phase stage, which would only test the glint's size here.
  RenderOptions matte;
  matte.specular = false;
  VirtualProbe probe(plane, MakeDefaultProbeDesign(), matte);
  const Burst b = probe.RenderBurst([](int64_t) { return Rigid3d::Identity(); }, 0, 0, 7, true);
  Reconstructor recon(probe.calibration());
  ReconstructedView v;
  ASSERT_TRUE(recon.Reconstruct(Frames(b), &v).ok());
  const CloudErrors e = EvaluateCloud(v.points_in_cam, v.unwrap.Phi, b.reference_truth, plane, probe.calibration().pattern);
  std::printf("[ plane    ] points %lld, valid %.1f %%, rms %.2f um, p95 %.2f um, order errors %lld, %.1f ms\n",
              static_cast<long long>(v.points), e.tooth_valid_pct, e.rms_um, e.p95_um, static_cast<long long>(e.order_errors),
              v.ms_total);
  EXPECT_GT(e.tooth_valid_pct, 90.0);
  EXPECT_EQ(e.order_errors, 0);
  EXPECT_LT(e.rms_um, 10.0);
  EXPECT_LT(e.p95_um, 25.0);
  EXPECT_EQ(NonFinitePointsWithFiniteParts(v.points_in_cam), 0);
}

TEST(Reconstruct, RefusesWrongInputWithAReason) {
  const ProbeCalibration calib = MakeDefaultProbeDesign().calibration;
  Reconstructor recon(calib);
  ReconstructedView v;
  const cv::Mat f(480, 640, CV_8U, cv::Scalar(100));
  Status s = recon.Reconstruct({f, f, f}, &v);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("3 frames"), std::string::npos) << s.ToString();
  s = recon.Reconstruct({f, f, f, cv::Mat(480, 640, CV_16U, cv::Scalar(100))}, &v);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument) << s.ToString();
  const cv::Mat small(240, 320, CV_8U, cv::Scalar(100));
  s = recon.Reconstruct({small, small, small, small}, &v);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("calibration"), std::string::npos) << s.ToString();
}

TEST(Reconstruct, DarkOrSaturatedBurstsGiveNoPointsAndNoNaNs) {
  const ProbeCalibration calib = MakeDefaultProbeDesign().calibration;
  Reconstructor recon(calib);
  ReconstructedView v;
  for (int level : {0, 255}) {
    const cv::Mat f(480, 640, CV_8U, cv::Scalar(level));
    ASSERT_TRUE(recon.Reconstruct({f, f, f, f}, &v).ok()) << level;
    EXPECT_EQ(v.points, 0) << level;
    EXPECT_EQ(NonFinitePointsWithFiniteParts(v.points_in_cam), 0);
  }
}

}  // namespace
}  // namespace d3d

namespace d3d {
namespace {

// Pixel sizes follow the fringe period in camera pixels: the 1280 × 1024 probe sees each fringe
// over twice the pixels of the 640 × 480 one, so lengths double (odd stay odd) and areas quadruple;
// the reference probe's options are unchanged.
TEST(Reconstruct, PixelSizesScaleWithTheFringePeriod) {
  const ProbeCalibration vga = MakeDefaultProbeDesign(640, 480).calibration;
  const ProbeCalibration sxga = MakeDefaultProbeDesign(1280, 1024).calibration;
  EXPECT_NEAR(FringePeriodCamPx(vga), kReferenceFringePeriodCamPx, 1e-9);
  EXPECT_NEAR(FringePeriodCamPx(sxga), 2 * kReferenceFringePeriodCamPx, 1e-9);
  const ReconstructOptions o;
  const ReconstructOptions same = ScaleToFringePeriod(o, FringePeriodCamPx(vga));
  EXPECT_EQ(same.phase.marker_box_px, o.phase.marker_box_px);
  EXPECT_EQ(same.unwrap.min_region_pixels, o.unwrap.min_region_pixels);
  const ReconstructOptions big = ScaleToFringePeriod(o, FringePeriodCamPx(sxga));
  EXPECT_EQ(big.phase.marker_box_px, 11);   // 2·5 = 10 → odd
  EXPECT_EQ(big.phase.marker_close_px, 7);  // 2·3
  EXPECT_EQ(big.phase.marker_suspect_reach_px, 2 * o.phase.marker_suspect_reach_px);
  EXPECT_EQ(big.phase.kappa_tile_px, 2 * o.phase.kappa_tile_px);
  EXPECT_EQ(big.unwrap.min_region_pixels, 4 * o.unwrap.min_region_pixels);
  EXPECT_EQ(big.unwrap.min_marker_votes, 4 * o.unwrap.min_marker_votes);
  EXPECT_EQ(big.unwrap.neck_radius, 2 * o.unwrap.neck_radius);
  EXPECT_NO_THROW(big.Check());
  EXPECT_THROW(ScaleToFringePeriod(o, 0.0), std::invalid_argument);
  // The Reconstructor applies it unless told not to.
  EXPECT_EQ(Reconstructor(sxga).options().unwrap.min_region_pixels, 4 * o.unwrap.min_region_pixels);
  ReconstructOptions fixed;
  fixed.scale_to_fringe_period = false;
  EXPECT_EQ(Reconstructor(sxga, fixed).options().unwrap.min_region_pixels, o.unwrap.min_region_pixels);
}

}  // namespace
}  // namespace d3d
