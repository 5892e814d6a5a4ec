#include "sim/trajectory/scan_styles.h"

#include <gtest/gtest.h>

#include "sim/trajectory/test_arches.h"

namespace d3d {
namespace {

using namespace d3d::testing;

const TriangleMesh& Arch() {
  static const TriangleMesh mesh = RidgeArch(SomeWorldFromLocal(), true);
  return mesh;
}

int CountPhase(const ScanPathResult& r, ScanPhase phase) {
  return static_cast<int>(std::count_if(r.segments.begin(), r.segments.end(),
                                        [&](const ScanSegment& s) { return s.phase == phase; }));
}

TEST(ScanStyles, EveryStylePlansAPathWhoseSegmentsCoverIt) {
  ScanPathOptions o;
  o.seed = 3;
  for (const std::string& style : ScanStyleNames()) {
    const ScanPathResult r = MakeStyledScan(Arch(), style, o);
    ASSERT_TRUE(r.ok()) << style << ": " << r.status.message();
    ASSERT_FALSE(r.segments.empty()) << style;
    EXPECT_EQ(r.segments.front().start_ns, r.trajectory.StartNs()) << style;
    EXPECT_NEAR(static_cast<double>(r.segments.back().end_ns),
                static_cast<double>(r.trajectory.EndNs()), 1e6)
        << style;
    for (size_t i = 1; i < r.segments.size(); ++i)
      EXPECT_GE(r.segments[i].start_ns, r.segments[i - 1].end_ns - 1) << style;
    EXPECT_GT(r.trajectory.DurationNs(), 5'000'000'000) << style;
  }
  EXPECT_FALSE(MakeStyledScan(Arch(), "backwards", o).ok());
  EXPECT_FALSE(IsScanStyle("backwards"));
}

TEST(ScanStyles, StylesDifferAsNamed) {
  ScanPathOptions o;
  const ArchFrame arch = AnalyzeArch(Arch());
  const ScanPathResult base = MakeStyledScan(Arch(), "full-arch", o);
  const ScanPathResult buccal = MakeStyledScan(Arch(), "buccal-first", o);
  const ScanPathResult second = MakeStyledScan(Arch(), "second-pass", o);
  const ScanPathResult fast = MakeStyledScan(Arch(), "fast", o);
  EXPECT_EQ(base.segments.front().phase, ScanPhase::kOcclusal);
  EXPECT_EQ(buccal.segments.front().phase, ScanPhase::kBuccal);
  EXPECT_EQ(MakeStyledScan(Arch(), "lingual-first", o).segments.front().phase, ScanPhase::kLingual);
  EXPECT_EQ(CountPhase(second, ScanPhase::kOcclusal), 2);
  EXPECT_GT(ComputeScanPathStats(fast.trajectory, arch).mean_speed_mm_s,
            1.5 * ComputeScanPathStats(base.trajectory, arch).mean_speed_mm_s);
  EXPECT_LT(fast.trajectory.DurationNs(), base.trajectory.DurationNs() * 2 / 3);
  // Glare is the full arch's path over wet teeth: the same keys, a scene with 3× the specular R0.
  const ScanPathResult glare = MakeStyledScan(Arch(), "glare", o);
  ASSERT_EQ(glare.trajectory.keys().size(), base.trajectory.keys().size());
  EXPECT_EQ(glare.trajectory.EndNs(), base.trajectory.EndNs());
  EXPECT_EQ(ScanStyleWetness("glare"), 3.0);
  EXPECT_EQ(ScanStyleWetness("full-arch"), 1.0);
}

TEST(ScanStyles, LiftsLeaveTheMeasurementVolumeAndComeBackEarlierAlongThePath) {
  for (uint32_t seed : {1u, 2u, 3u}) {
    ScanPathOptions o;
    o.seed = seed;
    const ScanPathResult r = MakeStyledScan(Arch(), "lifts", o);
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(CountPhase(r, ScanPhase::kLift), 3) << "seed " << seed;
    const ScanPathResult base = MakeStyledScan(Arch(), "full-arch", o);
    // 3 lifts of 1–3 s, each put back 2–6 s earlier: 9–27 s longer than the plain path.
    const double extra_s =
        static_cast<double>(r.trajectory.DurationNs() - base.trajectory.DurationNs()) * 1e-9;
    EXPECT_GT(extra_s, 9.0) << "seed " << seed;
    EXPECT_LT(extra_s, 27.0) << "seed " << seed;
    for (const ScanSegment& s : r.segments) {
      if (s.phase != ScanPhase::kLift) continue;
      const double lift_s = static_cast<double>(s.end_ns - s.start_ns) * 1e-9;
      EXPECT_GE(lift_s, 1.0);
      EXPECT_LE(lift_s, 3.0);
      // Halfway through, the probe is far beyond the 42–58 mm measurement volume.
      const double depth =
          AxisDepthToArchMm(r.arch, r.trajectory.WorldFromProbe((s.start_ns + s.end_ns) / 2));
      EXPECT_GT(depth, 70.0) << "seed " << seed;
    }
  }
  // The same seed, the same path.
  ScanPathOptions o;
  o.seed = 2;
  const ScanPathResult a = MakeStyledScan(Arch(), "lifts", o),
                       b = MakeStyledScan(Arch(), "lifts", o);
  ASSERT_EQ(a.trajectory.keys().size(), b.trajectory.keys().size());
  EXPECT_TRUE(a.trajectory.keys().back().world_from_probe.isApprox(
      b.trajectory.keys().back().world_from_probe));
}

TEST(ScanStyles, QuadrantsJoinTwoHalvesByOneLift) {
  ScanPathOptions o;
  const ScanPathResult r = MakeStyledScan(Arch(), "quadrants", o);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(CountPhase(r, ScanPhase::kLift), 1);
  // The two halves start at opposite distal ends.
  const Eigen::Vector3d start = r.trajectory.WorldFromProbe(r.trajectory.StartNs()).translation();
  int64_t resume = 0;
  for (const ScanSegment& s : r.segments)
    if (s.phase == ScanPhase::kLift) resume = s.end_ns;
  const Eigen::Vector3d second = r.trajectory.WorldFromProbe(resume).translation();
  EXPECT_GT((second - start).norm(), 30.0);
}

TEST(ScanStyles, IncisorsFirstStartsBothQuadrantsAtTheMidline) {
  ScanPathOptions o;
  const ScanPathResult r = MakeStyledScan(Arch(), "incisors-first", o);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(CountPhase(r, ScanPhase::kLift), 1);
  const ArchFrame& arch = r.arch;
  const Trajectory& t = r.trajectory;
  int64_t lift_start = 0, resume = 0;
  for (const ScanSegment& s : r.segments)
    if (s.phase == ScanPhase::kLift) lift_start = s.start_ns, resume = s.end_ns;
  // Where the camera looks along the arch (arc mm) at the start, before the lift and after it.
  auto arc = [&](int64_t t_ns) {
    const int i = ArchPointNearestAxis(arch, t.WorldFromProbe(t_ns));
    EXPECT_GE(i, 0);
    return i < 0 ? -1.0 : arch.curve[static_cast<size_t>(i)].arc_mm;
  };
  const double mid = arch.midline_arc_mm;
  EXPECT_LT(std::abs(arc(t.StartNs()) - mid), 8.0);
  EXPECT_LT(std::abs(arc(resume) - mid), 8.0);
  // The first quadrant ends at a distal end, the second at the other one.
  const double end_a = arc(lift_start), end_b = arc(t.EndNs());
  EXPECT_GT(std::abs(end_a - mid), 0.35 * arch.length_mm);
  EXPECT_GT(std::abs(end_b - mid), 0.35 * arch.length_mm);
  EXPECT_LT((end_a - mid) * (end_b - mid), 0.0);
  // Segments ordered and within the path.
  for (size_t k = 1; k < r.segments.size(); ++k)
    EXPECT_LE(r.segments[k - 1].end_ns, r.segments[k].start_ns + 1);
  EXPECT_GE(r.segments.front().start_ns, t.StartNs());
  EXPECT_LE(r.segments.back().end_ns, t.EndNs());
}

TEST(JoinWithLift, ContinuousAtBothEndsAndBacksOffInBetween) {
  ScanPathOptions o;
  const ScanPathResult base = MakeStyledScan(Arch(), "full-arch", o);
  const Trajectory& t = base.trajectory;
  const int64_t cut = t.StartNs() + 10'000'000'000, resume = t.StartNs() + 4'000'000'000,
                lift = 2'000'000'000;
  const Trajectory j = JoinWithLift(t, cut, t, resume, lift, 30.0);
  EXPECT_LT(TranslationDistanceMm(j.WorldFromProbe(cut), t.WorldFromProbe(cut)), 1e-6);
  EXPECT_LT(TranslationDistanceMm(j.WorldFromProbe(cut + lift), t.WorldFromProbe(resume)), 1e-6);
  EXPECT_LT(TranslationDistanceMm(j.WorldFromProbe(cut + lift + 3'000'000'000),
                                  t.WorldFromProbe(resume + 3'000'000'000)),
            1e-6);
  EXPECT_EQ(j.EndNs(), t.EndNs() + cut + lift - resume);
  // Halfway, 30 mm back along the optical axis from the straight move between the two poses.
  const Rigid3d mid = j.WorldFromProbe(cut + lift / 2);
  const Eigen::Vector3d straight =
      0.5 * (t.WorldFromProbe(cut).translation() + t.WorldFromProbe(resume).translation());
  EXPECT_NEAR((mid.translation() - straight).norm(), 30.0, 0.5);
  EXPECT_THROW(JoinWithLift(t, cut, t, resume, 5'000'000, 30.0), std::invalid_argument);
  EXPECT_THROW(JoinWithLift(t, t.EndNs() + 1, t, resume, lift, 30.0), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
