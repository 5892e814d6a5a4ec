#include "sim/trajectory/arch_moves.h"

#include <cmath>
#include <limits>

#include "common/core/status.h"

namespace d3d {

double ArcPositionSeenMm(const ArchFrame& arch, const Rigid3d& world_from_probe) {
  D3D_CHECK_MSG(arch.ok() && !arch.curve.empty(), "ArcPositionSeenMm needs an analysed arch");
  const int i = ArchPointNearestAxis(arch, world_from_probe);
  return i < 0 ? std::numeric_limits<double>::quiet_NaN()
               : arch.curve[static_cast<size_t>(i)].arc_mm;
}

Rigid3d ArchLocalFrame(const ArchFrame& arch, double arc_mm) {
  D3D_CHECK_MSG(arch.ok() && !arch.curve.empty(), "ArchLocalFrame needs an analysed arch");
  const ArchPoint p = arch.At(arc_mm);
  const Eigen::Vector3d o = arch.occlusal.normalized();
  const Eigen::Vector3d t = (p.tangent - p.tangent.dot(o) * o).normalized();
  Rigid3d f = Rigid3d::Identity();
  f.linear().col(0) = t;
  f.linear().col(1) = o.cross(t);  // buccal or lingual by the curve's sense, the same all along it
  f.linear().col(2) = o;
  f.translation() = p.position;
  return f;
}

Rigid3d ArchMove(const ArchFrame& arch, double arc_mm, double delta_arc_mm) {
  return ArchLocalFrame(arch, arc_mm + delta_arc_mm) * ArchLocalFrame(arch, arc_mm).inverse();
}

Rigid3d MirrorAcrossMidline(const ArchFrame& arch, double arc_mm, const Rigid3d& world_from_probe) {
  // The mirror M fixes the occlusal axis, keeps the across axis (outward stays outward) and turns
  // the tangent round: M = F(2·mid − a) · diag(−1, 1, 1) · F(a)⁻¹ in the local frames F. The
  // mirrored pose is M · world_from_probe · diag(−1, 1, 1) (camera x reversed): det = +1.
  const Rigid3d from = ArchLocalFrame(arch, arc_mm);
  const Rigid3d to = ArchLocalFrame(arch, 2 * arch.midline_arc_mm - arc_mm);
  const Eigen::Matrix3d flip_x = Eigen::Vector3d(-1, 1, 1).asDiagonal();
  const Rigid3d local = from.inverse() * world_from_probe;
  Rigid3d out = Rigid3d::Identity();
  out.linear() = to.linear() * flip_x * local.linear() * flip_x;
  out.translation() = to.translation() + to.linear() * flip_x * local.translation();
  return out;
}

}  // namespace d3d
