#include "sim/trajectory/scan_path.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <numbers>

#include "common/mesh/mesh_io.h"
#include "sim/trajectory/test_arches.h"

namespace d3d {
namespace {

using namespace d3d::testing;

constexpr double kPi = std::numbers::pi;
constexpr double kRadToDeg = 180.0 / kPi;

double AngleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::acos(std::clamp(a.normalized().dot(b.normalized()), -1.0, 1.0)) * kRadToDeg;
}

// ---------------------------------------------------------------------------------------------
// AnalyzeArch

TEST(AnalyzeArch, RecoversTheSyntheticArches) {
  const Rigid3d T = SomeWorldFromLocal();
  const Rigid3d local_from_world = T.inverse();
  for (const Shape shape : {Shape::kU, Shape::kParabola}) {
    std::vector<Eigen::Vector3d> c;
    const double true_length = ArchCentreline(shape, 0.5, &c);
    for (const bool labels : {true, false}) {
      const std::string what = std::string(shape == Shape::kU ? "U" : "parabola") +
                               (labels ? ", labels" : ", no labels");
      const ArchFrame arch = AnalyzeArch(RidgeArch(T, labels, shape));
      ASSERT_TRUE(arch.ok()) << what << ": " << arch.status.ToString();
      EXPECT_EQ(arch.used_labels, labels);
      EXPECT_LT(AngleDeg(arch.occlusal, T.linear() * Eigen::Vector3d::UnitY()), 2.0) << what;
      EXPECT_NEAR(arch.length_mm, true_length, 0.03 * true_length) << what;
      // The curve's ends are the ends of the centreline; the midline is at its front.
      const Eigen::Vector3d e0 = local_from_world * arch.curve.front().position;
      const Eigen::Vector3d e1 = local_from_world * arch.curve.back().position;
      EXPECT_NEAR(std::abs(e0.x()), std::abs(c.front().x()), 1.0) << what;
      EXPECT_NEAR(e0.z(), c.front().z(), 1.0) << what;
      EXPECT_NEAR(e1.z(), c.front().z(), 1.0) << what;
      EXPECT_LT(e0.x() * e1.x(), 0.0) << what;
      const Eigen::Vector3d mid = local_from_world * arch.At(arch.midline_arc_mm).position;
      EXPECT_NEAR(mid.z(), shape == Shape::kU ? 44.0 : 40.0, 1.0) << what;
      EXPECT_NEAR(mid.x(), 0.0, 1.5) << what;
      EXPECT_NEAR(mid.y(), kHeight, 0.5) << what;  // at the occlusal surface
      for (const auto& q : arch.curve) {
        const Eigen::Vector3d p = local_from_world * q.position;
        // Nearest centreline point: the curve runs through the middle of the ridge.
        double dist = 1e9;
        for (const auto& x : c)
          dist = std::min(dist, (Eigen::Vector3d(p.x(), 0, p.z()) - x).norm());
        EXPECT_LT(dist, 0.8) << what << " at arc " << q.arc_mm;
        EXPECT_NEAR(q.buccal.dot(arch.occlusal), 0.0, 1e-9);
        EXPECT_NEAR(q.tangent.dot(q.buccal), 0.0, 1e-9);
        if (q.arc_mm > 5 && q.arc_mm < arch.length_mm - 5) {
          EXPECT_NEAR(q.half_width_mm, kWidth / 2, 0.6) << what << " at arc " << q.arc_mm;
          // Buccal points away from the arch's interior (the local origin side is inside).
          const Eigen::Vector3d b = T.linear().transpose() * q.buccal;
          EXPECT_GT(b.dot(Eigen::Vector3d(p.x(), 0, p.z() - (shape == Shape::kU ? 12 : 0))), 0.0)
              << what;
        }
      }
    }
  }
}

TEST(AnalyzeArch, RefusesNonArches) {
  const ArchFrame empty = AnalyzeArch(TriangleMesh{});
  EXPECT_FALSE(empty.ok());
  EXPECT_NE(empty.status.message().find("empty"), std::string::npos) << empty.status.ToString();

  TriangleMesh plate;  // 60 × 60 mm flat square, 2 mm grid
  for (int y = 0; y <= 30; ++y)
    for (int x = 0; x <= 30; ++x) plate.vertices.emplace_back(2.0 * x, 0.5 * y, 2.0 * y);
  for (int y = 0; y < 30; ++y) {
    for (int x = 0; x < 30; ++x) {
      const int v = y * 31 + x;
      plate.faces.emplace_back(v, v + 1, v + 32);
      plate.faces.emplace_back(v, v + 32, v + 31);
    }
  }
  const ArchFrame flat = AnalyzeArch(plate);
  EXPECT_FALSE(flat.ok());
  EXPECT_NE(flat.status.message().find("not an elongated band"), std::string::npos)
      << flat.status.ToString();

  TriangleMesh gums = RidgeArch(Rigid3d::Identity(), true);
  std::fill(gums.face_labels.begin(), gums.face_labels.end(), SurfaceLabel::kGingiva);
  const ArchFrame no_teeth = AnalyzeArch(gums);
  EXPECT_FALSE(no_teeth.ok());
  EXPECT_NE(no_teeth.status.message().find("too few tooth faces"), std::string::npos)
      << no_teeth.status.ToString();
}

// ---------------------------------------------------------------------------------------------
// Scan trajectories

struct PassAngles {
  std::vector<double> occlusal, buccal, lingual;  // signed tilt (deg) of the optical axis
};

double Median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// The arch-curve point nearest to the optical axis (line) of a pose.
const ArchPoint& NearestToAxis(const ArchFrame& arch, const Rigid3d& pose) {
  const Eigen::Vector3d z = pose.linear().col(2);
  double best = 1e18;
  size_t idx = 0;
  for (size_t i = 0; i < arch.curve.size(); ++i) {
    const double d = (arch.curve[i].position - pose.translation()).cross(z).norm();
    if (d < best) {
      best = d;
      idx = i;
    }
  }
  return arch.curve[idx];
}

// Signed tilt of the optical axis from −occlusal about the local tangent: > 0 looking from the
// buccal side toward the palate, < 0 from the lingual side.
double SignedTiltDeg(const ArchFrame& arch, const Rigid3d& pose) {
  const Eigen::Vector3d z = pose.linear().col(2);
  const Eigen::Vector3d& buccal = NearestToAxis(arch, pose).buccal;
  return std::atan2(-z.dot(buccal), -z.dot(arch.occlusal)) * kRadToDeg;
}

// How far (mm) the camera is beyond the nearer end of the arch, along the end's outward tangent
// in the occlusal plane.
double BeyondEndMm(const ArchFrame& arch, const Eigen::Vector3d& camera) {
  const ArchPoint& a = arch.curve.front();
  const ArchPoint& b = arch.curve.back();
  const bool first = (camera - a.position).norm() < (camera - b.position).norm();
  const ArchPoint& end = first ? a : b;
  Eigen::Vector3d out = first ? Eigen::Vector3d(-end.tangent) : end.tangent;
  out = (out - out.dot(arch.occlusal) * arch.occlusal).normalized();
  return (camera - end.position).dot(out);
}

// The checks shared by the synthetic and the real arch.
void CheckFullArchScan(const ScanPathResult& scan, const std::string& what) {
  ASSERT_TRUE(scan.ok()) << what << ": " << scan.status.ToString();
  const Trajectory& tr = scan.trajectory;
  const ScanPathStats st = ComputeScanPathStats(tr, scan.arch);
  std::printf("[%s] arch %.1f mm; %s\n", what.c_str(), scan.arch.length_mm, st.ToString().c_str());
  EXPECT_GE(st.duration_s, 30.0) << what;
  EXPECT_LE(st.duration_s, 60.0) << what;
  EXPECT_GE(st.speed_in_5_20_share, 0.95) << what;
  EXPECT_LT(st.max_speed_mm_s, 40.0) << what;
  EXPECT_GE(st.depth_in_dof_share, 0.90) << what;

  // Passes in protocol order, with the expected tilts.
  std::vector<ScanPhase> order;
  for (const auto& s : scan.segments)
    if (s.phase != ScanPhase::kTransition) order.push_back(s.phase);
  EXPECT_EQ(order,
            (std::vector<ScanPhase>{ScanPhase::kOcclusal, ScanPhase::kBuccal, ScanPhase::kLingual}))
      << what;
  EXPECT_EQ(scan.segments.front().start_ns, tr.StartNs());
  EXPECT_EQ(scan.segments.back().end_ns, tr.EndNs());
  PassAngles angles;
  for (const auto& seg : scan.segments) {
    for (int64_t t = seg.start_ns; t <= seg.end_ns; t += 100'000'000) {
      const double tilt = SignedTiltDeg(scan.arch, tr.WorldFromProbe(t));
      if (seg.phase == ScanPhase::kOcclusal) angles.occlusal.push_back(tilt);
      if (seg.phase == ScanPhase::kBuccal) angles.buccal.push_back(tilt);
      if (seg.phase == ScanPhase::kLingual) angles.lingual.push_back(tilt);
    }
  }
  EXPECT_LT(std::abs(Median(angles.occlusal)), 8.0) << what;
  EXPECT_NEAR(Median(angles.buccal), 50.0, 10.0) << what;
  EXPECT_NEAR(Median(angles.lingual), -50.0, 10.0) << what;

  for (const auto& seg : scan.segments) {
    if (seg.phase == ScanPhase::kTransition) {
      // Half-way through a transition the probe is beyond the distal end, looking back at it.
      const Rigid3d mid = tr.WorldFromProbe((seg.start_ns + seg.end_ns) / 2);
      EXPECT_GT(BeyondEndMm(scan.arch, mid.translation()), 5.0) << what;
      continue;
    }
    // Each pass sweeps the whole arch, end to end.
    double lo = 1e9, hi = -1e9;
    for (int64_t t = seg.start_ns; t <= seg.end_ns; t += 50'000'000) {
      const double arc = NearestToAxis(scan.arch, tr.WorldFromProbe(t)).arc_mm;
      lo = std::min(lo, arc);
      hi = std::max(hi, arc);
    }
    EXPECT_LT(lo, 2.0) << what << " " << ScanPhaseName(seg.phase);
    EXPECT_GT(hi, scan.arch.length_mm - 2.0) << what << " " << ScanPhaseName(seg.phase);
  }
}

TEST(MakeScanTrajectory, FullArchOnTheSyntheticArch) {
  const TriangleMesh mesh = RidgeArch(SomeWorldFromLocal(), true);
  const ScanPathOptions options;
  CheckFullArchScan(MakeScanTrajectory(mesh, ScanKind::kFullArch, options), "synthetic");
}

TEST(MakeScanTrajectory, DeterministicForASeed) {
  const ArchFrame& arch = SyntheticArch();
  ASSERT_TRUE(arch.ok());
  ScanPathOptions options;
  options.seed = 7;
  const ScanPathResult a = MakeScanTrajectory(arch, ScanKind::kQuadrant, options);
  const ScanPathResult b = MakeScanTrajectory(arch, ScanKind::kQuadrant, options);
  options.seed = 8;
  const ScanPathResult c = MakeScanTrajectory(arch, ScanKind::kQuadrant, options);
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  ASSERT_EQ(a.trajectory.keys().size(), b.trajectory.keys().size());
  for (size_t i = 0; i < a.trajectory.keys().size(); ++i) {
    ASSERT_EQ(a.trajectory.keys()[i].t_ns, b.trajectory.keys()[i].t_ns);
    ASSERT_TRUE(a.trajectory.keys()[i].world_from_probe.isApprox(
        b.trajectory.keys()[i].world_from_probe, 0.0));
  }
  double max_diff = 0;
  for (int64_t t = 0; t < std::min(a.trajectory.EndNs(), c.trajectory.EndNs()); t += 50'000'000) {
    max_diff = std::max(max_diff, TranslationDistanceMm(a.trajectory.WorldFromProbe(t),
                                                        c.trajectory.WorldFromProbe(t)));
  }
  EXPECT_GT(max_diff, 0.5);
}

TEST(MakeScanTrajectory, QuadrantAndTooth) {
  const ArchFrame& arch = SyntheticArch();
  ASSERT_TRUE(arch.ok());
  ScanPathOptions options;
  options.start_ns = 1'000'000'000;
  for (const int side : {0, 1}) {
    options.side = side;
    const ScanPathResult quad = MakeScanTrajectory(arch, ScanKind::kQuadrant, options);
    ASSERT_TRUE(quad.ok()) << quad.status.ToString();
    EXPECT_EQ(quad.trajectory.StartNs(), options.start_ns);
    const ScanPathStats qs = ComputeScanPathStats(quad.trajectory, arch);
    std::printf("[quadrant side %d] %s\n", side, qs.ToString().c_str());
    EXPECT_GT(qs.duration_s, 10.0);
    EXPECT_LT(qs.duration_s, 40.0);
    EXPECT_GE(qs.depth_in_dof_share, 0.9);
    EXPECT_GE(qs.speed_in_5_20_share, 0.9);
    // Passes run from the chosen distal end to the midline.
    for (const auto& seg : quad.segments) {
      if (seg.phase == ScanPhase::kTransition) continue;
      double lo = 1e9, hi = -1e9;
      for (int64_t t = seg.start_ns; t <= seg.end_ns; t += 50'000'000) {
        const double arc = NearestToAxis(arch, quad.trajectory.WorldFromProbe(t)).arc_mm;
        lo = std::min(lo, arc);
        hi = std::max(hi, arc);
      }
      if (side == 0) {
        EXPECT_LT(lo, 2.0) << ScanPhaseName(seg.phase);
        EXPECT_GT(hi, arch.midline_arc_mm - 1.0) << ScanPhaseName(seg.phase);
        EXPECT_LT(hi, arch.midline_arc_mm + 15.0) << ScanPhaseName(seg.phase);
      } else {
        EXPECT_GT(hi, arch.length_mm - 2.0) << ScanPhaseName(seg.phase);
        EXPECT_LT(lo, arch.midline_arc_mm + 1.0) << ScanPhaseName(seg.phase);
        EXPECT_GT(lo, arch.midline_arc_mm - 15.0) << ScanPhaseName(seg.phase);
      }
    }

    const ScanPathResult tooth = MakeScanTrajectory(arch, ScanKind::kTooth, options);
    ASSERT_TRUE(tooth.ok()) << tooth.status.ToString();
    const ScanPathStats ts = ComputeScanPathStats(tooth.trajectory, arch);
    std::printf("[tooth side %d] %s\n", side, ts.ToString().c_str());
    EXPECT_GT(ts.duration_s, 5.0);
    EXPECT_LT(ts.duration_s, 30.0);
    EXPECT_GE(ts.depth_in_dof_share, 0.9);
    // The aimed tooth stays the one at tooth_arc_mm from the chosen end.
    const Eigen::Vector3d target =
        arch.At(side == 0 ? options.tooth_arc_mm : arch.length_mm - options.tooth_arc_mm).position;
    for (int64_t t = tooth.trajectory.StartNs(); t <= tooth.trajectory.EndNs(); t += 200'000'000) {
      const Rigid3d pose = tooth.trajectory.WorldFromProbe(t);
      const double miss = (target - pose.translation()).cross(pose.linear().col(2)).norm();
      EXPECT_LT(miss, 15.0) << "t " << t;
    }
  }
  options.tooth_arc_mm = 90.0;
  EXPECT_FALSE(MakeScanTrajectory(arch, ScanKind::kTooth, options).ok());
}

TEST(MakeScanTrajectory, RefusesBadInputs) {
  ScanPathOptions options;
  const ScanPathResult r = MakeScanTrajectory(TriangleMesh{}, ScanKind::kFullArch, options);
  EXPECT_FALSE(r.ok());
  options.speed_mm_s = 31;  // allowed 5–30
  EXPECT_THROW(options.Check(), std::invalid_argument);
  options = ScanPathOptions{};
  options.passes = {ScanPhase::kTransition};
  EXPECT_THROW(options.Check(), std::invalid_argument);
  EXPECT_NO_THROW(ScanPathOptions{}.Check());
}

TEST(MakeScanTrajectory, TrajectoryIsSmooth) {
  const ArchFrame& arch = SyntheticArch();
  ASSERT_TRUE(arch.ok());
  ScanPathOptions options;
  const ScanPathResult scan = MakeScanTrajectory(arch, ScanKind::kQuadrant, options);
  ASSERT_TRUE(scan.ok());
  // Speed at 1 ms resolution never jumps between neighbouring milliseconds by much (C1 + tremor).
  double prev = LinearSpeedMmPerS(scan.trajectory, scan.trajectory.StartNs() + 1'000'000);
  double max_jump = 0;
  for (int64_t t = scan.trajectory.StartNs() + 2'000'000; t < scan.trajectory.EndNs() - 1'000'000;
       t += 1'000'000) {
    const double v = LinearSpeedMmPerS(scan.trajectory, t);
    max_jump = std::max(max_jump, std::abs(v - prev));
    prev = v;
  }
  EXPECT_LT(max_jump, 2.0);
}

// ---------------------------------------------------------------------------------------------
// The real intraoral scan

TEST(MakeScanTrajectory, FullArchOnTheRealScan) {
  const std::string path = std::string(D3D_SHARED_DATA_DIR) + "/dental/upper_arch_0189MCMV.ply";
  if (!std::filesystem::exists(path))
    GTEST_SKIP() << "real arch not found at " << path << " (../shared/data absent)";
  TriangleMesh mesh;
  const Status st = LoadMesh(path, &mesh);
  ASSERT_TRUE(st.ok()) << st.ToString();
  LabelFacesFromColors(&mesh);
  const ArchFrame arch = AnalyzeArch(mesh);
  ASSERT_TRUE(arch.ok()) << arch.status.ToString();
  EXPECT_TRUE(arch.used_labels);
  // Known for this file (not assumed by the code): crowns toward −y, incisors at +z.
  EXPECT_LT(AngleDeg(arch.occlusal, Eigen::Vector3d(0, -1, 0)), 15.0);
  EXPECT_GT(arch.length_mm, 90.0);
  EXPECT_LT(arch.length_mm, 170.0);
  EXPECT_GT(arch.At(arch.midline_arc_mm).position.z(), 35.0);
  std::printf(
      "[real] occlusal (%.3f %.3f %.3f), length %.1f mm, mean width %.1f mm, midline at %.1f mm\n",
      arch.occlusal.x(), arch.occlusal.y(), arch.occlusal.z(), arch.length_mm, arch.mean_width_mm,
      arch.midline_arc_mm);
  CheckFullArchScan(MakeScanTrajectory(arch, ScanKind::kFullArch, ScanPathOptions{}), "real");

  // Without labels the palate is in: the crowns are found as the most occlusal part.
  mesh.face_labels.clear();
  const ArchFrame unlabelled = AnalyzeArch(mesh);
  ASSERT_TRUE(unlabelled.ok()) << unlabelled.status.ToString();
  EXPECT_FALSE(unlabelled.used_labels);
  EXPECT_LT(AngleDeg(unlabelled.occlusal, arch.occlusal), 5.0);
  EXPECT_NEAR(unlabelled.length_mm, arch.length_mm, 0.15 * arch.length_mm);
  std::printf("[real, unlabelled] length %.1f mm, mean width %.1f mm\n", unlabelled.length_mm,
              unlabelled.mean_width_mm);
}

}  // namespace
}  // namespace d3d
