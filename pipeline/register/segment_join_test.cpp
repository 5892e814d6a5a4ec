#include "pipeline/register/segment_join.h"

#include <gtest/gtest.h>

#include "pipeline/register/test_surfaces.h"

namespace d3d {
namespace {

using namespace d3d::testing;

// The world samples of views looking down at x = from … to (1 mm apart) over the height field.
SurfacePoints Strip(const HeightField& hf, double from, double to, uint32_t seed) {
  const PinholeBrownConrady cam = TestCamera();
  SurfacePoints all;
  for (double x = from; x <= to + 1e-9; x += 1.0) {
    const Rigid3d pose = LookDown(x, 0, 30);
    const SyntheticView v = RenderHeightField(hf, cam, pose, 0.004, seed++);
    const SurfacePoints s = SampleOrganised(v.points, v.normals, cv::Mat(), 2).Transformed(pose);
    all.points.insert(all.points.end(), s.points.begin(), s.points.end());
    all.normals.insert(all.normals.end(), s.normals.begin(), s.normals.end());
  }
  return all;
}

Rigid3d SegmentFrame() {  // segment_from_world: a segment started somewhere else
  Rigid3d g = Rigid3d::Identity();
  g.linear() =
      Eigen::AngleAxisd(0.4, Eigen::Vector3d(0.2, -0.5, 1).normalized()).toRotationMatrix();
  g.translation() = Eigen::Vector3d(2000, 13, -7);
  return g;
}

SegmentJoinOptions SmallViews() {
  SegmentJoinOptions o;
  o.min_correspondences = 300;  // 9.6 × 7.2 mm views
  return o;
}

TEST(JoinSegment, FindsWhereAnOverlappingSegmentBelongs) {
  const HeightField hf(11);
  const SegmentJoinTarget target = MakeSegmentJoinTarget(Strip(hf, -10, 0, 1), SmallViews());
  ASSERT_FALSE(target.empty());
  const Rigid3d g = SegmentFrame();
  const SurfacePoints segment = Strip(hf, -4, 6, 100).Transformed(g);  // overlaps x in [-8.8, 4.8]
  const SegmentJoinResult r = JoinSegment(segment, target, SmallViews());
  ASSERT_TRUE(r.ok) << r.reason;
  const Rigid3d error = r.main_from_segment * g;  // identity when exact
  const Eigen::Vector3d c(-2, 0, 0);              // the overlap's middle
  EXPECT_LT((error * c - c).norm(), 0.02);
  EXPECT_LT(Eigen::AngleAxisd(error.linear()).angle() * 180 / M_PI, 0.05);
  EXPECT_GE(r.icp.correspondences, 300);
}

TEST(JoinSegment, RefusesASegmentWithoutOverlapOrOnAPlane) {
  const HeightField hf(11);
  const SegmentJoinTarget target = MakeSegmentJoinTarget(Strip(hf, -10, 0, 1), SmallViews());
  const SegmentJoinResult apart =
      JoinSegment(Strip(hf, 15, 25, 100).Transformed(SegmentFrame()), target, SmallViews());
  EXPECT_FALSE(apart.ok);
  EXPECT_FALSE(apart.reason.empty());
  HeightField plane(11);
  plane.flat = 1;
  const SegmentJoinTarget flat = MakeSegmentJoinTarget(Strip(plane, -10, 0, 1), SmallViews());
  const SegmentJoinResult on_plane =
      JoinSegment(Strip(plane, -4, 6, 100).Transformed(SegmentFrame()), flat, SmallViews());
  EXPECT_FALSE(on_plane.ok);
  EXPECT_FALSE(JoinSegment(SurfacePoints{}, target, SmallViews()).ok);
  EXPECT_FALSE(JoinSegment(Strip(hf, -4, 6, 100), SegmentJoinTarget{}, SmallViews()).ok);
}

// A segment of two views over ground the main model holds has fewer samples than
// min_correspondences in all: it joins because it lies whole on the model; one of the same size
// only half on it does not.
TEST(RefineSegmentJoin, ASmallSegmentLyingWholeOnTheModelJoins) {
  const HeightField hf(11);
  SegmentJoinOptions o = SmallViews();
  o.min_contained_correspondences = 100;
  const SegmentJoinTarget target = MakeSegmentJoinTarget(Strip(hf, -10, 0, 1), o);
  const Rigid3d g = SegmentFrame();
  Rigid3d off_by = Rigid3d::Identity();  // 0.2 mm and 0.3° about the segment's middle
  off_by.linear() = Eigen::AngleAxisd(0.005, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const Eigen::Vector3d mid(-5.5, 0, 0);
  off_by.translation() = mid - off_by.linear() * mid + Eigen::Vector3d(0.15, -0.1, 0.08);
  const Rigid3d near = off_by * g.inverse();  // main_from_segment
  const SegmentJoinTarget inside = MakeSegmentJoinTarget(Strip(hf, -6, -5, 100).Transformed(g), o);
  o.min_correspondences = static_cast<int>(inside.samples.size()) + 1;  // more than it has
  const SegmentJoinResult r = RefineSegmentJoin(inside, target, near, o);
  ASSERT_TRUE(r.ok) << r.reason;
  const Rigid3d error = r.main_from_segment * g;
  EXPECT_LT((error * mid - mid).norm(), 0.02);
  SegmentJoinOptions off = o;
  off.min_contained_fraction = 0;
  const SegmentJoinResult refused = RefineSegmentJoin(inside, target, near, off);
  EXPECT_FALSE(refused.ok);
  EXPECT_NE(refused.reason.find("too little overlap"), std::string::npos) << refused.reason;
  // Half of it over ground the model has not seen (views at x = 4, 5: the model ends at 4.8).
  const SegmentJoinTarget half = MakeSegmentJoinTarget(Strip(hf, 4, 5, 100).Transformed(g), o);
  SegmentJoinOptions big = o;
  big.min_correspondences = static_cast<int>(half.samples.size()) + 1;
  const SegmentJoinResult out = RefineSegmentJoin(half, target, near, big);
  EXPECT_FALSE(out.ok);
  EXPECT_NE(out.reason.find("too little overlap"), std::string::npos) << out.reason;
}

// Samples of the height field over [x0, x1] × [y0, y1] on a 0.25 mm grid, moved by `pose`.
SurfacePoints Patch(const HeightField& hf, double x0, double x1, double y0, double y1,
                    const Rigid3d& pose = Rigid3d::Identity()) {
  SurfacePoints s;
  for (double x = x0; x <= x1 + 1e-9; x += 0.25)
    for (double y = y0; y <= y1 + 1e-9; y += 0.25) {
      double gx = 0, gy = 0;
      const double z = hf.HeightAndGradient(x, y, &gx, &gy);
      s.points.push_back((pose * Eigen::Vector3d(x, y, z)).cast<float>());
      s.normals.push_back(
          (pose.linear() * Eigen::Vector3d(-gx, -gy, 1).normalized()).cast<float>());
    }
  return s;
}

void Append(const SurfacePoints& a, SurfacePoints* to) {
  to->points.insert(to->points.end(), a.points.begin(), a.points.end());
  to->normals.insert(to->normals.end(), a.normals.begin(), a.normals.end());
}

// The main model holds the ground x ∈ [−14, 0] and, elsewhere (turned 180° about z, 40 mm away), a
// copy of its part x ∈ [−10, 0] beside other ground, 0.8 mm higher: the left and right quadrants
// of an arch that look alike. A segment over x ∈ [−10, 8] has two verified FPFH consensuses; both
// hold when refined with the whole segment, but the copy's puts the segment's new ground x ∈ [0, 8]
// through the other ground. A segment over the common part alone holds both: refused.
TEST(JoinSegment, AnAmbiguityIsSettledByTheWholeSegment) {
  const HeightField hf(11), other(29);
  Rigid3d copy = Rigid3d::Identity();
  copy.linear() = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  copy.translation() = Eigen::Vector3d(0, 40, 0);
  SurfacePoints main = Patch(hf, -14, 0, -5, 5);
  Append(Patch(hf, -10, 0, -5, 5, copy), &main);
  Rigid3d beside = Rigid3d::Identity();  // where the copy's continuation would be: other ground
  beside.translation() = Eigen::Vector3d(0, 40, 0.8);
  Append(Patch(other, -8, 0, -5, 5, beside), &main);
  const SegmentJoinOptions o = SmallViews();
  const SegmentJoinTarget target = MakeSegmentJoinTarget(main, o);
  const Rigid3d g = SegmentFrame();
  const SegmentJoinTarget segment = MakeSegmentJoinTarget(Patch(hf, -10, 8, -5, 5, g), o);

  SegmentJoinOptions refuse = o;
  refuse.settle_ambiguity = false;
  const SegmentJoinResult ambiguous = JoinSegment(segment, target, refuse);
  ASSERT_FALSE(ambiguous.ok);
  ASSERT_TRUE(ambiguous.fpfh.rival_verified) << ambiguous.reason;

  const SegmentJoinResult r = JoinSegment(segment, target, o);
  ASSERT_TRUE(r.ok) << r.reason;
  EXPECT_TRUE(r.settled);
  EXPECT_NE(r.reason.find("settled by the whole segment"), std::string::npos) << r.reason;
  const Rigid3d error = r.main_from_segment * g;  // identity when exact
  const Eigen::Vector3d c(-5, 0, 0);              // the overlap's middle
  EXPECT_LT((error * c - c).norm(), 0.02);
  EXPECT_LT(Eigen::AngleAxisd(error.linear()).angle() * 180 / M_PI, 0.05);

  const SegmentJoinTarget common = MakeSegmentJoinTarget(Patch(hf, -10, 0, -5, 5, g), o);
  const SegmentJoinResult both = JoinSegment(common, target, o);
  EXPECT_FALSE(both.ok);
  EXPECT_FALSE(both.settled);
  EXPECT_NE(both.reason.find("holds both"), std::string::npos) << both.reason;
}

}  // namespace
}  // namespace d3d
