#include "pipeline/recon/reconstruct.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <cstring>

#include "pipeline/recon/evaluate.h"
#include "sim/render/test_scenes.h"
#include "sim/render/virtual_probe.h"

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
  const CloudErrors e = EvaluateCloud(v.points_in_cam, v.unwrap.Phi, b.reference_truth, plane,
                                      probe.calibration().pattern);
  std::printf(
      "[ plane    ] points %lld, valid %.1f %%, rms %.2f um, p95 %.2f um, order errors %lld, %.1f "
      "ms\n",
      static_cast<long long>(v.points), e.tooth_valid_pct, e.rms_um, e.p95_um,
      static_cast<long long>(e.order_errors), v.ms_total);
  EXPECT_GT(e.tooth_valid_pct, 90.0);
  EXPECT_EQ(e.order_errors, 0);
  EXPECT_LT(e.rms_um, 10.0);
  EXPECT_LT(e.p95_um, 25.0);
  EXPECT_EQ(NonFinitePointsWithFiniteParts(v.points_in_cam), 0);
}

// Every byte of two maps equal (NaNs included: the same code computes both).
bool SameBits(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  const size_t row_bytes = static_cast<size_t>(a.cols) * a.elemSize();
  for (int r = 0; r < a.rows; ++r)
    if (std::memcmp(a.ptr(r), b.ptr(r), row_bytes) != 0) return false;
  return true;
}

TEST(Reconstruct, RowBlocksOnTwoThreadsGiveTheSameBits) {
  // ReconstructOptions::threads = 2 splits the per-pixel passes into blocks of rows run as oneTBB
  // tasks: every map must equal the one-thread run's, bit for bit. A moving, tilted plane with the
  // in-burst motion compensation on, so that every pass (sums, κ, drift, compensation, marker
  // score and guard, triangulation, normals) runs; twice, so that the second call reuses the
  // per-thread scratch.
  const TriangleMesh plane = PlaneMesh({0.25, -0.1, -1}, {0, 0, 50});
  RenderOptions matte;
  matte.specular = false;
  VirtualProbe probe(plane, MakeDefaultProbeDesign(), matte);
  const auto moving = [](int64_t t_ns) {
    Rigid3d pose = Rigid3d::Identity();
    pose.translation() =
        Eigen::Vector3d(30.0, -10.0, 5.0) * (static_cast<double>(t_ns) * 1e-9);  // mm/s
    return pose;
  };
  ReconstructOptions one;
  one.phase.motion_compensation = true;
  ReconstructOptions two = one;
  two.threads = 2;
  tbb::global_control cap(tbb::global_control::max_allowed_parallelism, 2);
  Reconstructor r1(probe.calibration(), one), r2(probe.calibration(), two);
  EXPECT_EQ(r2.options().phase.threads, 2);
  for (uint64_t seq : {0u, 1u}) {
    const Burst b =
        probe.RenderBurst(moving, static_cast<int64_t>(seq) * 33'000'000, seq, 7, false);
    ReconstructedView v1, v2;
    ASSERT_TRUE(r1.Reconstruct(Frames(b), &v1).ok());
    ASSERT_TRUE(r2.Reconstruct(Frames(b), &v2).ok());
    ASSERT_GT(v1.points, 100000);
    EXPECT_GT(v1.phase.num_marker, 0);
    EXPECT_FALSE(v1.phase.phase_drift.empty());
    EXPECT_EQ(v1.points, v2.points);
    EXPECT_TRUE(SameBits(v1.phase.phi, v2.phase.phi));
    EXPECT_TRUE(SameBits(v1.phase.modulation, v2.phase.modulation));
    EXPECT_TRUE(SameBits(v1.phase.offset, v2.phase.offset));
    EXPECT_TRUE(SameBits(v1.phase.marker, v2.phase.marker));
    EXPECT_TRUE(SameBits(v1.phase.marker_score, v2.phase.marker_score));
    EXPECT_TRUE(SameBits(v1.quality, v2.quality));
    EXPECT_TRUE(SameBits(v1.unwrap.Phi, v2.unwrap.Phi));
    EXPECT_TRUE(SameBits(v1.points_in_cam, v2.points_in_cam));
    EXPECT_TRUE(SameBits(v1.normals, v2.normals));
  }
  EXPECT_THROW(Reconstructor(probe.calibration(),
                             [] {
                               ReconstructOptions o;
                               o.threads = 0;
                               return o;
                             }()),
               std::invalid_argument);
}

TEST(Reconstruct, BinFrameAveragesBlocksAndKeepsClipping) {
  cv::Mat f(4, 6, CV_8U);
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 6; ++c) f.at<uint8_t>(r, c) = static_cast<uint8_t>(10 * r + c);
  f.at<uint8_t>(3, 5) = 255;  // one clipped pixel in the last block
  cv::Mat b;
  ASSERT_TRUE(BinFrame(f, 2, &b).ok());
  ASSERT_EQ(b.size(), cv::Size(3, 2));
  ASSERT_EQ(b.type(), CV_8U);
  // Block (0,0): 0 1 10 11 → 5.5 → 6 (to nearest, halves up); block (1,1): 22 23 32 33 → 27.5 → 28.
  EXPECT_EQ(b.at<uint8_t>(0, 0), 6);
  EXPECT_EQ(b.at<uint8_t>(0, 2), 10);  // 4 5 14 15 → 9.5 → 10
  EXPECT_EQ(b.at<uint8_t>(1, 1), 28);
  EXPECT_EQ(b.at<uint8_t>(1, 2), 255);  // 24 25 34 255: clipped, not 84.5
  cv::Mat w(4, 4, CV_16U, cv::Scalar(1000));
  w.at<uint16_t>(0, 0) = 1003;
  ASSERT_TRUE(BinFrame(w, 2, &b).ok());
  EXPECT_EQ(b.type(), CV_16U);
  EXPECT_EQ(b.at<uint16_t>(0, 0), 1001);  // 4003 / 4 = 1000.75
  EXPECT_EQ(b.at<uint16_t>(1, 1), 1000);
  ASSERT_TRUE(BinFrame(f, 1, &b).ok());
  EXPECT_EQ(cv::countNonZero(b != f), 0);
  EXPECT_EQ(BinFrame(f, 4, &b).code(), StatusCode::kInvalidArgument);  // 6 is not a multiple of 4
  EXPECT_EQ(BinFrame(f, 0, &b).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(BinFrame(cv::Mat(4, 4, CV_32F), 2, &b).code(), StatusCode::kInvalidArgument);
}

// Every bin factor against the definition, block by block, on a random frame with clipped pixels
// (2 × 2 has a loop of its own).
TEST(Reconstruct, BinFrameMatchesTheDefinitionForEveryFactor) {
  cv::Mat f(48, 72, CV_8U);
  cv::RNG rng(7);
  rng.fill(f, cv::RNG::UNIFORM, 0, 256);
  for (int k = 0; k < 40; ++k) f.at<uint8_t>(rng.uniform(0, f.rows), rng.uniform(0, f.cols)) = 255;
  for (const int factor : {2, 3, 4}) {
    SCOPED_TRACE(factor);
    cv::Mat b;
    ASSERT_TRUE(BinFrame(f, factor, &b).ok());
    ASSERT_EQ(b.size(), cv::Size(f.cols / factor, f.rows / factor));
    int clipped = 0;
    for (int y = 0; y < b.rows; ++y)
      for (int x = 0; x < b.cols; ++x) {
        uint32_t sum = 0;
        bool clip = false;
        for (int dy = 0; dy < factor; ++dy)
          for (int dx = 0; dx < factor; ++dx) {
            const uint8_t v = f.at<uint8_t>(y * factor + dy, x * factor + dx);
            sum += v;
            clip = clip || v == 255;
          }
        const uint32_t n = static_cast<uint32_t>(factor * factor);
        clipped += clip;
        ASSERT_EQ(b.at<uint8_t>(y, x), clip ? 255 : (sum + n / 2) / n) << x << "," << y;
      }
    EXPECT_GT(clipped, 0);
  }
}

// Signed distances (µm) of a view's finite points to the plane n·p = n·p0, n normalised.
std::vector<double> PlaneDistancesUm(const cv::Mat& points, Eigen::Vector3d n,
                                     const Eigen::Vector3d& p0) {
  n.normalize();
  std::vector<double> d;
  for (int r = 0; r < points.rows; ++r)
    for (int c = 0; c < points.cols; ++c) {
      const cv::Vec3f& p = points.at<cv::Vec3f>(r, c);
      if (std::isfinite(p[2])) d.push_back(1000.0 * n.dot(Eigen::Vector3d(p[0], p[1], p[2]) - p0));
    }
  return d;
}

TEST(Reconstruct, BinnedFramesWithTheBinnedCalibrationGiveTheSameSurface) {
  // The tilted plane of TiltedPlaneEndToEnd, reconstructed at full resolution and from 2×2-binned
  // frames with BinnedCalibration: the binned view has a quarter of the points, lies on the same
  // plane and is not noisier. The principal point matters: cx / 2 instead of (cx − ½) / 2 (a
  // quarter of a binned pixel along the baseline) moved the binned plane by 59 µm.
  const Eigen::Vector3d n(0.25, -0.1, -1), p0(0, 0, 50);
  const TriangleMesh plane = PlaneMesh(n, p0);
  RenderOptions matte;
  matte.specular = false;
  VirtualProbe probe(plane, MakeDefaultProbeDesign(), matte);
  const Burst b = probe.RenderBurst([](int64_t) { return Rigid3d::Identity(); }, 0, 0, 7, false);
  Reconstructor full(probe.calibration());
  Reconstructor half(BinnedCalibration(probe.calibration(), 2));
  EXPECT_EQ(half.calibration().camera.width, 320);
  std::vector<cv::Mat> binned(4);
  for (int k = 0; k < 4; ++k)
    ASSERT_TRUE(
        BinFrame(Frames(b)[static_cast<size_t>(k)], 2, &binned[static_cast<size_t>(k)]).ok());
  ReconstructedView vf, vh;
  ASSERT_TRUE(full.Reconstruct(Frames(b), &vf).ok());
  ASSERT_TRUE(half.Reconstruct(binned, &vh).ok());
  ASSERT_EQ(vh.points_in_cam.size(), cv::Size(320, 240));
  const auto stats = [](const std::vector<double>& d, double* mean, double* rms) {
    double s = 0, s2 = 0;
    for (double v : d) s += v, s2 += v * v;
    *mean = s / static_cast<double>(d.size());
    *rms = std::sqrt(s2 / static_cast<double>(d.size()));
  };
  double mean_f, rms_f, mean_h, rms_h;
  const std::vector<double> df = PlaneDistancesUm(vf.points_in_cam, n, p0),
                            dh = PlaneDistancesUm(vh.points_in_cam, n, p0);
  stats(df, &mean_f, &rms_f);
  stats(dh, &mean_h, &rms_h);
  std::printf(
      "[ binned   ] full %zu points, mean %.2f rms %.2f um; binned %zu points, mean %.2f rms %.2f "
      "um; %.1f vs %.1f ms\n",
      df.size(), mean_f, rms_f, dh.size(), mean_h, rms_h, vf.ms_total, vh.ms_total);
  EXPECT_GT(static_cast<double>(dh.size()), 0.23 * static_cast<double>(df.size()));
  EXPECT_LT(static_cast<double>(dh.size()), 0.27 * static_cast<double>(df.size()));
  EXPECT_LT(std::abs(mean_h - mean_f), 1.5);
  EXPECT_LT(rms_h, rms_f + 0.5);
  EXPECT_EQ(NonFinitePointsWithFiniteParts(vh.points_in_cam), 0);
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
  EXPECT_EQ(Reconstructor(sxga, fixed).options().unwrap.min_region_pixels,
            o.unwrap.min_region_pixels);
}

}  // namespace
}  // namespace d3d
