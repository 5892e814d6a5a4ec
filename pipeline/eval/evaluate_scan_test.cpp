#include "pipeline/eval/evaluate_scan.h"

#include <gtest/gtest.h>

#include <cmath>

#include "pipeline/register/test_surfaces.h"

namespace d3d {
namespace {

// A bumpy 20 × 10 mm sheet z = h(x, y), triangulated on a 0.1 mm grid, faces toward +z; with
// `relief`, h is its height field (bumps and blobs at the scale of cusps and fissures).
TriangleMesh Sheet(double x0 = -10, double x1 = 10, double step = 0.1,
                   const testing::HeightField* relief = nullptr) {
  TriangleMesh m;
  const int nx = static_cast<int>(std::lround((x1 - x0) / step)) + 1,
            ny = static_cast<int>(std::lround(10 / step)) + 1;
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i) {
      const double x = x0 + i * step, y = -5 + j * step;
      m.vertices.emplace_back(
          x, y,
          relief ? relief->Height(x, y)
                 : 0.8 * std::sin(0.7 * x) * std::cos(0.9 * y) + 0.3 * std::sin(2.3 * x + 1.1 * y));
    }
  for (int j = 0; j + 1 < ny; ++j)
    for (int i = 0; i + 1 < nx; ++i) {
      const int a = j * nx + i, b = a + 1, c = a + nx, d = c + 1;
      m.faces.emplace_back(a, b, d);
      m.faces.emplace_back(a, d, c);
    }
  return m;
}

// A frame to see a trajectory in: 0.8 rad about y, then (5, 6, 7) mm.
Rigid3d AnotherFrame() {
  Rigid3d W = Rigid3d::Identity();
  W.linear() = Eigen::AngleAxisd(0.8, Eigen::Vector3d::UnitY()).toRotationMatrix();
  W.translation() = Eigen::Vector3d(5, 6, 7);
  return W;
}

TEST(EvaluateScan, AReferenceShiftedByAKnownAmount) {
  const TriangleMesh ref = Sheet();
  const MeshClosestPoint cp(ref);
  TriangleMesh scan = Sheet(-5, 5);  // the middle half of the sheet
  Rigid3d shift = Rigid3d::Identity();
  shift.translation() = Eigen::Vector3d(0, 0, 0.030);
  for (auto& v : scan.vertices) v = shift * v;
  EvaluateOptions o;
  o.align = false;
  o.teeth_only_coverage = false;
  const TruenessReport r = EvaluateTrueness(scan, cp, Rigid3d::Identity(), o);
  // The signed distance of a 30 µm vertical shift is 30 µm · cos(slope) ≤ 30 µm, positive (above).
  EXPECT_GT(r.mean_um, 20.0);
  EXPECT_LE(r.max_um, 30.01);
  EXPECT_NEAR(r.rms_um, r.mean_abs_um, 2.0);
  EXPECT_GT(r.p95_um, 25.0);
  EXPECT_NEAR(r.coverage_pct, 50.0, 3.0);  // half the sheet, within 0.2 mm
  // Best fit removes the shift.
  o.align = true;
  const TruenessReport a = EvaluateTrueness(scan, cp, Rigid3d::Identity(), o);
  EXPECT_LT(a.rms_um, 1.5);
  EXPECT_LT(TranslationDistanceMm(a.reference_from_scan, shift.inverse()), 0.002);
  // A scan placed far off is found by the global alignment.
  Rigid3d far = Rigid3d::Identity();
  far.linear() =
      Eigen::AngleAxisd(2.5, Eigen::Vector3d(0.2, 0.5, 1).normalized()).toRotationMatrix();
  far.translation() = Eigen::Vector3d(40, -7, 12);
  TriangleMesh moved = Sheet(-8, 8);
  for (auto& v : moved.vertices) v = far * v;
  const Rigid3d g = GlobalAlign(moved, cp);
  const TruenessReport ga = EvaluateTrueness(moved, cp, g, o);
  EXPECT_LT(ga.rms_um, 1.5);
}

// Issue 55: a mesh against itself gave 1.6 % outliers (its border vertices, whose closest point is
// on the border), and a scan reaching past the reference's border must still count as outliers.
TEST(EvaluateScan, AMeshAgainstItselfHasNoOutlierAndAScanPastTheBorderHas) {
  const TriangleMesh ref = Sheet(-5, 5);
  const MeshClosestPoint cp(ref);
  EvaluateOptions o;
  o.align = false;
  o.teeth_only_coverage = false;
  const TruenessReport self = EvaluateTrueness(ref, cp, Rigid3d::Identity(), o);
  EXPECT_EQ(self.outlier_pct, 0.0);
  EXPECT_EQ(self.points, static_cast<int64_t>(ref.vertices.size()));
  EXPECT_LT(self.rms_um, 1e-6);
  EXPECT_NEAR(self.coverage_pct, 100.0, 1e-9);
  // The same surface as a coarse mesh (vertices 0.5 mm apart, more than the 0.2 mm coverage
  // distance): covered all the same (issue 55: the real arch against itself gave 21.7 %).
  const TruenessReport coarse = EvaluateTrueness(Sheet(-5, 5, 0.5), cp, Rigid3d::Identity(), o);
  EXPECT_GT(coarse.coverage_pct, 99.0);
  // A sheet twice as long: the half beyond the reference's border is out of the figures.
  const TruenessReport wider = EvaluateTrueness(Sheet(-10, 10), cp, Rigid3d::Identity(), o);
  EXPECT_NEAR(wider.outlier_pct, 50.0, 1.0);
  EXPECT_LT(wider.rms_um, 1e-6);
}

// Issue 55: a partial scan (here a third of the reference) has principal axes of its own; the
// global alignment must still find it (FPFH when the principal-axes starts leave it unmatched).
TEST(EvaluateScan, GlobalAlignFindsAPartialScan) {
  const testing::HeightField relief(11);
  const TriangleMesh ref = Sheet(-10, 10, 0.1, &relief);
  const MeshClosestPoint cp(ref);
  Rigid3d far = Rigid3d::Identity();
  far.linear() =
      Eigen::AngleAxisd(2.0, Eigen::Vector3d(0.3, -0.4, 1).normalized()).toRotationMatrix();
  far.translation() = Eigen::Vector3d(-30, 12, 25);
  TriangleMesh part = Sheet(-10, -3.5, 0.1, &relief);
  for (auto& v : part.vertices) v = far * v;
  EvaluateOptions o;
  o.teeth_only_coverage = false;
  const TruenessReport r = EvaluateTrueness(part, cp, GlobalAlign(part, cp), o);
  EXPECT_LT(r.rms_um, 1.5);
  EXPECT_LT(r.outlier_pct, 1.0);
  EXPECT_LT(TranslationDistanceMm(r.reference_from_scan, far.inverse()), 0.01);
}

TEST(EvaluateScan, TeethFiguresCountOnlyThePointsOnTeeth) {
  // Left half of the reference labelled tooth, right half gingiva; the scan is 20 µm above it on
  // the left and 60 µm on the right.
  TriangleMesh ref = Sheet();
  for (const auto& f : ref.faces) {
    const double x =
        (ref.vertices[static_cast<size_t>(f[0])].x() + ref.vertices[static_cast<size_t>(f[1])].x() +
         ref.vertices[static_cast<size_t>(f[2])].x()) /
        3;
    ref.face_labels.push_back(x < 0 ? SurfaceLabel::kTooth : SurfaceLabel::kGingiva);
  }
  const MeshClosestPoint cp(ref);
  TriangleMesh scan = Sheet(-9, 9);
  for (auto& v : scan.vertices) v.z() += v.x() < 0 ? 0.020 : 0.060;
  EvaluateOptions o;
  o.align = false;
  const TruenessReport r = EvaluateTrueness(scan, cp, Rigid3d::Identity(), o);
  ASSERT_GT(r.teeth_points, 0);
  EXPECT_NEAR(static_cast<double>(r.teeth_points) / static_cast<double>(r.points), 0.5, 0.03);
  EXPECT_GT(r.teeth_mean_um, 14.0);  // 20 µm · cos(slope)
  EXPECT_LE(r.teeth_p95_um, 21.0);   // none of the right half's 60 µm
  EXPECT_GT(r.rms_um, 30.0);         // all points
  // An unlabelled reference has no teeth figures.
  const TruenessReport u =
      EvaluateTrueness(scan, MeshClosestPoint(Sheet()), Rigid3d::Identity(), o);
  EXPECT_EQ(u.teeth_points, 0);
}

// A flat 10 × 10 mm square at height z on a 0.1 mm grid, x from x0, faces toward +z (or −z).
TriangleMesh Square(double x0, double z, bool facing_up) {
  TriangleMesh m;
  const int n = 101;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) m.vertices.emplace_back(x0 + 0.1 * i, -5 + 0.1 * j, z);
  for (int j = 0; j + 1 < n; ++j)
    for (int i = 0; i + 1 < n; ++i) {
      const int a = j * n + i, b = a + 1, c = a + n, d = c + 1;
      if (facing_up) {
        m.faces.emplace_back(a, b, d);
        m.faces.emplace_back(a, d, c);
      } else {
        m.faces.emplace_back(a, d, b);
        m.faces.emplace_back(a, c, d);
      }
    }
  return m;
}

TriangleMesh Joined(const std::vector<TriangleMesh>& parts) {
  TriangleMesh m;
  for (const TriangleMesh& p : parts) {
    const int base = static_cast<int>(m.vertices.size());
    m.vertices.insert(m.vertices.end(), p.vertices.begin(), p.vertices.end());
    for (const auto& f : p.faces) m.faces.emplace_back(f[0] + base, f[1] + base, f[2] + base);
  }
  return m;
}

TEST(EvaluateScan, CoverageIsSplitIntoNarrowGapsAndTheOpenSurface) {
  // Two tooth walls 0.4 mm apart facing each other over x in [-10, 0] (a gap), and the lower wall
  // going on in the open over x in [0, 10]. The scan has the lower wall only (the probe did not
  // reach the upper one inside the gap).
  const TriangleMesh lower = Joined({Square(-10, 0, true), Square(0, 0, true)});
  TriangleMesh ref = Joined({lower, Square(-10, 0.4, false)});
  ref.face_labels.assign(ref.faces.size(), SurfaceLabel::kTooth);
  const MeshClosestPoint cp(ref);
  EvaluateOptions o;
  o.align = false;
  const TruenessReport r = EvaluateTrueness(lower, cp, Rigid3d::Identity(), o);
  EXPECT_NEAR(r.coverage_pct, 66.7, 1.5);
  EXPECT_NEAR(r.gap_area_pct, 66.7, 1.5);      // both walls of the gap
  EXPECT_NEAR(r.coverage_gap_pct, 50.0, 1.5);  // the lower one
  EXPECT_NEAR(r.coverage_open_pct, 100.0, 0.5);
  // A gap wider than gap_mm is open surface; gap_mm 0 makes no split.
  o.gap_mm = 0.3;
  const TruenessReport wide = EvaluateTrueness(lower, cp, Rigid3d::Identity(), o);
  EXPECT_EQ(wide.gap_area_pct, 0.0);
  EXPECT_TRUE(std::isnan(wide.coverage_gap_pct));
  EXPECT_NEAR(wide.coverage_open_pct, wide.coverage_pct, 1e-9);
  o.gap_mm = 0;
  const TruenessReport none = EvaluateTrueness(lower, cp, Rigid3d::Identity(), o);
  EXPECT_TRUE(std::isnan(none.gap_area_pct) && std::isnan(none.coverage_open_pct));
  EXPECT_DOUBLE_EQ(none.coverage_pct, r.coverage_pct);
  // Surfaces back to back (a thin plate's two sides) are no gap: the other side lies behind.
  TriangleMesh plate = Joined({Square(-10, 0, false), Square(-10, 0.4, true)});
  plate.face_labels.assign(plate.faces.size(), SurfaceLabel::kTooth);
  o.gap_mm = 1.0;
  const TruenessReport back =
      EvaluateTrueness(plate, MeshClosestPoint(plate), Rigid3d::Identity(), o);
  EXPECT_EQ(back.gap_area_pct, 0.0);
  o.gap_mm = -1;
  EXPECT_THROW(o.Check(), std::invalid_argument);
}

TEST(EvaluateScan, SeenSurfaceCountsTheToothFacesAViewShowed) {
  // Four unit right triangles 50 mm in front of the camera (camera frame = world): 0 and 1 face
  // the camera, 2 is tilted 85° (grazing), 3 faces it but is gingiva. All tooth but 3.
  TriangleMesh ref;
  auto add = [&](const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                 SurfaceLabel l) {
    const int i = static_cast<int>(ref.vertices.size());
    ref.vertices.insert(ref.vertices.end(), {a, b, c});
    ref.faces.emplace_back(i, i + 1, i + 2);
    ref.face_labels.push_back(l);
  };
  add({0, 0, 50}, {0, 1, 50}, {1, 0, 50}, SurfaceLabel::kTooth);  // normal −z: toward the camera
  add({2, 0, 50}, {2, 1, 50}, {3, 0, 50}, SurfaceLabel::kTooth);
  const double t = 85 * M_PI / 180;
  add({4, 0, 50}, {4, 1, 50}, {4 + std::cos(t), 0, 50 + std::sin(t)}, SurfaceLabel::kTooth);
  add({6, 0, 50}, {6, 1, 50}, {7, 0, 50}, SurfaceLabel::kGingiva);
  ASSERT_LT(ref.FaceNormal(0).z(), -0.99);
  FrameTruth truth;
  truth.world_from_probe = Rigid3d::Identity();
  truth.depth_mm = cv::Mat(1, 4, CV_32F, cv::Scalar(50));
  truth.points_in_cam = cv::Mat(1, 4, CV_32FC3);
  truth.face_index = (cv::Mat_<int32_t>(1, 4) << 0, 1, 2, 3);
  truth.visibility = (cv::Mat_<uint8_t>(1, 4) << 2, 1, 2, 2);  // face 1 in the projector's shadow
  for (int x = 0; x < 4; ++x)
    truth.points_in_cam.at<cv::Vec3f>(0, x) = cv::Vec3f(0.3f + 2 * x, 0.3f, 50.0f);
  SeenSurface seen(ref, 42, 58, 80);
  seen.Add(truth);
  EXPECT_EQ(seen.views(), 1);
  const double tooth_area = ref.FaceArea(0) + ref.FaceArea(1) + ref.FaceArea(2);
  EXPECT_NEAR(seen.SeenToothAreaPct(), 100 * ref.FaceArea(0) / tooth_area,
              1e-9);  // 1 shadowed, 2 grazing
  // Lit now, but beyond the measurement volume: still not seen.
  truth.visibility.at<uint8_t>(0, 1) = 2;
  truth.points_in_cam.at<cv::Vec3f>(0, 1)[2] = 60.0f;
  seen.Add(truth);
  EXPECT_NEAR(seen.SeenToothAreaPct(), 100 * ref.FaceArea(0) / tooth_area, 1e-9);
  // With the limit at 90°, the grazing face counts; a view without maps is ignored.
  SeenSurface any(ref, 42, 58, 90);
  any.Add(truth);
  any.Add(FrameTruth{});
  EXPECT_EQ(any.views(), 1);
  EXPECT_NEAR(any.SeenToothAreaPct(), 100 * (ref.FaceArea(0) + ref.FaceArea(2)) / tooth_area, 1e-9);
  EXPECT_THROW(SeenSurface(ref, 58, 42, 80), std::invalid_argument);
}

TEST(EvaluateScan, PrecisionAndTrajectoryError) {
  const TriangleMesh a = Sheet();
  TriangleMesh b = Sheet(-9, 9);
  Rigid3d T = Rigid3d::Identity();
  T.translation() = Eigen::Vector3d(0.05, -0.02, 0.01);
  for (auto& v : b.vertices) v = T * v;
  const PrecisionReport p = EvaluatePrecision(a, b, T.inverse());
  EXPECT_LT(p.rms_um, 1.5);
  EXPECT_GT(p.points, 1000);
  // ATE: a trajectory seen in another frame, with one pose off by 1 mm.
  std::vector<Rigid3d> truth, est;
  const Rigid3d W = AnotherFrame();
  for (int i = 0; i < 50; ++i) {
    Rigid3d t = Rigid3d::Identity();
    t.translation() = Eigen::Vector3d(i, std::sin(0.2 * i) * 5, 0.1 * i);
    truth.push_back(t);
    est.push_back(W * t);
  }
  Rigid3d align;
  AteReport r = AbsoluteTrajectoryError(est, truth, &align);
  EXPECT_LT(r.rmse_mm, 1e-9);
  EXPECT_LT(r.mean_deg, 1e-6);
  est[10].translation() += Eigen::Vector3d(0, 0, 1.0);
  r = AbsoluteTrajectoryError(est, truth);
  EXPECT_NEAR(r.rmse_mm, std::sqrt(1.0 / 50), 0.02);
  EXPECT_NEAR(r.max_mm, 1.0, 0.05);
}

// RPE: the same trajectory in another frame has none; a jump of 0.2 mm at pose 20 that every
// later pose keeps (a view registered off, then followed: the rest of the estimate moved as one)
// is one step error, at pose 20, while the ATE spreads it over the whole trajectory.
TEST(EvaluateScan, RelativePoseErrorFindsTheJump) {
  std::vector<Rigid3d> truth, est;
  const Rigid3d W = AnotherFrame();
  for (int i = 0; i < 50; ++i) {
    Rigid3d t = Rigid3d::Identity();
    t.linear() = Eigen::AngleAxisd(0.02 * i, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    t.translation() = Eigen::Vector3d(0.3 * i, std::sin(0.2 * i) * 5, 0.1 * i);
    truth.push_back(t);
    est.push_back(W * t);
  }
  RpeReport r = RelativePoseError(est, truth);
  EXPECT_EQ(r.steps, 49);
  EXPECT_LT(r.rmse_mm, 1e-9);
  EXPECT_LT(r.mean_deg, 1e-6);
  Rigid3d jump = Rigid3d::Identity();  // in the estimate's frame, applied to poses 20..49
  jump.translation() = Eigen::Vector3d(0.12, -0.16, 0);
  for (int i = 20; i < 50; ++i) est[static_cast<size_t>(i)] = jump * est[static_cast<size_t>(i)];
  r = RelativePoseError(est, truth);
  EXPECT_EQ(r.max_pose, 20);
  EXPECT_NEAR(r.max_mm, 0.2, 1e-9);
  EXPECT_NEAR(r.rmse_mm, 0.2 / 7, 1e-9);  // one step of 49
  EXPECT_LT(r.mean_deg, 1e-6);
  EXPECT_GT(AbsoluteTrajectoryError(est, truth).rmse_mm, 0.05);  // ATE: off from pose 20 on
  EXPECT_THROW(RelativePoseError(est, std::vector<Rigid3d>(3)), std::invalid_argument);
  EXPECT_EQ(RelativePoseError({est[0]}, {truth[0]}).steps, 0);
}

// Precision counts the surface both scans have. b = a's sheet plus a wall a never reached, rising
// from 0.05 to 0.45 mm above the sheet (a tooth wall above a gingiva both scans have): one-sided,
// the wall's vertices meet a's sheet below them; reciprocally they do not count. A real difference
// (a 60 µm bump that b has and a has not) is kept whole.
TEST(EvaluateScan, PrecisionCountsOnlyTheSurfaceBothScansHave) {
  const TriangleMesh a = Sheet();
  TriangleMesh b = Sheet();
  const auto h = [&](double x, double y) {
    return 0.8 * std::sin(0.7 * x) * std::cos(0.9 * y) + 0.3 * std::sin(2.3 * x + 1.1 * y);
  };
  const int base = static_cast<int>(b.vertices.size()), ny = 81, nz = 9;
  for (int j = 0; j < ny; ++j)
    for (int k = 0; k < nz; ++k) {
      const double y = -4 + 0.1 * j;
      b.vertices.emplace_back(0.03, y, h(0.03, y) + 0.05 + 0.05 * k);
    }
  for (int j = 0; j + 1 < ny; ++j)
    for (int k = 0; k + 1 < nz; ++k) {
      const int v = base + j * nz + k;
      b.faces.emplace_back(v, v + nz, v + nz + 1);
      b.faces.emplace_back(v, v + nz + 1, v + 1);
    }
  const PrecisionReport wall = EvaluatePrecision(a, b);
  EXPECT_GT(wall.one_sided_rms_um, 30.0);
  EXPECT_LT(wall.rms_um, 1.0);
  EXPECT_GT(wall.not_reciprocal_pct, 0.5);
  EXPECT_GT(wall.points, 15000);
  // A 60 µm bump of radius ~1 mm that only b has: measured, not thinned.
  TriangleMesh bump = Sheet();
  for (auto& v : bump.vertices)
    v.z() += 0.060 * std::exp(-(std::pow(v.x() - 3, 2) + std::pow(v.y(), 2)) / (2 * 0.5 * 0.5));
  const PrecisionReport p = EvaluatePrecision(a, bump);
  EXPECT_EQ(p.not_reciprocal_pct, 0.0);
  EXPECT_DOUBLE_EQ(p.rms_um, p.one_sided_rms_um);
  EXPECT_GT(p.rms_um, 3.0);
  EXPECT_THROW(EvaluatePrecision(a, bump, Rigid3d::Identity(), 0.5, -1.0), std::invalid_argument);
}

TEST(EvaluateScan, HeatMapHasTheScanAndABar) {
  const TriangleMesh s = Sheet();
  std::vector<float> d(s.vertices.size());
  for (size_t i = 0; i < d.size(); ++i) d[i] = static_cast<float>(s.vertices[i].x() * 5);
  const cv::Mat img = DeviationHeatMap(s, d, 50, 800);
  ASSERT_EQ(img.type(), CV_8UC3);
  EXPECT_EQ(img.cols, 800);
  // One end blue (−50 µm), the other red (+50 µm) (the principal axis may point either way).
  const cv::Vec3b left = img.at<cv::Vec3b>(img.rows / 3, 30),
                  right = img.at<cv::Vec3b>(img.rows / 3, 770);
  const bool blue_left = left[0] > 200 && left[2] < 50 && right[2] > 200 && right[0] < 50;
  const bool red_left = left[2] > 200 && left[0] < 50 && right[0] > 200 && right[2] < 50;
  EXPECT_TRUE(blue_left || red_left) << left << " " << right;
}

// A view turned about its own surface: its camera centre moves by the lever of the working
// distance, its footprint (the surface it sees) hardly; a view shifted moves both alike. The
// wrong-fusion rule judges the footprint.
TEST(ViewFootprint, MeasuresWhereTheViewsSurfaceMovesNotTheCameraCentre) {
  const PinholeBrownConrady cam{640, 480, 2000, 2000, 319.5, 239.5, 0, 0, 0, 0, 0};
  const std::vector<Eigen::Vector3d> foot = ViewFootprint(cam, 50.0);
  ASSERT_EQ(foot.size(), 5u);
  EXPECT_NEAR((foot[0] - Eigen::Vector3d(0, 0, 50)).norm(), 0.0, 1e-9);  // the image centre
  for (const Eigen::Vector3d& p : foot) EXPECT_NEAR(p.z(), 50.0, 1e-9);
  EXPECT_NEAR(foot[4].x(), 319.5 / 2000 * 50, 1e-9);  // a corner: 8 mm off the axis
  EXPECT_THROW(ViewFootprint(cam, 0.0), std::invalid_argument);

  const Rigid3d truth = testing::LookDown(2, -1, 30);
  // 0.23° about x through the point of the surface 50 mm in front of the camera: the corners
  // (5.99 mm off the axis along y) move by 5.99 · 2 sin(θ/2) = 0.024 mm.
  Rigid3d turn = Rigid3d::Identity();
  const Eigen::Vector3d pivot(0, 0, 50);
  turn.linear() = Eigen::AngleAxisd(0.23 * M_PI / 180, Eigen::Vector3d::UnitX()).toRotationMatrix();
  turn.translation() = pivot - turn.linear() * pivot;
  const Rigid3d turned = truth * turn;
  EXPECT_GT(TranslationDistanceMm(turned, truth), kWrongFusionMm);  // the camera centre: 0.2 mm
  EXPECT_NEAR(FootprintDistanceMm(turned, truth, foot),
              239.5 / 2000 * 50 * 2 * std::sin(0.23 * M_PI / 360), 1e-9);
  // Shifted 0.3 mm: both.
  Rigid3d shift = Rigid3d::Identity();
  shift.translation() = Eigen::Vector3d(0.3, 0, 0);
  EXPECT_NEAR(FootprintDistanceMm(truth * shift, truth, foot), 0.3, 1e-9);
  EXPECT_NEAR(FootprintDistanceMm(truth * shift, truth, {}), 0.3,
              1e-9);  // no footprint: the centre
}

}  // namespace
}  // namespace d3d
