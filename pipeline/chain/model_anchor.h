// Model-guided anchoring: fringe orders for the parts of a view that the burst alone could not
// anchor, taken from the model the scan has already built.
//
// Why: the unwrapper (pipeline/unwrap/unwrap.h) gives a region an absolute order only when the
// marker stripes crossing it, or the measurement volume, decide its offset K; a region without a
// readable stripe, one whose votes disagree, or a part joined to a verified one through a narrow
// neck is dropped. Measured on 40 virtual-probe bursts spread over each arch, that dropped 40–70 %
// of the gingiva and 2–12 % of the teeth. When whole teeth go (real arch seed 3, burst 1212: the
// marker unreadable on both molars, blurred by the probe's motion), only the smooth palate is left,
// ICP slides along it (eigenvalue ratio 0.02) and the tracked pose is 0.3 mm / 0.5° off. The model
// has usually seen those surfaces already, and a wrong K puts a surface a whole fringe order
// (1.4–1.9 mm for this probe) away from where the model has it, so the model tells K apart.
//
// Method (after the view is registered, pose world_from_cam): the unanchored pixels of the view are
// grouped by unwrapping region (the dropped parts of an anchored region form a group of their own).
// For a group of ≥ min_pixels, its candidate offsets are the K admissible (Φ = φ + 2π(r + K) within
// [phase_min, phase_max], the measurement volume) at ≥ min_admit_share of its pixels. For each
// candidate, up to max_samples pixels spread over the group are triangulated and moved to the
// world; a sample is an inlier when the model has a sample within gate_mm whose tangent plane is
// within inlier_mm (the point-to-plane distance of the tracker's ICP) and whose surface faces the
// camera within max_incidence_deg of the ray (a wrong K moves a point along its ray: on a wall
// nearly parallel to the ray it would stay on the wall, and whole orders back it can land on the
// far side of the tooth the ray went through). The best K is taken when its inlier share is ≥
// min_inlier_share and every other candidate's is ≤ max_rival_share; the group's pixels then get Φ
// and k where the model confirms the pixel's own point the same way and not also its point one
// order nearer or farther (a part beyond a hidden order jump inside the group lies a fringe order
// away from anything the model holds; two model surfaces along a ray leave the order open), checked
// on a 2 × 2 pixel lattice; the view's normals are computed again where they read an anchored point
// (UpdateOrganisedNormals). This is the model-based phase unwrapping that real-time scanners use
// once a model exists (cf. the temporal/geometric order prediction of An et al. 2016, here with the
// fused model as the geometry).
//
// Threads: one ModelAnchorer per thread (the register thread); it keeps per-call buffers.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "calib/model/probe_calibration.h"
#include "common/core/rigid.h"
#include "pipeline/recon/reconstruct.h"
#include "pipeline/register/grid_target.h"
#include "pipeline/register/point_map.h"
#include "pipeline/triangulate/triangulate.h"

namespace d3d {

struct ModelAnchorOptions {
  bool enabled = true;
  int min_pixels = 400;           // smaller groups are left alone (px, for the 640×480 probe)
  int max_samples = 300;          // pixels tested per group and candidate K
  double gate_mm = 0.2;           // nearest model sample searched within this
  double inlier_mm = 0.15;        // point-to-plane distance of an inlier
  double min_inlier_share = 0.6;  // of the samples, for the chosen K
  double max_rival_share = 0.15;  // every other candidate K at most this
  double min_admit_share = 0.5;   // a candidate K is admissible at this share of the group's pixels
  double max_incidence_deg = 65.0;  // a match counts only where the model's surface faces the
                                    // camera, its normal within this of the (reversed) ray
  double model_margin_mm = 1.0;     // model samples gathered within the candidates' box ± this
  // Throws std::invalid_argument unless min_pixels ≥ 1, max_samples ≥ 10, 0 < inlier_mm ≤ gate_mm,
  // 0 < min_inlier_share ≤ 1, 0 ≤ max_rival_share < min_inlier_share, 0 < min_admit_share ≤ 1,
  // model_margin_mm ≥ 0, 0 < max_incidence_deg < 90.
  void Check() const;
};

struct ModelAnchorStats {
  int groups_tested = 0;  // groups of ≥ min_pixels with at least one candidate
  int groups_anchored = 0;
  int64_t pixels_anchored = 0;
  double ms = 0;
};

class ModelAnchorer {
 public:
  // Throws std::invalid_argument for an invalid calibration or options. normal_max_gap_mm: as
  // ReconstructOptions (for the normals after the new triangulation).
  ModelAnchorer(const ProbeCalibration& calibration, const ModelAnchorOptions& options,
                double normal_max_gap_mm);

  // view: a Reconstructor's output for this probe (its phase, unwrap, points and normals are read;
  // unwrap.Phi/order and points_in_cam/normals are rewritten in place, in the same buffers, when
  // some group is anchored). model: world frame; world_from_cam: the view's pose. Returns the
  // pixels anchored (0 when the view has no group to test, the model nothing near, or the options
  // are disabled). Never throws; a view of another size is left alone (0).
  int64_t Anchor(const PointMap& model, const Rigid3d& world_from_cam, ReconstructedView* view,
                 ModelAnchorStats* stats = nullptr);

  const ModelAnchorOptions& options() const { return options_; }

 private:
  ModelAnchorOptions options_;
  double normal_max_gap_mm_;
  PhaseTriangulator triangulator_;
  cv::Mat phase_min_, phase_max_;
  std::vector<int32_t> keys_;  // per pixel: its group key, −1 for none (per call)
  std::vector<int8_t>
      verdict_;  // per lattice pixel: −1 unchecked, 0 refused, 1 confirmed (per call)
  std::vector<int> changed_;    // the pixels anchored (per call): their normals are computed again
  SurfacePoints near_samples_;  // the model's samples near the view (per call, buffers reused)
  GridTarget near_;  // grids over them, for the nearest-sample look-ups (per call, buffers reused)
};

}  // namespace d3d
