// The tracker's odometry: frame-to-model ICP of a view against the tracking model (a PointMap of
// the accepted views), the map gate that keeps a badly fitting view out of that model, coasting
// through a smooth stretch, and the model insert (now, or left pending for CommitView).
//
// Owns: the tracking model, its pending insert, the ICP's gathered model samples and association
// grids (refilled per ICP, buffers reused), the residual history of the map gate and the coast run.
// All of it is touched by Track()'s thread only (the Tracker that composes it).
#pragma once

#include <cstddef>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "calib/model/camera_model.h"
#include "pipeline/register/grid_target.h"
#include "pipeline/register/icp.h"
#include "pipeline/register/motion_model.h"
#include "pipeline/register/point_map.h"

namespace d3d {

// Frame-to-model data association: projective (the model rendered from the prediction), or the
// exact nearest model sample within the gate, by a nanoflann k-d tree or by uniform grids
// (GridTarget: the same matches, faster).
enum class Association { kProjective, kKdTree, kGrid };
const char* AssociationName(Association a);  // "projective", "kdtree", "grid"
// Parses AssociationName's names; false for any other text.
bool ParseAssociation(const std::string& name, Association* out);

// Frame-to-model ICP of the tracker: IcpOptions' levels (gates 1.0 → 0.15 mm) with the finest
// level on every 2nd sample, the two coarse levels pure point-to-plane and ended at 10 / 5 µm (a
// level only has to bring the pose inside the next one's gate), the finest at pose updates below
// 0.5 µm / 2e-5 rad or an error change below 0.1 %: the same trueness as IcpOptions' stricter
// defaults in less time (figures: docs/decisions/0008).
IcpOptions DefaultTrackerIcp();

// Segment frames (segments.h): segment s's frame is the main one moved by s · kSegmentSpacingMm
// along x. A scan spans ~100 mm around its first view, so the segments never meet in the tracking
// model (its voxel keys reach ±80 m).
inline constexpr double kSegmentSpacingMm = 2000.0;
// The segment whose frame a model point (world, mm) lies in.
int SegmentOfPoint(const Eigen::Vector3f& p);

struct OdometryOptions {
  IcpOptions icp = DefaultTrackerIcp();  // frame-to-model
  PointMapOptions map;                   // the tracking model (map.undo_inserts: the undo journal)
  // Nearest model sample by grids (the k-d tree finds the same samples, slower); projective
  // association is faster but far less true (docs/decisions/0008).
  Association association = Association::kGrid;
  int sample_stride = 2;  // px lattice of the ICP source samples
  int map_stride = 3;     // px lattice of the samples added to the model
  // true: Track() leaves the accepted view's model insert pending and the caller runs it with
  // CommitView() once it has passed the view on (d3d-scan: after handing it to the preview); the
  // next Track() or UndoFrom() runs a pending one first. Nothing between reads the model: the same
  // bits.
  bool defer_model_insert = false;
  double target_scale = 0.5;      // projective: model image size / camera size
  int target_splat = 1;           // projective: splat half-size (px of the model image)
  int target_window = 1;          // projective: search half-window (px)
  double gather_margin_mm = 1.0;  // grid, k-d tree: model samples within the view's box ± this
  // grid: ICP levels whose gate is at least this (mm) search a decimated model, one sample per
  // voxel of a quarter of the gate (GridTarget::Build): the coarse level (and the local search's 4
  // mm) only, the finer levels still find the exact nearest sample. 0 = every level exact.
  double grid_decimate_min_gate_mm = 0.5;
  int min_view_samples =
      5000;  // fewer samples (a fragment, ~6 % of the image): skipped, state unchanged
  // A view that a Track() augmenter enlarged is registered again when its samples grew by at least
  // this share; that ICP runs icp's levels from reregister_first_level on (it starts at the pose
  // found).
  double reregister_min_gain = 0.25;
  int reregister_first_level = 1;
  // Map gate: an accepted view whose ICP residual is above map_max_rmse_ratio × the median of the
  // last 16 accepted views' is fused but kept out of the tracking model (a view straddling two
  // drifted layers would grow a third at a wrong pose), only when it lies mostly on the model
  // (overlap ≥ map_gate_min_overlap) and for at most map_gate_max_run views in a row (the model
  // must keep growing where the probe goes). 0 = every accepted view enters the model.
  double map_max_rmse_ratio = 1.4;
  double map_gate_min_overlap = 0.8;
  int map_gate_max_run = 2;
  // Coasting: a view whose ICP from the prediction fits but is degenerate (a smooth stretch) is not
  // fused but, while tracking, keeps the track: ICP again stepping only along directions with an
  // eigenvalue ratio ≥ coast_min_eigen_ratio, and that pose feeds the motion and tracking models.
  // At most max_coast_views in a row; 0 = off, the default (it placed a view off on the zoo:
  // docs/decisions/0003).
  int max_coast_views = 0;
  double coast_min_eigen_ratio = 0.02;
  void Check() const;  // throws std::invalid_argument
};

class Odometry {
 public:
  // camera: intrinsics of the organised views (projective association). Throws for invalid options.
  Odometry(const PinholeBrownConrady& camera, const OdometryOptions& options);
  const OdometryOptions& options() const { return o_; }

  // ICP of `source` (camera frame) against the tracking model from `initial` (world_from_cam).
  IcpResult Register(const SurfacePoints& source, const Rigid3d& initial,
                     const IcpOptions& icp) const;

  const PointMap& model() const { return map_; }  // without a pending insert (see Commit)
  // The view's samples (map_stride) into the model at `pose` (world_from_cam): now, or left pending
  // for Commit (defer_model_insert). `tag`: the view's anchor keyframe (PointMap::Insert).
  void Insert(const cv::Mat& points, const cv::Mat& normals, const Rigid3d& pose, int32_t tag = -1);
  // Runs a pending insert; nothing when none is. Returns its time (ms).
  double Commit();
  bool insert_pending() const { return insert_pending_; }
  // The model as it was after `inserts` Insert calls (PointMap::RollBackTo): false when the undo
  // journal does not reach back that far.
  bool RollBackTo(int64_t inserts) { return map_.RollBackTo(inserts); }
  // Replaces the model (a segment joined: its samples moved into the main frame). No undo journal.
  void ReplaceModel(PointMap model) { map_ = std::move(model); }
  // Moves the model's samples with the keyframes they were tagged with (PointMap::MoveByTag), a
  // pending insert first. No undo journal.
  void MoveModel(const std::vector<Rigid3d>& new_from_old_by_tag) {
    Commit();
    map_.MoveByTag(new_from_old_by_tag);
  }

  // The map gate of an accepted view with ICP result `icp`: whether it enters the model. Its
  // residual joins the history when ICP ran (*rmse_pushed_mm gets it; untouched otherwise).
  bool AdmitToModel(const IcpResult& icp, double* rmse_pushed_mm);
  // The same bookkeeping replayed from a view's log (UndoFrom): residual pushed (< 0: none),
  // whether it entered the model.
  void ReplayAdmission(double rmse_pushed_mm, bool in_model);
  // The gate's residual history starts again (a new segment's views are compared with each other).
  void ForgetResiduals();

  // Coasting (max_coast_views): `failed` is ICP's result from `prediction`. When it fits the model
  // but is degenerate, ICP again along the constrained directions; true with *fit when that fits
  // and is a consistent motion (the coast run grows), false otherwise.
  bool Coast(const SurfacePoints& samples, const IcpResult& failed, const Rigid3d& prediction,
             const MotionModel& motion, IcpResult* fit);
  int coast_run() const { return coast_run_; }  // views coasted in a row
  void set_coast_run(int views) { coast_run_ = views; }

 private:
  void PushResidual(double rmse_mm);

  OdometryOptions o_;
  PinholeIntrinsics pinhole_;  // projective: the model image's intrinsics
  PointMap map_;
  bool insert_pending_ = false;  // map_samples_ go into map_ at pending_pose_ (Commit)
  Rigid3d pending_pose_ = Rigid3d::Identity();
  int32_t pending_tag_ = -1;
  SurfacePoints map_samples_;
  // Register's model samples near the view and its association grids, refilled for every ICP.
  mutable SurfacePoints gathered_;
  mutable GridTarget grid_;
  static constexpr size_t kRecentResiduals = 16;  // the "last 16" of map_max_rmse_ratio
  std::vector<double> recent_rmse_mm_;            // the last kRecentResiduals residuals (ring)
  size_t recent_rmse_next_ = 0;
  int gated_run_ = 0;  // views in a row kept out of the model
  int coast_run_ = 0;  // views in a row coasted
};

}  // namespace d3d
