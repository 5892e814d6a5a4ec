#include "sim/trajectory/arch_moves.h"

#include <gtest/gtest.h>

#include "sim/trajectory/test_arches.h"

namespace d3d {
namespace {

using namespace d3d::testing;

// A probe 15 mm above the curve point at arc_mm, looking down the occlusal axis, tilted a little.
Rigid3d LookingAt(const ArchFrame& arch, double arc_mm) {
  const Rigid3d f = ArchLocalFrame(arch, arc_mm);
  Rigid3d local = Rigid3d::Identity();
  local.linear() = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix() *
                   Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitY()).toRotationMatrix();
  local.translation() = Eigen::Vector3d(0.5, 1.0, 15.0);
  return f * local;
}

TEST(ArchMoves, ArcPositionIsWhereTheProbeLooks) {
  const ArchFrame& arch = SyntheticArch();
  ASSERT_TRUE(arch.ok());
  for (double a : {10.0, 40.0, arch.midline_arc_mm, arch.length_mm - 15})
    EXPECT_NEAR(ArcPositionSeenMm(arch, LookingAt(arch, a)), a, 4.0) << "arc " << a;
}

TEST(ArchMoves, AMoveAlongALegIsATranslationAlongIt) {
  const ArchFrame& arch = SyntheticArch();
  const Rigid3d p = LookingAt(arch, 3.0);  // on the first 12 mm leg (straight)
  const Rigid3d moved = ArchMove(arch, 3.0, 6.0) * p;
  EXPECT_NEAR(TranslationDistanceMm(moved, p), 6.0, 0.3);
  EXPECT_LT(RotationAngleRad(moved, p) * 180 / M_PI, 2.0);
  // There and back again.
  const Rigid3d back = ArchMove(arch, 9.0, -6.0) * moved;
  EXPECT_LT(TranslationDistanceMm(back, p), 1e-6);
  EXPECT_LT(RotationAngleRad(back, p), 1e-9);
}

TEST(ArchMoves, TheMirrorIsTheArchsOwnSymmetry) {
  // The synthetic U arch is symmetric about its local plane X = 0 (scan_path's test arches).
  const ArchFrame& arch = SyntheticArch();
  const Rigid3d world_from_local = SomeWorldFromLocal();
  const Eigen::Matrix3d flip_x = Eigen::Vector3d(-1, 1, 1).asDiagonal();
  for (double a : {8.0, 30.0, 45.0}) {
    const Rigid3d p = LookingAt(arch, a);
    const Rigid3d local = world_from_local.inverse() * p;
    Rigid3d want = Rigid3d::Identity();
    want.linear() = world_from_local.linear() * flip_x * local.linear() * flip_x;
    want.translation() = world_from_local * (flip_x * local.translation());
    const Rigid3d got = MirrorAcrossMidline(arch, a, p);
    EXPECT_NEAR(got.linear().determinant(), 1.0, 1e-9);
    EXPECT_LT(TranslationDistanceMm(got, want), 1.0) << "arc " << a;
    EXPECT_LT(RotationAngleRad(got, want) * 180 / M_PI, 3.0) << "arc " << a;
    // Twice is the pose again.
    const Rigid3d twice = MirrorAcrossMidline(arch, 2 * arch.midline_arc_mm - a, got);
    EXPECT_LT(TranslationDistanceMm(twice, p), 1e-6);
  }
}

}  // namespace
}  // namespace d3d
