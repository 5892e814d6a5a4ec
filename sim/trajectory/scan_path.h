// Plausible hand-held scans of a dental arch: the arch's geometry found from the mesh itself, and
// continuous-time probe trajectories that follow the usual clinical protocol.
//
// Frames and units: world = the mesh's frame (no axis convention assumed); probe = camera frame
// (OpenCV: +z optical axis toward the scene, +x image right, +y image down). mm, ns, rad unless a
// name says otherwise (…_deg, …_hz, …_mm_s).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "common/core/rigid.h"
#include "common/core/status.h"
#include "common/mesh/mesh.h"
#include "sim/trajectory/trajectory.h"

namespace d3d {

// ---------------------------------------------------------------------------------------------
// Arch analysis

// A sample of the arch curve (world frame).
struct ArchPoint {
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  // mm: middle of the tooth band, at the
                                                       // height of the occlusal (biting) surface
  Eigen::Vector3d tangent = Eigen::Vector3d::UnitX();  // unit, toward increasing arc length
  Eigen::Vector3d buccal = Eigen::Vector3d::UnitY();  // unit, outward (cheek/lip side), ⟂ tangent
                                                      // and ⟂ the occlusal direction
  double arc_mm = 0;                                  // arc length from the curve's first end
  double half_width_mm = 0;  // half the band's buccal-lingual width here (95th percentile)
};

// The geometry of a dental arch, found from the mesh alone.
struct ArchFrame {
  Status status;  // ok, or why the mesh is not taken for an arch (the other fields are then unset)
  // Unit vector from the roots toward the biting surfaces (world frame).
  Eigen::Vector3d occlusal = Eigen::Vector3d::UnitZ();
  Eigen::Vector3d centroid =
      Eigen::Vector3d::Zero();  // area-weighted centroid of the analysed surface
  // Ordered from one distal end to the other, about 0.5 mm apart.
  std::vector<ArchPoint> curve;
  double length_mm = 0;       // arc length of the curve
  double midline_arc_mm = 0;  // arc position of the midline (the point farthest from the chord
                              // joining the two ends: between the central incisors)
  double mean_width_mm = 0;   // band area / length
  bool used_labels = false;   // true: tooth faces only; false: every face (no usable labels)
  size_t faces_used = 0;

  bool ok() const { return status.ok(); }
  // The curve at arc position arc_mm, linearly interpolated; beyond the ends, extended straight
  // along the end tangent (tangent, buccal and width of the end). Requires ok().
  ArchPoint At(double arc_mm) const;
};

// Finds the arch's geometry. Uses the faces labelled kTooth when the mesh has labels with teeth
// (refused with a reason when labelled but with too few tooth faces), every face otherwise. Faces
// are resampled into area-weighted points at most about 1.5 mm apart.
//  - Occlusal direction: the smallest principal axis of those points, signed so that tooth faces
//    lie on the occlusal side of gingiva faces (by more than 0.5 mm), or, with no gingiva, so that
//    the mean area-weighted face normal points occlusally.
//  - Arch curve, in the occlusal plane, with points weighted by their footprint there (area ×
//    |n·occlusal|, walls 5 %): (1) first guess: the points are rasterised (1 mm cells,
//    morphological closing to bridge interdental gaps), the two distal ends are the extremities of
//    the band's geodesic diameter (Dijkstra on the 8-connected grid), and 1 mm slices by geodesic
//    distance from one end give ordered centroids; (2) principal-curve refinement (after Hastie &
//    Stuetzle 1989, 5 rounds): 1 mm slices square to the current curve (its ends extended
//    straight), each slice's centre taken midway between the 5th and 95th percentiles of the
//    lateral offsets (the middle of the teeth; robust where a slice cuts the band's end
//    obliquely), light end slices merged, Gaussian smoothing (σ = 3 mm), the last 5 mm of each end
//    dropped before the next round so the end slices follow the arch, not a bent end;
//    (3) resampled every 0.5 mm. Height: the 90th percentile of the slice's heights (cusp level).
//    Tangent: smoothed over σ = 8 mm (the arch, not the tooth-by-tooth wobble). Buccal: the side
//    away from the curve's concave interior.
//  - Without labels, when every face together does not form a band (a palate or the floor of the
//    mouth fills the arch), the curve is fitted again to the most occlusal 50 %, then 30 %, of
//    the surface (the crowns).
//  - Refusals (status not ok): empty mesh, too few tooth faces, a degenerate point set (a line or
//    no dominant plane), occlusal sense undecidable (closed unlabelled mesh), a band that is not
//    elongated (geodesic length < 3 × area / length: a plate or a blob), a refined curve much
//    longer than the geodesic length (no clear centreline), or an arch shorter than 20 mm.
ArchFrame AnalyzeArch(const TriangleMesh& mesh);

// The depth (probe z, mm) of the arch-curve point nearest to the probe's optical axis, among the
// points in front of the camera: the "distance along the optical axis to the arch" used as the
// depth-of-field criterion. NaN when the whole curve is behind the camera.
double AxisDepthToArchMm(const ArchFrame& arch, const Rigid3d& world_from_probe);
// The index of that curve point in arch.curve; −1 when the whole curve is behind the camera.
int ArchPointNearestAxis(const ArchFrame& arch, const Rigid3d& world_from_probe);

// ---------------------------------------------------------------------------------------------
// Scan paths

enum class ScanKind {
  kFullArch,  // occlusal, buccal and lingual passes over the whole arch
  kQuadrant,  // the same passes over one half: distal molar to central incisor
  kTooth,     // a short dwell around one molar from several angles
};

// What the probe is doing during a stretch of the scan.
enum class ScanPhase {
  kOcclusal,    // above the biting surfaces, optical axis along −occlusal
  kBuccal,      // outside the arch, axis tilted toward the palate / tongue
  kLingual,     // inside the arch, axis tilted toward the cheeks
  kTransition,  // lift and roll between passes (around a distal end or the midline)
  kDwell,       // circling one tooth (ScanKind::kTooth)
  kLift,        // out of the mouth: backed off beyond the measurement volume (scan_styles.h)
};
const char* ScanPhaseName(ScanPhase phase);

struct ScanSegment {
  ScanPhase phase = ScanPhase::kOcclusal;
  int64_t start_ns = 0;
  int64_t end_ns = 0;
};

// Everything that shapes a scan. Angles in degrees, distances in mm, speeds in mm/s, rates in Hz.
struct ScanPathOptions {
  // --- Optics / geometry ---
  // Camera centre to the aimed surface point along the optical axis (the plane of best focus).
  double working_distance_mm = 50.0;
  // Order of the passes; consecutive passes run in opposite directions (serpentine) and are joined
  // by transitions. Only kOcclusal, kBuccal, kLingual are allowed here.
  std::vector<ScanPhase> passes = {ScanPhase::kOcclusal, ScanPhase::kBuccal, ScanPhase::kLingual};
  // Tilt of the optical axis from −occlusal, about the arch tangent: the buccal pass looks from
  // outside toward the palate, the lingual pass from inside toward the cheeks.
  double buccal_tilt_deg = 50.0;
  double lingual_tilt_deg = 50.0;
  // Where the side passes aim: the arch curve moved outward (buccal) / inward (lingual) by these
  // offsets and down (toward the roots) by side_aim_drop_mm, i.e. onto the side of the crowns.
  double buccal_aim_offset_mm = 4.0;
  double lingual_aim_offset_mm = 4.0;
  double side_aim_drop_mm = 2.0;
  // The passes start and end this far beyond the curve's ends (distal surfaces of the last molars).
  double end_overshoot_mm = 2.0;
  // Around a distal end, transitions tilt the axis back along the arch by up to this angle (to see
  // the distal surface of the last molar) and lift the probe by transition_lift_mm.
  double distal_tilt_deg = 20.0;
  double transition_lift_mm = 3.0;
  // Radius over which the corners between passes and transitions are rounded (Gaussian σ, mm of
  // camera travel).
  double corner_smoothing_mm = 4.0;

  // --- Speeds ---
  // Nominal speed (mm/s) of the aimed surface point along the arch during passes; allowed 5–30.
  double speed_mm_s = 10.0;
  // Slow natural variation of that speed: ±speed_variation (fraction, 0–0.5), seeded.
  double speed_variation = 0.2;
  // Bounds on the camera-centre speed during passes (the camera moves faster than the aim point on
  // the outside of the arch's curve and slower inside).
  double min_camera_speed_mm_s = 6.0;
  double max_camera_speed_mm_s = 15.0;
  // Camera-centre speed during transitions and the tooth dwell.
  double transition_speed_mm_s = 13.0;
  // Cap on the angular speed of the planned path (before wiggle and tremor), rad/s.
  double max_path_angular_speed_rad_s = 1.0;

  // --- Deliberate wiggles (seeded quasi-periodic: two sinusoids ±15 % around the frequency) ---
  // Each wiggle rotates the probe about a pivot on its optical axis, `…_pivot_depth_mm` in front of
  // the optical centre: 0 turns the camera in place (the aimed point sweeps the surface, the
  // camera does not move), the working distance pivots about the aimed point (the camera swings
  // by working distance × angle, which adds to its speed).
  // Roll: buccal-lingual rocking about the image y axis (≈ arch tangent), as when the wand is
  // rolled about its handle; default pivot ≈ 15 mm above the surface, where the wand's tip is.
  double roll_amplitude_deg = 10.0;
  double roll_frequency_hz = 0.15;
  double roll_pivot_depth_mm = 35.0;
  // Rock: mesial-distal tilt about the image x axis (⟂ arch tangent) so the walls next to the
  // interdental gaps are seen obliquely from both sides (the aimed point sweeps ±WD·tan(amplitude)
  // ≈ ±13 mm along the arch with the defaults).
  double rock_amplitude_deg = 15.0;
  double rock_frequency_hz = 0.3;
  double rock_pivot_depth_mm = 0.0;

  // --- Involuntary hand motion (seeded sums of sinusoids: smooth, C∞) ---
  // Physiological tremor: per axis, peak amplitudes; frequencies uniform in the band.
  double tremor_position_mm = 0.07;
  double tremor_rotation_deg = 0.15;
  double tremor_min_hz = 8.0;
  double tremor_max_hz = 12.0;
  // Slow drift: per axis, peak amplitudes, frequencies within ±40 % of drift_frequency_hz.
  double drift_position_mm = 0.5;
  double drift_rotation_deg = 1.5;
  double drift_frequency_hz = 0.5;

  // --- Selection (quadrant and tooth scans) ---
  // 0: the half / molar at the curve's first end (arc 0), 1: at its last end.
  int side = 0;
  // Tooth dwell: arc distance of the tooth centre from the chosen distal end (first molar ≈ 15 mm
  // when the arch ends with the second molar).
  double tooth_arc_mm = 15.0;
  // Tooth dwell: largest mesial-distal tilt while circling.
  double dwell_rock_deg = 25.0;

  // --- Sampling / randomness ---
  uint32_t seed = 1;                    // std::mt19937 seed: speeds, wiggles, tremor, drift
  int64_t start_ns = 0;                 // time of the first pose
  int64_t key_interval_ns = 5'000'000;  // key poses every 5 ms (tremor ≤ 12 Hz → ≥ 16 keys/period)

  // Throws std::invalid_argument naming the offending field.
  void Check() const;
};

struct ScanPathResult {
  Status status;  // not ok: the mesh is not an arch (reason from AnalyzeArch) or a selection fails
  Trajectory trajectory;
  ArchFrame arch;
  std::vector<ScanSegment> segments;  // in time order, covering the trajectory
  bool ok() const { return status.ok(); }
};

// Plans a hand-held scan of `mesh` (see AnalyzeArch) of the given kind.
//
// Passes: the probe aims at a point of the arch (the curve, moved to the side being scanned) and
// keeps it at the working distance; the optical axis lies in the plane ⟂ the arch tangent, tilted
// by 0 (occlusal), +buccal_tilt (buccal) or −lingual_tilt (lingual) from −occlusal. Image x is
// ACROSS the arch (⟂ tangent, in that plane), image y along it: the projector-camera baseline
// (along x) then lies in the plane of the interdental gaps, so camera and projector both look
// into them instead of one of them being shadowed by the neighbouring tooth; and the 16 mm image
// width covers the ≈ 10 mm buccal-lingual width of a molar with margin. Transitions lift and roll
// the probe around the end of the arch (with a tilt back along the arch at distal ends); the
// corners between passes and transitions are rounded (corner_smoothing_mm). The plan is re-timed
// so the aimed point moves at speed_mm_s (± variation) within the camera-speed bounds (transitions
// and the dwell at transition_speed_mm_s), with its angular speed capped; then roll/rock wiggles
// (faded out within 1.5 s of the scan's start/end and of transitions, so passes reach the arch's
// ends), drift and tremor are composed on top (all seeded), and the result is sampled every
// key_interval_ns into a C1 Trajectory starting at start_ns.
// Full arch: passes from one end (options.side) to the other. Quadrant: from the distal end of
// options.side to end_overshoot_mm past the midline. Tooth: a dwell at tooth_arc_mm from that end
// (INVALID_ARGUMENT when past the midline).
// Throws std::invalid_argument when options.Check() fails; a mesh that is not an arch gives a
// non-ok status with AnalyzeArch's reason.
ScanPathResult MakeScanTrajectory(const TriangleMesh& mesh, ScanKind kind,
                                  const ScanPathOptions& options);
// Same, on an already analysed arch (must be ok()).
ScanPathResult MakeScanTrajectory(const ArchFrame& arch, ScanKind kind,
                                  const ScanPathOptions& options);

// Summary figures of a scan trajectory over an arch.
struct ScanPathStats {
  double duration_s = 0;
  double path_length_mm = 0;  // camera-centre path, sampled every 2 ms
  double min_speed_mm_s = 0;  // camera-centre speed at 30 Hz samples (1 ms central differences)
  double mean_speed_mm_s = 0;
  double max_speed_mm_s = 0;
  double speed_in_5_20_share = 0;      // share of samples with speed in [5, 20] mm/s
  double max_angular_speed_rad_s = 0;  // at the same samples
  double mean_angular_speed_rad_s = 0;
  double depth_in_dof_share = 0;  // share of samples whose AxisDepthToArchMm is within [42, 58] mm
  double mean_axis_depth_mm = 0;  // over the samples with a finite depth
  size_t samples = 0;
  std::string ToString() const;
};
// Computes the stats at 30 Hz over the trajectory (depth of field [42, 58] mm, the probe's).
ScanPathStats ComputeScanPathStats(const Trajectory& trajectory, const ArchFrame& arch);

}  // namespace d3d
