// Iterative closest point with the combined point-to-point / point-to-plane metric, robust
// weights and coarse-to-fine termination. Units: mm, rad. Transforms are target_from_source.
//
// Metric (the dissertation's combination, weighted per level; Chen & Medioni 1992 point-to-plane,
// Besl & McKay 1992 point-to-point): for source sample p (moved by the current estimate, p' = T p)
// and its associated target sample q with unit normal n,
//   E(T) = Σ wᵢ [ α (nᵢ·(p'ᵢ − qᵢ))² + (1 − α) ‖p'ᵢ − qᵢ‖² ],
// minimised by Gauss–Newton on the small-motion linearisation T ← Exp([ω, t]) T (left update,
// p' + ω × p' + t), with a Levenberg damping of 1e-9 · trace(H). α =
// IcpLevel::point_to_plane_weight: point-to-plane converges fast on smooth surfaces; point-to-point
// widens the basin early on. Robust weights: Tukey's biweight on the point-to-plane residual, w =
// (1 − (r/c)²)², c = 4.685 σ, σ = 1.4826 · median |r| (floored at min_sigma_mm) re-estimated every
// iteration (Zhang 1994; Holland & Welsch 1977), times the source sample's own weight (quality).
// Hierarchy: levels from coarse (few samples, large association distance) to fine; a level ends
// when the pose update is below (min_delta_rotation_rad, min_delta_translation_mm) or the weighted
// error changes by less than min_relative_error_change, or after its max_iterations.
// Data association: a target object (IcpTarget): a nanoflann k-d tree over target samples
// (KdTreeTarget) or a projective look-up in an organised target image (ProjectiveTarget).
#pragma once

#include <Eigen/Core>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "common/core/rigid.h"
#include "pipeline/register/kdtree.h"
#include "pipeline/register/surface_points.h"

namespace d3d {

// Squared distance summed in nanoflann's L2_Simple_Adaptor order, ((0 + dx²) + dy²) + dz² in float:
// the k-d tree's, so that GridTarget and RegisterIcp's reused associations compare distances as it
// does.
inline float L2SimpleDistance2(const Eigen::Vector3f& q, const Eigen::Vector3f& p) {
  float d2 = 0.0f;
  const float dx = q.x() - p.x(), dy = q.y() - p.y(), dz = q.z() - p.z();
  d2 += dx * dx;
  d2 += dy * dy;
  d2 += dz * dz;
  return d2;
}

// A nearest-sample answer with a clearance, so that it can be reused while the query moves a
// little (RegisterIcp between iterations, where the pose changes by micrometres): the nearest
// target sample within the search's reach (≥ the gate), and how far around the query no other
// sample lies. For the query moved by Δ (|Δ| = distance between the two queries):
//   found, |q' − point| + |Δ| < clearance_mm → `point` is still q''s unique nearest sample (any
//     other lies ≥ clearance − |Δ| from q'), so Find(q', r) is `point` when |q' − point| < r, else
//     none;
//   not found, r + |Δ| < clearance_mm → nothing lies within r of q': Find(q', r) finds none.
struct CertifiedNearest {
  bool certified = false;  // false: no answer to reuse (the caller searches every time)
  bool found = false;      // a sample lies within the search's reach
  // The nearest sample (target frame).
  Eigen::Vector3f point = Eigen::Vector3f::Zero(), normal = Eigen::Vector3f::Zero();
  float distance_mm = 0;  // |query − point|
  float clearance_mm =
      0;  // found: no other sample is nearer the query than this; else none within it
};

// Associates a query point (target frame, mm) with a target sample: returns true and writes the
// sample's point and unit normal (target frame) when one lies within max_distance_mm.
// Implementations must be safe to call concurrently (const, no shared scratch).
class IcpTarget {
 public:
  virtual ~IcpTarget() = default;
  virtual bool Find(const Eigen::Vector3f& query, float max_distance_mm, Eigen::Vector3f* point,
                    Eigen::Vector3f* normal) const = 0;
  // The nearest sample with a clearance (CertifiedNearest) for a search with gate max_distance_mm,
  // certifying up to margin_mm beyond the nearest. Returns out->certified; targets that cannot
  // certify leave it false (the default).
  virtual bool FindCertified(const Eigen::Vector3f& query, float max_distance_mm, float margin_mm,
                             CertifiedNearest* out) const {
    (void)query;
    (void)max_distance_mm;
    (void)margin_mm;
    *out = CertifiedNearest{};
    return false;
  }
};

// Nearest neighbour in a k-d tree (nanoflann). Holds its own copy of the samples.
class KdTreeTarget final : public IcpTarget {
 public:
  explicit KdTreeTarget(SurfacePoints target);  // normals required (same size as points)
  bool Find(const Eigen::Vector3f& query, float max_distance_mm, Eigen::Vector3f* point,
            Eigen::Vector3f* normal) const override;
  const SurfacePoints& samples() const { return target_; }

 private:
  SurfacePoints target_;
  std::unique_ptr<PointKdTree> tree_;
};

// Simple pinhole for projective association (no distortion: the target image is rendered with
// the same projection, so the look-up is consistent).
struct PinholeBrownConrady;  // calib/model/camera_model.h

struct PinholeIntrinsics {
  double fx = 0, fy = 0, cx = 0, cy = 0;
  int width = 0, height = 0;
  PinholeIntrinsics Scaled(double s) const;  // for an image s times the size
  static PinholeIntrinsics Of(
      const PinholeBrownConrady& camera);  // its pinhole part (distortion dropped)
};

// Projective data association (Blais & Levine 1995; KinectFusion, Newcombe et al. 2011): the query
// is moved into the image's camera (cam_from_target), projected, and the nearest valid sample in a
// (2·window+1)² pixel neighbourhood is taken. points, normals: H×W CV_32FC3 in the TARGET frame
// (NaN = empty), H×W = intrinsics' size.
class ProjectiveTarget final : public IcpTarget {
 public:
  ProjectiveTarget(cv::Mat points, cv::Mat normals, const PinholeIntrinsics& intrinsics,
                   const Rigid3d& cam_from_target, int window = 1);
  bool Find(const Eigen::Vector3f& query, float max_distance_mm, Eigen::Vector3f* point,
            Eigen::Vector3f* normal) const override;

 private:
  cv::Mat points_, normals_;
  PinholeIntrinsics k_;
  Eigen::Matrix3f R_;
  Eigen::Vector3f t_;
  int window_;
};

struct IcpLevel {
  int stride = 1;                // use every stride-th source sample
  int max_iterations = 10;       // at most this many Gauss–Newton iterations at this level
  double max_distance_mm = 0.5;  // association gate
  // α of the combined metric at this level, [0, 1]. The point-to-point term widens the basin on
  // coarse levels but, with nearest-neighbour association, also damps (and biases) tangential
  // motion, so the finest level is pure point-to-plane by default.
  double point_to_plane_weight = 1.0;
  // > 0: at most about this many source samples at this level (the stride grows to fit), so that a
  // large view costs no more than a small one. 0: every stride-th sample.
  int max_samples = 0;
  // > 0: this level ends at updates below these (rad, mm) instead of IcpOptions'
  // min_delta_rotation_rad / min_delta_translation_mm. A coarse level only has to bring the pose
  // well inside the next level's gate; its own last micrometres are found again by the next level.
  double min_delta_rotation_rad = 0;
  double min_delta_translation_mm = 0;
  // > 0: the registration gives up after this level (not ok) when fewer of its samples than this
  // share found a match within its gate: a start that has left the target does not pay for the
  // finer levels, whose narrower gates would match fewer still. 0: every level runs.
  double min_overlap = 0;
};

struct IcpOptions {
  // Coarse to fine. The last level decides the reported figures.
  std::vector<IcpLevel> levels = {{16, 12, 1.0, 0.7}, {4, 10, 0.3, 0.9}, {1, 8, 0.15, 1.0}};
  double max_normal_angle_deg = 45;         // association refused when normals disagree more
  double min_sigma_mm = 0.004;              // floor of the robust scale
  double min_delta_rotation_rad = 2e-6;     // level ends when the update is smaller ...
  double min_delta_translation_mm = 1e-4;   // ... in both rotation and translation (see IcpLevel)
  double min_relative_error_change = 1e-4;  // ... or the error stops changing
  // Acceptance (a registration failing these comes back not ok, with the reason):
  double min_overlap = 0.3;      // fraction of final-level source samples associated
  double max_rmse_mm = 0.06;     // RMS point-to-plane residual of the associated samples
  int min_correspondences = 30;  // associated final-level source samples, at least
  // Degeneracy: smallest / largest eigenvalue of the point-to-plane Hessian (rotation scaled by the
  // source radius so that all six are in mm²). Below: a direction slides freely (plane, sphere,
  // cylinder, extrusion): not ok.
  double min_eigen_ratio = 2e-3;
  // true: the degeneracy is judged with the radius and centroid of the source samples associated in
  // the last iteration instead of the whole source's. For a source much larger than its overlap (a
  // scan segment that meets the model at one end): the whole length would make a well-held overlap
  // look degenerate (rotations scaled by a radius the matches do not span), where the question is
  // whether the overlap's surface lets the pose slide.
  bool conditioning_on_overlap = false;
  // > 0: solution remapping (Zhang, Kaess & Singh, "On degeneracy of optimization-based state
  // estimation problems", ICRA 2016): each Gauss–Newton step is taken only along the directions
  // whose eigenvalue (as for min_eigen_ratio) is at least this × the largest; along the others the
  // pose stays where it started. For a view known to be degenerate, started from a prediction.
  // The acceptance is unchanged (a degenerate fit still comes back not ok). 0 = off.
  double remap_min_eigen_ratio = 0;
  // > 1: association and the normal equations in parallel (TBB). The sums are formed over fixed
  // chunks of 4096 matches added in a fixed order (parallel_deterministic_reduce), so a result
  // repeats bit for bit whatever the schedule and differs from one thread's by rounding only.
  int threads = 1;
  // > 0: a sample's association is reused in the level's next iterations while it provably stays
  // the same (IcpTarget::FindCertified: the nearest target sample and a clearance around the
  // query; the moved query is checked against both), certifying this fraction of the level's gate
  // beyond the nearest sample. The matches, and so the result, are the same as searching every
  // time (up to 1e-5 mm of slack in the test); targets that cannot certify search every time.
  // 0 = search every time.
  double association_reuse_margin = 0.1;
  void Check() const;  // throws std::invalid_argument
};

struct IcpResult {
  bool ok = false;
  std::string reason;  // why not ok
  Rigid3d target_from_source = Rigid3d::Identity();
  double rmse_mm = 0;  // final point-to-plane RMS of associated samples
  double overlap = 0;  // associated / final-level samples
  int correspondences = 0;
  int iterations = 0;           // over all levels
  int64_t searches = 0;         // nearest-sample searches, over all levels and iterations
  int64_t searches_reused = 0;  // associations reused instead (association_reuse_margin)
  double eigen_ratio = 0;       // see IcpOptions::min_eigen_ratio
  // Gauss–Newton information of the final level, [ω (rad), t (mm)], scaled by 1/σ²: the inverse
  // covariance of the left-perturbation of target_from_source (pose graph edges use it).
  Eigen::Matrix<double, 6, 6> information = Eigen::Matrix<double, 6, 6>::Zero();
};

// Registers `source` (its own frame; normals used for the compatibility test and the source
// weights as per-sample confidence) to `target`, starting from `initial` (target_from_source).
// Throws std::invalid_argument for invalid options; expected failures are returned.
IcpResult RegisterIcp(const SurfacePoints& source, const IcpTarget& target, const Rigid3d& initial,
                      const IcpOptions& options = {});

}  // namespace d3d
