#include "pipeline/register/odometry.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "common/core/status.h"

namespace d3d {

const char* AssociationName(Association a) {
  switch (a) {
    case Association::kProjective:
      return "projective";
    case Association::kKdTree:
      return "kdtree";
    case Association::kGrid:
      return "grid";
  }
  return "?";
}

bool ParseAssociation(const std::string& name, Association* out) {
  for (Association a : {Association::kProjective, Association::kKdTree, Association::kGrid})
    if (name == AssociationName(a)) {
      *out = a;
      return true;
    }
  return false;
}

IcpOptions DefaultTrackerIcp() {
  IcpOptions o;
  o.levels.back().stride = 2;
  // Coarse levels pure point-to-plane and ended at a few micrometres (see odometry.h).
  o.levels[0].point_to_plane_weight = 1.0;
  o.levels[0].min_delta_translation_mm = 0.010;
  o.levels[0].min_delta_rotation_rad = 1e-3;
  o.levels[1].point_to_plane_weight = 1.0;
  o.levels[1].min_delta_translation_mm = 0.005;
  o.levels[1].min_delta_rotation_rad = 5e-4;
  o.min_delta_translation_mm = 5e-4;
  o.min_delta_rotation_rad = 2e-5;
  o.min_relative_error_change = 1e-3;
  return o;
}

int SegmentOfPoint(const Eigen::Vector3f& p) {
  return static_cast<int>(std::lround(p.x() / kSegmentSpacingMm));
}

void OdometryOptions::Check() const {
  icp.Check();
  map.Check();
  D3D_CHECK_MSG(grid_decimate_min_gate_mm >= 0,
                "OdometryOptions: grid_decimate_min_gate_mm >= 0 (0 = off)");
  D3D_CHECK_MSG(sample_stride >= 1 && map_stride >= 1, "OdometryOptions: strides >= 1");
  D3D_CHECK_MSG(target_scale > 0 && target_scale <= 2 && target_splat >= 0 && target_window >= 0,
                "OdometryOptions: target");
  D3D_CHECK_MSG(max_coast_views >= 0, "OdometryOptions: max_coast_views >= 0 (0 = off)");
  D3D_CHECK_MSG(coast_min_eigen_ratio > 0 && coast_min_eigen_ratio < 1,
                "OdometryOptions: coast_min_eigen_ratio must be in (0, 1)");
  D3D_CHECK_MSG(reregister_min_gain >= 0, "OdometryOptions: reregister_min_gain >= 0");
  D3D_CHECK_MSG(
      reregister_first_level >= 0 && reregister_first_level < static_cast<int>(icp.levels.size()),
      "OdometryOptions: reregister_first_level must index icp.levels");
  D3D_CHECK_MSG(map_max_rmse_ratio == 0 || map_max_rmse_ratio >= 1,
                "OdometryOptions: map_max_rmse_ratio 0 (off) or >= 1");
  D3D_CHECK_MSG(map_gate_min_overlap >= 0 && map_gate_min_overlap <= 1 && map_gate_max_run >= 0,
                "OdometryOptions: map_gate_min_overlap in [0, 1], map_gate_max_run >= 0");
}

Odometry::Odometry(const PinholeBrownConrady& camera, const OdometryOptions& options)
    : o_(options), map_(options.map) {
  o_.Check();
  pinhole_ = PinholeIntrinsics::Of(camera).Scaled(o_.target_scale);
}

IcpResult Odometry::Register(const SurfacePoints& source, const Rigid3d& initial,
                             const IcpOptions& icp) const {
  if (o_.association == Association::kProjective) {
    cv::Mat P, N;
    map_.Render(initial, pinhole_, o_.target_splat, &P, &N);
    ProjectiveTarget target(P, N, pinhole_, initial.inverse(), o_.target_window);
    return RegisterIcp(source, target, initial, icp);
  }
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(1e30f), hi = -lo;
  const Eigen::Matrix3f R = initial.linear().cast<float>();
  const Eigen::Vector3f t = initial.translation().cast<float>();
  for (const auto& p : source.points) {
    const Eigen::Vector3f w = R * p + t;
    lo = lo.cwiseMin(w);
    hi = hi.cwiseMax(w);
  }
  const Eigen::Vector3f m = Eigen::Vector3f::Constant(static_cast<float>(o_.gather_margin_mm));
  map_.Gather(lo - m, hi + m, &gathered_);
  // ICP linearises about the target's origin, in float: a segment's frame, kSegmentSpacingMm · s
  // from the main one, is moved back near the origin for it (its normal equations lost their
  // precision there: views 0.3 mm off after two steps), and the pose moved back after.
  const double shift_x =
      -kSegmentSpacingMm * std::round(initial.translation().x() / kSegmentSpacingMm);
  Rigid3d local = initial;
  if (shift_x != 0) {
    for (Eigen::Vector3f& p : gathered_.points) p.x() += static_cast<float>(shift_x);
    local.translation().x() += shift_x;
  }
  IcpResult r;
  if (o_.association == Association::kKdTree) {
    r = RegisterIcp(source, KdTreeTarget(gathered_), local, icp);
  } else {
    std::vector<double> gates;
    for (const IcpLevel& level : icp.levels) gates.push_back(level.max_distance_mm);
    grid_.Build(gathered_, gates, o_.grid_decimate_min_gate_mm);
    r = RegisterIcp(source, grid_, local, icp);
  }
  if (shift_x != 0) r.target_from_source.translation().x() -= shift_x;
  return r;
}

void Odometry::Insert(const cv::Mat& points, const cv::Mat& normals, const Rigid3d& pose,
                      int32_t tag) {
  SampleOrganised(points, normals, cv::Mat(), o_.map_stride, &map_samples_);
  insert_pending_ = true;
  pending_pose_ = pose;
  pending_tag_ = tag;
  if (!o_.defer_model_insert) Commit();
}

double Odometry::Commit() {
  if (!insert_pending_) return 0;
  const auto t0 = std::chrono::steady_clock::now();
  insert_pending_ = false;
  map_.Insert(map_samples_, pending_pose_, pending_tag_);
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

bool Odometry::AdmitToModel(const IcpResult& icp, double* rmse_pushed_mm) {
  // The first view (no ICP) always enters.
  bool in_model = true;
  if (icp.ok && icp.rmse_mm > 0) {
    if (o_.map_max_rmse_ratio > 0 && recent_rmse_mm_.size() >= 8 &&
        icp.overlap >= o_.map_gate_min_overlap && gated_run_ < o_.map_gate_max_run) {
      std::vector<double> sorted = recent_rmse_mm_;
      std::nth_element(sorted.begin(),
                       sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2),
                       sorted.end());
      in_model = icp.rmse_mm <= o_.map_max_rmse_ratio * sorted[sorted.size() / 2];
    }
    PushResidual(icp.rmse_mm);
    *rmse_pushed_mm = icp.rmse_mm;
  }
  gated_run_ = in_model ? 0 : gated_run_ + 1;
  return in_model;
}

void Odometry::ReplayAdmission(double rmse_pushed_mm, bool in_model) {
  if (rmse_pushed_mm >= 0) PushResidual(rmse_pushed_mm);
  gated_run_ = in_model ? 0 : gated_run_ + 1;
}

void Odometry::ForgetResiduals() {
  recent_rmse_mm_.clear();
  recent_rmse_next_ = 0;
  gated_run_ = 0;
}

void Odometry::PushResidual(double rmse_mm) {
  if (recent_rmse_mm_.size() < kRecentResiduals)
    recent_rmse_mm_.push_back(rmse_mm);
  else
    recent_rmse_mm_[recent_rmse_next_++ % kRecentResiduals] = rmse_mm;
}

bool Odometry::Coast(const SurfacePoints& samples, const IcpResult& failed,
                     const Rigid3d& prediction, const MotionModel& motion, IcpResult* fit) {
  const IcpOptions& icp = o_.icp;
  if (o_.max_coast_views <= 0 || coast_run_ >= o_.max_coast_views) return false;
  // Refused for its degeneracy alone: it fits the model where it overlaps it.
  auto fits = [&](const IcpResult& r) {
    return r.correspondences >= icp.min_correspondences && r.overlap >= icp.min_overlap &&
           r.rmse_mm <= icp.max_rmse_mm;
  };
  if (!fits(failed) || failed.eigen_ratio >= icp.min_eigen_ratio) return false;
  // ICP again from the prediction, stepping only along the well-constrained directions.
  IcpOptions remapped = icp;
  remapped.remap_min_eigen_ratio = o_.coast_min_eigen_ratio;
  const IcpResult r = Register(samples, prediction, remapped);
  if (!fits(r)) return false;
  if (!motion.Consistent(r.target_from_source, nullptr)) return false;
  *fit = r;
  ++coast_run_;
  return true;
}

}  // namespace d3d
