// Named scan-path styles of the virtual probe: the ways dentists actually scan, each a seeded
// variation of the planned scan paths (scan_path.h), so that the registration is tested on more
// than the path it was tuned on.
//
//   full-arch       occlusal, buccal, lingual passes from one distal end to the other (the default)
//   buccal-first    the same passes, buccal first: buccal, occlusal, lingual
//   lingual-first   lingual, occlusal, buccal
//   second-pass     a second occlusal pass after the three (over a region already scanned)
//   fast            the full arch at 27 mm/s of the aimed point (faster hands; camera up to 35
//   mm/s) lifts           the full arch with 3 lifts: at seeded times the probe leaves the mouth
//   (backs off
//                   30 mm along its axis, out of the measurement volume) for 1–3 s and is put back
//                   2–6 s earlier along the path, over a tooth already scanned ("fill the hole")
//   quadrants       one quadrant (distal end to the midline), a 2 s lift, then the other quadrant
//                   (its distal end to the midline): the second starts on ground not yet scanned
//                   and joins the first over the incisors
//   incisors-first  each quadrant from the central incisors out to its distal end (a quadrant path
//                   played backwards), a 1.5 s lift between them: the second starts where the first
//                   began, over the model's oldest part
//   tooth           a dwell circling one molar (ScanKind::kTooth)
//   glare           the full arch over wet teeth: pooled saliva, the specular reflectance of enamel
//                   and gingiva ×3 (ScanStyleWetness), so more glints saturate the camera
//
// Units: mm, ns, s where a name says so.
#pragma once

#include <string>
#include <vector>

#include "common/core/status.h"
#include "common/mesh/mesh.h"
#include "sim/trajectory/scan_path.h"

namespace d3d {

// The style names above, in that order.
const std::vector<std::string>& ScanStyleNames();
bool IsScanStyle(const std::string& name);
// The names joined by `separator` ("full-arch | buccal-first | ..."), for help texts.
std::string ScanStyleList(const std::string& separator = " | ");
// The factor on the materials' specular reflectance R0 (probe_design.h: Material) that the style's
// scene takes: 3 for "glare", 1 otherwise. A stress condition, not a measured saliva film.
double ScanStyleWetness(const std::string& style);

// Plans scan-path style `style` over `mesh` with `base` (its seed seeds the style's own choices
// too: lift times, durations and where the probe is put back). The result's segments include the
// lifts (ScanPhase::kLift). INVALID_ARGUMENT for an unknown style; otherwise MakeScanTrajectory's
// status. Throws std::invalid_argument when base.Check() fails.
ScanPathResult MakeStyledScan(const TriangleMesh& mesh, const std::string& style,
                              const ScanPathOptions& base);

// Joins two trajectories by a lift: `a` up to a_end_ns, then for lift_ns the probe backs off
// lift_mm along its optical axis (smooth rise, hold, descent over the first / middle / last part)
// while it moves and turns to b's pose at b_start_ns, then `b` from b_start_ns on, shifted in time
// to follow. Keys every key_interval_ns during the lift. Throws std::invalid_argument unless
// a_end_ns and b_start_ns lie within their trajectories, lift_ns > 2 · key_interval_ns and lift_mm
// >= 0.
Trajectory JoinWithLift(const Trajectory& a, int64_t a_end_ns, const Trajectory& b,
                        int64_t b_start_ns, int64_t lift_ns, double lift_mm,
                        int64_t key_interval_ns = 5'000'000);

}  // namespace d3d
