// Probe poses moved along a dental arch or mirrored across its midline: the starting places of an
// adversarial re-entry set (issue 50: views of tooth N tried from tooth N ± 1 and from the
// contralateral tooth). The moves act on the probe's pose relative to the arch curve, so a moved
// probe sees the other tooth from the same side, distance and angle as the original saw its own.
#pragma once

#include "common/core/rigid.h"
#include "sim/trajectory/scan_path.h"

namespace d3d {

// The arc position (mm, ArchFrame::curve's arc_mm) of the curve point nearest the probe's optical
// axis, in front of the camera (what the probe looks at; see AxisDepthToArchMm). NaN when the whole
// curve is behind the camera. Requires arch.ok().
double ArcPositionSeenMm(const ArchFrame& arch, const Rigid3d& world_from_probe);

// The arch's local frame at arc position arc_mm: columns tangent, buccal, occlusal
// (orthonormalised, occlusal kept), origin at the curve point. Requires arch.ok().
Rigid3d ArchLocalFrame(const ArchFrame& arch, double arc_mm);

// The rigid move that carries the arch's local frame at arc_mm to the one at arc_mm + delta_arc_mm:
// applied to a pose looking at arc_mm, world_from_moved = ArchMove(...) · world_from_probe.
Rigid3d ArchMove(const ArchFrame& arch, double arc_mm, double delta_arc_mm);

// A pose mirrored across the arch's midline (ArchFrame::midline_arc_mm): the pose relative to the
// local frame at arc_mm, with the tangent reversed, placed at 2·midline − arc_mm. A reflection is
// not a rigid motion; the camera's x axis is reversed too so the result is a proper pose (it sees
// the mirrored surface as a mirror image). arc_mm: ArcPositionSeenMm of the pose (or any
// reference).
Rigid3d MirrorAcrossMidline(const ArchFrame& arch, double arc_mm, const Rigid3d& world_from_probe);

}  // namespace d3d
