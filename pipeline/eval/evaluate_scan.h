// Accuracy of a scanned model against a reference surface, as the in-vitro full-arch studies
// report it (ISO 5725-1 trueness / precision; ISO 20896-1 for intraoral scanners; e.g. Ender &
// Mehl 2013, J. Prosthet. Dent. 109(2)): best-fit alignment of the scan to the reference (ICP,
// point-to-plane, on mesh closest points), then signed distances from the scan to the reference
// over the region the scan covers; coverage of the reference tooth surface; precision between
// repeated scans; absolute trajectory error (Sturm et al. 2012, TUM RGB-D benchmark, §V-A) after
// a rigid Umeyama alignment of the trajectories. Units: mm in, µm in the reported deviations.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "calib/model/camera_model.h"
#include "common/burst/burst.h"
#include "common/core/rigid.h"
#include "common/mesh/mesh.h"
#include "pipeline/register/icp.h"

namespace d3d {

// Exact closest points on a triangle mesh: a k-d tree over triangle centroids gives candidates,
// the point–triangle distance (Ericson 2005, Real-Time Collision Detection §5.1.5) decides.
// The mesh is copied. Const methods are thread-safe.
class MeshClosestPoint final : public IcpTarget {
 public:
  explicit MeshClosestPoint(const TriangleMesh& mesh, int candidates = 16);
  ~MeshClosestPoint() override;
  struct Hit {
    int face = -1;
    Eigen::Vector3d point = Eigen::Vector3d::Zero();
    double distance_mm = 0;    // unsigned
    double signed_mm = 0;      // positive on the side the face normal points to
    bool on_boundary = false;  // the closest point lies on an open (boundary) edge of the mesh
    // on_boundary and the point lies past that border: more than kPastBorderMm of its offset is
    // along the surface, not along the face normal (a point on the border itself is not past it).
    bool past_border = false;
  };
  static constexpr double kPastBorderMm = 0.001;
  Hit Closest(const Eigen::Vector3d& p) const;
  // IcpTarget: closest point and its face normal.
  bool Find(const Eigen::Vector3f& query, float max_distance_mm, Eigen::Vector3f* point,
            Eigen::Vector3f* normal) const override;
  const TriangleMesh& mesh() const { return mesh_; }

 private:
  struct Impl;
  TriangleMesh mesh_;
  int candidates_;
  std::unique_ptr<Impl> impl_;
};

struct EvaluateOptions {
  bool align = true;  // best-fit ICP of the scan onto the reference
  double max_distance_mm =
      1.0;  // scan points farther from the reference are outliers (counted, not in the figures)
  double coverage_distance_mm =
      0.2;  // a reference point is covered when a scan point is this close
  double coverage_sample_mm2 = 0.01;  // reference surface per coverage sample
  bool teeth_only_coverage = true;    // coverage of tooth faces when the reference is labelled
  // Coverage is also split into the reference surface in narrow gaps and the open rest: a face is
  // in a gap when another surface faces it (normals more than 120 deg apart) within gap_mm in front
  // of it, as the walls of an interproximal gap or a deep fissure do (a probe sees into such a gap
  // only along it). 0 = no split.
  double gap_mm = 1.0;
  int max_scan_points = 400000;  // scan vertices evaluated (evenly subsampled beyond)
  // The depth (mm) of a view's footprint (ViewFootprint) for its pose error: the probe's working
  // distance (the default probe's: 50 mm, the middle of its 42–58 mm measurement volume).
  double footprint_depth_mm = 50.0;
  void Check() const;
};

struct TruenessReport {
  Rigid3d reference_from_scan =
      Rigid3d::Identity();  // the best fit applied (identity without align)
  double alignment_rmse_mm = 0;
  int64_t points = 0;  // scan points in the figures
  double outlier_pct =
      0;  // scan points beyond max_distance_mm or past the reference's border (Hit::past_border)
  double rms_um = 0, mean_um = 0, mean_abs_um = 0, p95_um = 0, max_um = 0;  // p95 of |d|
  double coverage_pct = 0;
  // The coverage split (EvaluateOptions::gap_mm): of the counted surface, the area share (%) in
  // narrow gaps, and the coverage (%) of the gap surface and of the open rest; NaN where there is
  // no such surface or no split.
  double gap_area_pct = std::nan("");
  double coverage_gap_pct = std::nan("");
  double coverage_open_pct = std::nan("");
  // The same figures over the scan points whose closest reference face is a tooth (NaN-free: only
  // when the reference is labelled, else teeth_points = 0), as studies that cut the scans to the
  // teeth report them (e.g. Ender & Mehl 2013); gingiva is noisier (darker, more translucent).
  int64_t teeth_points = 0;
  double teeth_rms_um = 0, teeth_mean_um = 0, teeth_p95_um = 0;
  std::vector<float> signed_um;  // per scan vertex (NaN where excluded), for heat maps
};

// Aligns (if asked) starting from `initial` (reference_from_scan) and evaluates.
TruenessReport EvaluateTrueness(const TriangleMesh& scan, const MeshClosestPoint& reference,
                                const Rigid3d& initial, const EvaluateOptions& options = {});

// A coarse global alignment when no initial pose is known: principal axes of both vertex sets
// (4 sign hypotheses) each refined by ICP; the best (overlap, then residual) wins. When that best
// leaves more than a fifth of the scan unmatched or fits at more than 50 µm RMS (a partial scan: a
// quadrant, a tooth), FPFH + RANSAC at the scale of teeth (fpfh.h, DentalFpfh: Rusu et al. 2009)
// proposes one more start.
Rigid3d GlobalAlign(const TriangleMesh& scan, const MeshClosestPoint& reference);

// Precision between two scans of the same object (ISO 5725-1: closeness of repeated
// measurements): b is aligned onto a (ICP, from `initial` a_from_b), and the RMS / p95 of |signed
// distance| from b's vertices to a over the region both scans cover are returned (µm).
// The region both cover: b's vertex p counts when its closest point q on a lies within
// max_distance_mm, not on a's border, and is reciprocal: b's own closest point to q is at least
// ½ |p − q| away (deviations of at most reciprocal_below_um count without that test, so noise-level
// differences are never thinned). A one-sided closest point is not the same surface where one scan
// reached a surface the other did not but the other measured a neighbouring one within reach: a
// tooth wall above a gingiva both scans have, the two sides of an interproximal gap. Typodont full
// arch, seeds 1 and 3: 0.29 % of b's counted vertices are not reciprocal, all on tooth outlines;
// they lie 313 µm (median) from a but 7.6 µm (median; RMS 26) from the true surface, and alone
// they took the one-sided RMS from 10.6 to 19.9 µm. The one-sided figures are reported too.
// Not counted either, a limit of the test: a double layer b has near a surface both have. It shows
// in the one-sided figures and in b's trueness: real arch, seeds 1 / 3, before the mesh's span test
// (pipeline/fuse/tsdf.h), the 0.22 % non-reciprocal vertices were such a layer 0.23 mm inside the
// teeth (one-sided 17.6 µm, reciprocal 14.1); with it gone, one-sided 14.6, reciprocal 14.1.
struct PrecisionReport {
  double rms_um = 0, p95_um = 0;
  int64_t points = 0;
  double not_reciprocal_pct = 0;  // of b's vertices within reach, off the border
  double one_sided_rms_um = 0, one_sided_p95_um = 0;  // without the reciprocity test
};
PrecisionReport EvaluatePrecision(const TriangleMesh& a, const TriangleMesh& b,
                                  const Rigid3d& a_from_b = Rigid3d::Identity(),
                                  double max_distance_mm = 0.5, double reciprocal_below_um = 20.0);

// Absolute trajectory error: estimated and true poses (same length, paired) are aligned by the
// rigid transform minimising the position error (Umeyama 1991), then RMS position error (mm) and
// mean rotation error (deg). *truth_from_estimate (optional) gets the alignment.
struct AteReport {
  double rmse_mm = 0, mean_deg = 0, max_mm = 0;
  int poses = 0;
};
AteReport AbsoluteTrajectoryError(const std::vector<Rigid3d>& estimate,
                                  const std::vector<Rigid3d>& truth,
                                  Rigid3d* truth_from_estimate = nullptr);

// Relative pose error between consecutive poses (Sturm et al. 2012, "A benchmark for the
// evaluation of RGB-D SLAM systems", IROS, eq. 1 with Δ = one pose): for k ≥ 1,
//   E_k = (Q_{k−1}⁻¹ Q_k)⁻¹ (P_{k−1}⁻¹ P_k),  P estimate, Q truth (any frames: E_k is invariant),
// RMS and largest |translation(E_k)| (mm) and the k of the largest, mean rotation angle (deg).
// Where ATE says how far a trajectory wandered, this says where it jumped: a view registered off
// (sliding along a weakly constrained direction, say) shows as one large step, and every later
// view that followed it is unaffected. Throws std::invalid_argument for unpaired inputs; fewer than
// 2 poses: all zero.
struct RpeReport {
  double rmse_mm = 0, mean_deg = 0, max_mm = 0;
  int max_pose = 0;  // k of the largest step error (the pose that moved off its predecessor)
  int steps = 0;
};
RpeReport RelativePoseError(const std::vector<Rigid3d>& estimate,
                            const std::vector<Rigid3d>& truth);

// Where a fused view's pose error is judged (issue 50's wrong fusions): the view's footprint, the
// points (camera frame, mm) at depth_mm along the rays of the image's centre and four corner
// pixels. A view's surface lies there (depth_mm: the probe's working distance), so the largest
// displacement of these points is how far the view's surface was fused off; the camera centre's
// displacement adds the lever of a rotation about the surface (a view turned 0.23° about its
// surface moves its camera centre 0.2 mm at 50 mm and its surface 0.015 mm). Pixels whose ray the
// model cannot give are left out. Throws std::invalid_argument for depth_mm ≤ 0.
std::vector<Eigen::Vector3d> ViewFootprint(const PinholeBrownConrady& camera, double depth_mm);

// The largest distance (mm) between estimate·p and truth·p over the points p of footprint_in_cam
// (camera frame, mm; estimate and truth: world_from_cam); the camera centres' distance when the
// footprint is empty.
double FootprintDistanceMm(const Rigid3d& estimate, const Rigid3d& truth,
                           const std::vector<Eigen::Vector3d>& footprint_in_cam);

// A wrong fusion (issue 50): a fused view whose footprint (ViewFootprint) is off by more than
// kWrongFusionMm, or whose rotation is off by more than kWrongFusionDeg, from the truth after the
// scan's best fit: a view placed on the wrong tooth, not noise.
constexpr double kWrongFusionMm = 0.2, kWrongFusionDeg = 1.0;

// The part of a reference surface that the probe saw, from the simulator's truth maps: the
// acquisition's own coverage limit, against which a scan's coverage_pct reads (a face no view saw
// cannot be in the model, however good the reconstruction). A face counts as seen when a pixel of
// a view shows it lit and visible (FrameTruth visibility 2), within [depth_min_mm, depth_max_mm]
// of the camera (z) and at an incidence (face normal vs the ray to the camera centre) below
// max_incidence_deg (use the fusion's limit, TsdfOptions::max_incidence_deg). Keeps each face's
// normal and counted area, not the mesh. Throws std::invalid_argument for an empty reference or
// limits out of order.
class SeenSurface {
 public:
  SeenSurface(const TriangleMesh& reference, double depth_min_mm, double depth_max_mm,
              double max_incidence_deg);
  // One view's truth maps (face_index into the reference, world_from_probe = the camera's pose).
  // Views without maps are ignored.
  void Add(const FrameTruth& truth);
  int64_t views() const { return views_; }
  // Area share (%) of the tooth faces seen by at least one view (of all faces when the reference
  // is not labelled).
  double SeenToothAreaPct() const;

 private:
  double depth_min_mm_, depth_max_mm_, cos_max_incidence_;
  std::vector<Eigen::Vector3d> normals_;  // per face, unit
  std::vector<double> counted_area_;      // per face, mm²: its area if it counts (tooth), else 0
  std::vector<uint8_t> seen_;
  int64_t views_ = 0;
};

// A deviation heat map: the scan's vertices seen along the smallest principal axis of the scan
// (orthographic, z-buffered splats), coloured by signed deviation on a diverging blue–green–red
// scale clipped at ±range_um (vertices without a value not drawn), with a colour bar and its
// labels.
cv::Mat DeviationHeatMap(const TriangleMesh& scan_in_reference, const std::vector<float>& signed_um,
                         double range_um = 50, int width_px = 1200);

}  // namespace d3d
