#include "pipeline/register/icp.h"

#include <gtest/gtest.h>

#include <random>

#include "pipeline/register/grid_target.h"
#include "pipeline/register/test_surfaces.h"

namespace d3d {
namespace {

using testing::HeightField;
using testing::LookDown;
using testing::RenderHeightField;
using testing::TestCamera;

Rigid3d Perturbation(double deg, double mm) {
  Rigid3d T = Rigid3d::Identity();
  T.linear() = Eigen::AngleAxisd(deg * M_PI / 180, Eigen::Vector3d(0.3, -1, 0.4).normalized())
                   .toRotationMatrix();
  T.translation() = Eigen::Vector3d(0.6, -0.8, 0.3).normalized() * mm;
  return T;
}

struct Pair {
  SurfacePoints source, target;
  cv::Mat target_points, target_normals;
  Rigid3d target_from_source;
  PinholeIntrinsics k;
};

// Two views of the bumpy surface 1.5 mm apart; returns samples in their camera frames.
Pair MakePair(const HeightField& hf, double shift_mm, double noise_mm) {
  const auto cam = TestCamera();
  const Rigid3d wa = LookDown(0, 0, 30), wb = LookDown(shift_mm, 0.3, 30.2, 0.03, -0.04, 0.05);
  const auto va = RenderHeightField(hf, cam, wa, noise_mm, 1),
             vb = RenderHeightField(hf, cam, wb, noise_mm, 2);
  Pair p;
  p.target = SampleOrganised(va.points, va.normals, va.quality, 1);
  p.source = SampleOrganised(vb.points, vb.normals, vb.quality, 2);
  p.target_points = va.points;
  p.target_normals = va.normals;
  p.target_from_source = wa.inverse() * wb;
  p.k = {cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height};
  return p;
}

// The bumpy surface seen from two poses 1.5 mm apart (5 µm noise), and a start 1° / 0.3 mm off.
struct StartedPair {
  Pair p;
  Rigid3d init;
};
StartedPair StandardPair() {
  const HeightField hf(11);
  StartedPair c{MakePair(hf, 1.5, 0.005), Rigid3d::Identity()};
  c.init = Perturbation(1.0, 0.3) * c.p.target_from_source;
  return c;
}

TEST(Icp, RecoversAKnownTransformWithBothAssociations) {
  const auto [p, init] = StandardPair();
  IcpOptions o;
  KdTreeTarget kd(p.target);
  const IcpResult a = RegisterIcp(p.source, kd, init, o);
  ASSERT_TRUE(a.ok) << a.reason;
  EXPECT_LT(RotationAngleRad(a.target_from_source, p.target_from_source) * 180 / M_PI, 0.01);
  EXPECT_LT(TranslationDistanceMm(a.target_from_source, p.target_from_source),
            0.004);  // at the camera, 30 mm away
  EXPECT_GT(a.overlap, 0.5);
  EXPECT_LT(a.rmse_mm, 0.012);
  // Projective association in the target's own image (the target frame is its camera frame).
  ProjectiveTarget pt(p.target_points, p.target_normals, p.k, Rigid3d::Identity(), 2);
  const IcpResult b = RegisterIcp(p.source, pt, init, o);
  ASSERT_TRUE(b.ok) << b.reason;
  EXPECT_LT(RotationAngleRad(b.target_from_source, p.target_from_source) * 180 / M_PI, 0.01);
  EXPECT_LT(TranslationDistanceMm(b.target_from_source, p.target_from_source), 0.004);
}

TEST(Icp, ALevelsSampleCapThinsItsSamplesAndKeepsThePose) {
  const auto [p, init] = StandardPair();
  KdTreeTarget kd(p.target);
  IcpOptions capped;
  const int cap = static_cast<int>(p.source.size() / 4);
  for (IcpLevel& l : capped.levels) l.max_samples = cap;
  const IcpResult all = RegisterIcp(p.source, kd, init, IcpOptions{});
  const IcpResult few = RegisterIcp(p.source, kd, init, capped);
  ASSERT_TRUE(all.ok) << all.reason;
  ASSERT_TRUE(few.ok) << few.reason;
  // The final level used at most the cap (correspondences ≤ samples) where it used ~all before.
  EXPECT_GT(all.correspondences, 2 * cap);
  EXPECT_LE(few.correspondences, cap);
  EXPECT_LT(RotationAngleRad(few.target_from_source, p.target_from_source) * 180 / M_PI, 0.01);
  EXPECT_LT(TranslationDistanceMm(few.target_from_source, p.target_from_source), 0.004);
  capped.levels[0].max_samples = -1;
  EXPECT_THROW(capped.Check(), std::invalid_argument);
}

// A level's own termination ends it sooner; the next level finds the pose all the same. With the
// coarse levels' micrometre ends ignored the first level runs on (more iterations): fails.
TEST(Icp, ALevelsOwnTerminationEndsItSoonerAndTheNextLevelKeepsThePose) {
  const auto [p, init] = StandardPair();
  KdTreeTarget kd(p.target);
  IcpOptions strict;
  strict.levels = {{4, 30, 1.0, 1.0}, {1, 30, 0.3, 1.0}};
  IcpOptions loose = strict;
  loose.levels[0].min_delta_translation_mm = 0.02;
  loose.levels[0].min_delta_rotation_rad = 1e-3;
  const IcpResult a = RegisterIcp(p.source, kd, init, strict);
  const IcpResult b = RegisterIcp(p.source, kd, init, loose);
  ASSERT_TRUE(a.ok) << a.reason;
  ASSERT_TRUE(b.ok) << b.reason;
  EXPECT_LT(b.iterations, a.iterations);  // 10 against 14
  EXPECT_LT(RotationAngleRad(b.target_from_source, p.target_from_source) * 180 / M_PI,
            0.015);  // 0.011°, as strict
  EXPECT_LT(TranslationDistanceMm(b.target_from_source, p.target_from_source),
            0.006);  // 4.8 µm, as strict
  EXPECT_LT(TranslationDistanceMm(a.target_from_source, b.target_from_source), 0.001);  // 0.03 µm
  loose.levels[1].min_delta_rotation_rad = -1;
  EXPECT_THROW(loose.Check(), std::invalid_argument);
}

// threads > 1 forms the normal equations in fixed chunks summed in a fixed order: the same pose as
// one thread up to rounding, and bit for bit the same from run to run (lossless replay must
// repeat).
TEST(Icp, TwoThreadsAgreeWithOneAndRepeatExactly) {
  const auto [p, init] = StandardPair();
  KdTreeTarget kd(p.target);
  IcpOptions o;
  o.levels = {{4, 12, 1.0, 0.7},
              {1, 10, 0.3, 0.9}};  // both metrics (α < 1) and enough matches for several chunks
  const IcpResult one = RegisterIcp(p.source, kd, init, o);
  o.threads = 2;
  const IcpResult two = RegisterIcp(p.source, kd, init, o);
  ASSERT_TRUE(one.ok) << one.reason;
  ASSERT_TRUE(two.ok) << two.reason;
  ASSERT_GT(two.correspondences, 2 * 4096);
  EXPECT_LT(RotationAngleRad(one.target_from_source, two.target_from_source), 1e-9);
  EXPECT_LT(TranslationDistanceMm(one.target_from_source, two.target_from_source), 1e-9);
  EXPECT_NEAR(one.rmse_mm, two.rmse_mm, 1e-12);
  for (int run = 0; run < 3; ++run) {
    const IcpResult again = RegisterIcp(p.source, kd, init, o);
    EXPECT_TRUE(again.target_from_source.matrix() == two.target_from_source.matrix())
        << "run " << run;
    EXPECT_TRUE(again.information == two.information) << "run " << run;
  }
}

// Reusing certified associations between iterations (association_reuse_margin) changes no match:
// the same pose, bit for bit, on one thread and two, with most searches saved.
TEST(Icp, ReusedAssociationsGiveTheSamePoseBitForBit) {
  const HeightField hf(13);
  const auto cam = TestCamera();
  const Rigid3d wa = LookDown(0, 0, 30), wb = LookDown(1.2, -0.4, 30.3, 0.02, 0.03, -0.04);
  const auto va = RenderHeightField(hf, cam, wa, 0.005, 3),
             vb = RenderHeightField(hf, cam, wb, 0.005, 4);
  const SurfacePoints target = SampleOrganised(va.points, va.normals, va.quality, 1);
  const SurfacePoints source = SampleOrganised(vb.points, vb.normals, vb.quality, 2);
  Rigid3d init = wa.inverse() * wb;
  init.translation() += Eigen::Vector3d(0.25, -0.1, 0.08);
  IcpOptions o;
  std::vector<double> gates;
  for (const IcpLevel& l : o.levels) gates.push_back(l.max_distance_mm);
  GridTarget grid;
  grid.Build(target, gates, 1.0);  // the coarse level decimated, as the tracker's
  for (const int threads : {1, 2}) {
    o.threads = threads;
    o.association_reuse_margin = 0;
    const IcpResult every = RegisterIcp(source, grid, init, o);
    o.association_reuse_margin = 0.1;
    const IcpResult reused = RegisterIcp(source, grid, init, o);
    ASSERT_TRUE(every.ok) << every.reason;
    ASSERT_TRUE(reused.ok) << reused.reason;
    EXPECT_EQ(every.target_from_source.matrix(), reused.target_from_source.matrix());
    EXPECT_EQ(every.iterations, reused.iterations);
    EXPECT_EQ(every.correspondences, reused.correspondences);
    EXPECT_EQ(every.rmse_mm, reused.rmse_mm);
    EXPECT_EQ(every.information, reused.information);
    EXPECT_EQ(every.searches_reused, 0);
    EXPECT_EQ(reused.searches + reused.searches_reused, every.searches);
    EXPECT_GT(reused.searches_reused, every.searches / 3) << "searches " << reused.searches;
    EXPECT_LT(TranslationDistanceMm(reused.target_from_source, wa.inverse() * wb), 0.005);
  }
  // A target that cannot certify (the k-d tree) searches every time.
  const IcpResult tree = RegisterIcp(source, KdTreeTarget(target), init, o);
  EXPECT_EQ(tree.searches_reused, 0);
  EXPECT_GT(tree.searches, 0);
}

TEST(Icp, CombinedMetricAtEveryLevelConverges) {
  const HeightField hf(12);
  const Pair p = MakePair(hf, 1.0, 0.0);
  IcpOptions o;
  o.levels = {{8, 30, 1.0, 0.7}, {2, 30, 0.3, 0.8}, {1, 30, 0.1, 0.9}};
  KdTreeTarget kd(p.target);
  const IcpResult a = RegisterIcp(p.source, kd, Perturbation(0.5, 0.1) * p.target_from_source, o);
  ASSERT_TRUE(a.ok) << a.reason;
  EXPECT_LT(TranslationDistanceMm(a.target_from_source, p.target_from_source), 0.03);
}

// The point-to-point term alone (α = 0; its sums come in closed form from the matches' moments)
// and half-and-half: a view registered onto its own samples from a start closer than half their
// spacing (so every nearest neighbour is the true one) comes back to the identity; the information
// stays the plane term's, whatever α.
TEST(Icp, PointToPointTermAloneConverges) {
  const HeightField hf(12);
  const Pair p = MakePair(hf, 1.0, 0.0);
  KdTreeTarget kd(p.target);
  IcpLevel level;
  level.max_iterations = 30;
  level.max_distance_mm = 0.3;
  IcpOptions plane;
  plane.levels.assign(1, level);
  const Rigid3d start = Perturbation(0.02, 0.01);
  const IcpResult by_plane = RegisterIcp(p.target, kd, start, plane);
  ASSERT_TRUE(by_plane.ok) << by_plane.reason;
  for (const double alpha : {0.0, 0.5}) {
    SCOPED_TRACE(alpha);
    IcpOptions o = plane;
    o.levels[0].point_to_plane_weight = alpha;
    const IcpResult a = RegisterIcp(p.target, kd, start, o);
    ASSERT_TRUE(a.ok) << a.reason;
    EXPECT_LT(TranslationDistanceMm(a.target_from_source, Rigid3d::Identity()), 1e-4);
    EXPECT_LT(RotationAngleRad(a.target_from_source, Rigid3d::Identity()), 1e-6);
    EXPECT_LT((a.information - by_plane.information).norm(), 1e-3 * by_plane.information.norm());
  }
}

TEST(Icp, PlaneIsDegenerate) {
  HeightField hf(13);
  hf.flat = 1;
  const Pair p = MakePair(hf, 1.0, 0.002);
  KdTreeTarget kd(p.target);
  const IcpResult r = RegisterIcp(p.source, kd, p.target_from_source, IcpOptions{});
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.reason.find("degenerate"), std::string::npos) << r.reason;
}

TEST(Icp, RemappedOnAPlaneOnlyTheConstrainedMotionIsTaken) {
  // A plane seen twice: ICP fixes the height and the tilt, the slide in the plane and the turn
  // about its normal are free. From a start 0.1 mm too high and 0.3 mm off in the plane, plain ICP
  // slides anywhere; with solution remapping the height and tilt are fixed and the view's centre
  // stays where the start put it in the plane. (The plane is z = 0 in the target camera's frame
  // turned by LookDown: its normal is the z axis.)
  HeightField hf(13);
  hf.flat = 1;
  const Pair p = MakePair(hf, 1.0, 0.002);
  KdTreeTarget kd(p.target);
  Rigid3d off = Rigid3d::Identity();
  off.translation() = Eigen::Vector3d(0.3, -0.2, 0.1);
  off.linear() = Eigen::AngleAxisd(0.3 * M_PI / 180, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const Rigid3d init = off * p.target_from_source;
  const Eigen::Vector3d c = p.target_from_source * p.source.Centroid();
  const Eigen::Vector3d started = off * c - c;
  IcpOptions remap;
  remap.remap_min_eigen_ratio = 0.02;
  for (const bool remapped : {true, false}) {
    SCOPED_TRACE(remapped);
    const IcpResult r = RegisterIcp(p.source, kd, init, remapped ? remap : IcpOptions{});
    EXPECT_FALSE(r.ok);  // still degenerate
    EXPECT_NE(r.reason.find("degenerate"), std::string::npos) << r.reason;
    const Rigid3d e =
        r.target_from_source * p.target_from_source.inverse();  // its error, target frame
    const Eigen::Vector3d moved = e * c - c;                    // where the view's centre went
    EXPECT_NEAR(moved.z(), 0.0, 0.01);                          // back onto the plane either way
    EXPECT_LT(std::acos(std::min(1.0, (e.linear() * Eigen::Vector3d::UnitZ()).z())) * 180 / M_PI,
              0.02);                                            // tilt fixed
    const double slid_mm = (moved - started).head<2>().norm();  // in the plane, from the start
    if (remapped) {
      EXPECT_LT(slid_mm, 0.02);
    } else {
      EXPECT_GT(slid_mm, 0.1);  // plain ICP slides
    }
  }
  // A well-constrained fit is the same with remapping.
  const auto [q, qinit] = StandardPair();
  KdTreeTarget kq(q.target);
  const IcpResult plain = RegisterIcp(q.source, kq, qinit, IcpOptions{}),
                  mapped = RegisterIcp(q.source, kq, qinit, remap);
  ASSERT_TRUE(plain.ok && mapped.ok) << plain.reason << " / " << mapped.reason;
  EXPECT_LT(TranslationDistanceMm(plain.target_from_source, mapped.target_from_source), 1e-3);
  remap.remap_min_eigen_ratio = 1;
  EXPECT_THROW(remap.Check(), std::invalid_argument);
}

// A source much larger than its overlap (the view plus a copy of it 60 mm away, where the target
// has nothing: a scan segment that meets the model at one end). Judged on the whole source, the
// rotations scaled by its radius make the well-held overlap look degenerate; judged on the
// associated samples (conditioning_on_overlap) the ratio is at least the view's own, and a plane's
// overlap stays degenerate.
TEST(Icp, ConditioningOnTheOverlapJudgesWhereTheSourceMeetsTheTarget) {
  const auto with_tail = [](const SurfacePoints& s) {
    SurfacePoints out = s;
    for (size_t i = 0; i < s.size(); ++i) {
      out.points.push_back(s.points[i] + Eigen::Vector3f(60, 0, 0));
      out.normals.push_back(s.normals[i]);
    }
    return out;
  };
  IcpOptions on;
  on.conditioning_on_overlap = true;
  on.min_overlap = 0.2;  // half the long source lies on the target
  IcpOptions whole = on;
  whole.conditioning_on_overlap = false;
  const auto [p, init] = StandardPair();
  KdTreeTarget kd(p.target);
  const IcpResult view = RegisterIcp(p.source, kd, init, IcpOptions{});
  const IcpResult long_whole = RegisterIcp(with_tail(p.source), kd, init, whole);
  const IcpResult long_on = RegisterIcp(with_tail(p.source), kd, init, on);
  ASSERT_TRUE(view.ok) << view.reason;
  ASSERT_TRUE(long_on.ok) << long_on.reason;
  EXPECT_FALSE(long_whole.ok);
  EXPECT_NE(long_whole.reason.find("degenerate"), std::string::npos) << long_whole.reason;
  EXPECT_LT(long_whole.eigen_ratio, 0.2 * view.eigen_ratio);
  EXPECT_GE(long_on.eigen_ratio,
            view.eigen_ratio);  // the overlap is a little smaller than the view
  EXPECT_LT(RotationAngleRad(long_on.target_from_source, p.target_from_source) * 180 / M_PI, 0.01);

  HeightField flat(13);
  flat.flat = 1;
  const Pair plane = MakePair(flat, 1.0, 0.002);
  KdTreeTarget kp(plane.target);
  const IcpResult on_plane = RegisterIcp(with_tail(plane.source), kp, plane.target_from_source, on);
  EXPECT_FALSE(on_plane.ok);
  EXPECT_NE(on_plane.reason.find("degenerate"), std::string::npos) << on_plane.reason;
}

TEST(Icp, SphereIsSymmetric) {
  // Samples of a sphere cap: rotations about its centre slide freely.
  SurfacePoints s;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> U(-1, 1);
  while (s.size() < 4000) {
    Eigen::Vector3d d(U(rng), U(rng), U(rng));
    if (d.norm() > 1 || d.norm() < 0.1 || d.z() > -0.3) continue;
    d.normalize();
    s.points.push_back((Eigen::Vector3d(0, 0, 40) + 5 * d).cast<float>());
    s.normals.push_back((-d).cast<float>());
  }
  KdTreeTarget kd(s);
  const IcpResult r = RegisterIcp(s, kd, Perturbation(0.3, 0.02), IcpOptions{});
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.reason.find("degenerate"), std::string::npos) << r.reason;
}

TEST(Icp, LowOverlapFailsCleanly) {
  const HeightField hf(14);
  const Pair p = MakePair(hf, 8.5, 0.003);  // 9.6 mm wide views, 8.5 mm apart: ~10 % overlap
  KdTreeTarget kd(p.target);
  const IcpResult r = RegisterIcp(p.source, kd, p.target_from_source, IcpOptions{});
  EXPECT_FALSE(r.ok);
  EXPECT_TRUE(r.reason.find("overlap") != std::string::npos ||
              r.reason.find("correspondences") != std::string::npos)
      << r.reason;
}

// A level's min_overlap ends a registration whose coarse level has left the target: the finer
// levels do not run (fewer iterations), and the same pair with it off runs them all.
TEST(Icp, ALevelsMinOverlapEndsAStartThatLeftTheTarget) {
  const HeightField hf(14);
  const Pair p = MakePair(hf, 6.0, 0.003);  // 9.6 mm wide views, 6 mm apart: ~35 % overlap
  KdTreeTarget kd(p.target);
  IcpOptions o;
  o.min_overlap = 0.5;
  const IcpResult all = RegisterIcp(p.source, kd, p.target_from_source, o);
  EXPECT_FALSE(all.ok);
  o.levels[0].min_overlap = 0.5;
  const IcpResult early = RegisterIcp(p.source, kd, p.target_from_source, o);
  EXPECT_FALSE(early.ok);
  EXPECT_NE(early.reason.find("left the target at level 0"), std::string::npos) << early.reason;
  EXPECT_LT(early.iterations, all.iterations);
  EXPECT_LT(early.overlap, 0.5);
  // A start on the target passes the same limit.
  const StartedPair c = StandardPair();
  IcpOptions good;
  good.levels[0].min_overlap = 0.5;
  EXPECT_TRUE(RegisterIcp(c.p.source, KdTreeTarget(c.p.target), c.init, good).ok);
}

}  // namespace
}  // namespace d3d
