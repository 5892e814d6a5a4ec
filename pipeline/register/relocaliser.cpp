#include "pipeline/register/relocaliser.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "common/core/status.h"

namespace d3d {

void RelocaliserOptions::Check() const {
  D3D_CHECK_MSG(feature_candidates >= 1, "RelocaliserOptions: feature_candidates >= 1");
  D3D_CHECK_MSG(direct_max_views >= 0, "RelocaliserOptions: direct_max_views >= 0");
  D3D_CHECK_MSG(min_eigen_ratio >= 0 && min_eigen_ratio < 1,
                "RelocaliserOptions: min_eigen_ratio in [0, 1)");
  D3D_CHECK_MSG(ambiguity_mm >= 0, "RelocaliserOptions: ambiguity_mm >= 0 (0 = off)");
  D3D_CHECK_MSG(jump_check_mm >= 0 && jump_check_deg >= 0,
                "RelocaliserOptions: jump_check_mm and jump_check_deg >= 0 (0 = off)");
  check.Check();
}

Relocaliser::Relocaliser(const PinholeBrownConrady& camera, const RelocaliserOptions& options,
                         const Odometry* odometry, const MotionModel* motion,
                         KeyframeGraph* keyframes, const Segments* segments)
    : o_(options),
      odometry_(*odometry),
      motion_(*motion),
      keyframes_(*keyframes),
      segments_(*segments),
      reentry_check_(camera, options.check) {
  o_.Check();
}

IcpOptions Relocaliser::LocalSearchIcp() const {
  IcpOptions icp = odometry_.options().icp;
  icp.levels.front().max_distance_mm =
      std::max(icp.levels.front().max_distance_mm, o_.local_search_gate_mm);
  // Its wide first level keeps IcpOptions' point-to-point share, which widens the basin: a
  // re-entry starts from a pose up to millimetres off, tracking from one a view's motion off.
  icp.levels.front().point_to_plane_weight = IcpOptions().levels.front().point_to_plane_weight;
  // A view found this way re-enters the model and must meet max_rmse_mm like a feature
  // relocalisation (neighbouring-tooth fits came back just under tracking's limit).
  icp.max_rmse_mm = std::min(icp.max_rmse_mm, o_.max_rmse_mm);
  return icp;
}

void Relocaliser::SetCandidate(int64_t view, int64_t capture_ns, const Rigid3d& world_from_cam,
                               const std::string& how) {
  candidate_.pending = true;
  candidate_.view = view;
  candidate_.capture_ns = capture_ns;
  candidate_.world_from_cam = world_from_cam;
  candidate_.how = how;
}

bool Relocaliser::Confirm(const SurfacePoints& samples, bool gap, TrackResult* out) {
  candidate_.pending = false;
  const IcpResult r = odometry_.Register(samples, candidate_.world_from_cam, LocalSearchIcp());
  if (!r.ok) {
    out->reason = "icp: " + r.reason;
    return false;
  }
  const double views = motion_.ViewsSince(candidate_.view, candidate_.capture_ns);
  if (!motion_.ConsistentFrom(candidate_.world_from_cam, views, r.target_from_source, &out->reason))
    return false;
  if (!VerifyReentry(samples, r, gap, &out->reentry, &out->reason)) return false;
  out->icp = r;
  out->world_from_cam = r.target_from_source;
  return true;
}

bool Relocaliser::AfterGap(bool gap) const {
  return gap || motion_.ViewsElapsed() > o_.direct_max_views;
}

bool Relocaliser::JumpsFromPrediction(const Rigid3d& pose) const {
  if (motion_.last_view() < 0) return false;
  // The prediction's error grows with the time it spans (a live host's views come unevenly).
  const double views = std::max(1.0, motion_.ViewsElapsed());
  const Rigid3d pred = motion_.Predict();
  return (o_.jump_check_mm > 0 && TranslationDistanceMm(pose, pred) > o_.jump_check_mm * views) ||
         (o_.jump_check_deg > 0 &&
          RotationAngleRad(pose, pred) * 180 / M_PI > o_.jump_check_deg * views);
}

bool Relocaliser::MeetsJumpStandard(const SurfacePoints& samples, const IcpResult& r, bool gap,
                                    std::string* why) {
  char what[160];
  if (r.rmse_mm > o_.max_rmse_mm || r.overlap < o_.min_overlap) {
    std::snprintf(what, sizeof what,
                  "rmse %.1f um, overlap %.2f (a jump needs <= %.1f um, >= %.2f)", r.rmse_mm * 1000,
                  r.overlap, o_.max_rmse_mm * 1000, o_.min_overlap);
    *why = what;
    return false;
  }
  ReentryEvidence evidence;
  return VerifyReentry(samples, r, gap, &evidence, why);
}

bool Relocaliser::VerifyReentry(const SurfacePoints& samples, const IcpResult& r, bool gap,
                                ReentryEvidence* evidence, std::string* why) {
  if ((AfterGap(gap) || JumpsFromPrediction(r.target_from_source)) &&
      r.eigen_ratio < o_.min_eigen_ratio) {
    *why = "degenerate re-entry (eigen ratio " + std::to_string(r.eigen_ratio) + " < " +
           std::to_string(o_.min_eigen_ratio) + ")";
    return false;
  }
  *evidence = CheckReentry(samples, r.target_from_source);
  if (evidence->ok) return true;
  *why = evidence->reason;
  return false;
}

ReentryEvidence Relocaliser::CheckReentry(const SurfacePoints& samples,
                                          const Rigid3d& world_from_cam) {
  // The keyframes whose surface centre is nearest the view's at the candidate pose.
  const Eigen::Vector3d centre = world_from_cam * samples.Centroid();
  std::vector<std::pair<double, int>> order;
  for (int k = 0; k < keyframes_.size(); ++k) {
    const double d = (keyframes_.CentreInWorld(k) - centre).norm();
    if (d <= o_.check.max_centre_distance_mm) order.emplace_back(d, k);
  }
  const size_t n = std::min(order.size(), static_cast<size_t>(o_.check.keyframes));
  std::partial_sort(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(n), order.end());
  reentry_kfs_.clear();
  for (size_t i = 0; i < n; ++i) {
    const Keyframe& kf = keyframes_.keyframes()[static_cast<size_t>(order[i].second)];
    const Rigid3d world_from_kf = keyframes_.world_from_keyframe(order[i].second);
    reentry_kfs_.push_back({&kf.samples, world_from_kf, world_from_kf * kf.centre_in_cam});
  }
  return reentry_check_.Test(samples, world_from_cam, reentry_kfs_);
}

std::vector<std::pair<double, int>> Relocaliser::NearestKeyframes(
    const SurfacePoints& samples) const {
  const Eigen::Vector3d here = motion_.last_pose() * samples.Centroid();
  std::vector<std::pair<double, int>> order;
  for (int k = 0; k < keyframes_.size(); ++k) {
    if (!segments_.KeyframeInActive(k)) continue;
    order.emplace_back((keyframes_.CentreInWorld(k) - here).norm(), k);
  }
  std::sort(order.begin(), order.end());
  return order;
}

bool Relocaliser::SearchLocally(const SurfacePoints& samples, bool gap, TrackResult* out,
                                bool* from_prediction) {
  *from_prediction = false;
  const std::vector<std::pair<double, int>> order = NearestKeyframes(samples);
  std::vector<Rigid3d> starts = {motion_.Predict(), motion_.last_pose()};
  for (int i = 0; i < std::min<int>(o_.local_candidates, static_cast<int>(order.size())); ++i)
    starts.push_back(keyframes_.world_from_keyframe(order[static_cast<size_t>(i)].second));
  const IcpOptions icp = LocalSearchIcp();
  // The search is local: its result must also be a consistent motion from the last accepted pose
  // (over the views elapsed); a far return is left to the feature relocalisation.
  std::string last_reason, failures;  // failures: why each start failed, for the events
  const auto start_name = [&](size_t i) {
    return i == 0   ? std::string("from the prediction")
           : i == 1 ? std::string("from the last pose")
                    : "from keyframe " + std::to_string(order[i - 2].second);
  };
  // After a gap every start is tried: a second fit that passes too, elsewhere, makes the return
  // ambiguous (ambiguity_mm).
  const bool all_starts = AfterGap(gap) && o_.ambiguity_mm > 0;
  const Eigen::Vector3d centre_in_cam = samples.Centroid();
  int found = -1;
  for (size_t i = 0; i < starts.size(); ++i) {
    // A start equal bit for bit to an earlier one gives that one's result: skipped. When lost, the
    // prediction is the last pose, and the nearest keyframe is often that pose too; each repeat was
    // a wide-gate ICP (docs/decisions/0013).
    size_t same = 0;
    while (same < i && !SameBits(starts[same], starts[i])) ++same;
    if (same < i) {
      failures += (failures.empty() ? "" : ", ") + start_name(i) + ": as " + start_name(same);
      continue;
    }
    const IcpResult r = odometry_.Register(samples, starts[i], icp);
    ReentryEvidence evidence;
    if (!r.ok) last_reason = r.reason;
    if (!r.ok || !motion_.Consistent(r.target_from_source, &last_reason) ||
        !VerifyReentry(samples, r, gap, &evidence, &last_reason)) {
      failures += (failures.empty() ? "" : ", ") + start_name(i) + ": " + last_reason;
      continue;
    }
    if (found >= 0) {
      const double apart_mm =
          (r.target_from_source * centre_in_cam - out->world_from_cam * centre_in_cam).norm();
      const double apart_deg =
          RotationAngleRad(r.target_from_source, out->world_from_cam) * 180 / M_PI;
      if (apart_mm > o_.ambiguity_mm || apart_deg > 2.0) {
        char why[160];
        std::snprintf(why, sizeof why, "ambiguous re-entry: two fits %.2f mm, %.1f deg apart",
                      apart_mm, apart_deg);
        out->reason = why;
        return false;
      }
      continue;
    }
    found = static_cast<int>(i);
    out->reentry = evidence;
    out->icp = r;
    out->world_from_cam = r.target_from_source;
    *from_prediction = i == 0;
    out->reason = i == 0 ? "icp from the predicted pose" : "icp " + start_name(i);
    if (!all_starts) return true;
  }
  if (found >= 0) return true;
  out->reason = failures.empty() ? last_reason : failures;
  return false;
}

bool Relocaliser::SearchByFeatures(const SurfacePoints& samples, const cv::Mat& points,
                                   const cv::Mat& texture, bool gap, TrackResult* out) {
  const FeatureOptions& features = keyframes_.options().features;
  const ViewFeatures f = ExtractViewFeatures(points, texture, features);
  keyframes_.CollectFeatures();
  // Local border search: keyframes nearest the last accepted view first.
  const std::vector<std::pair<double, int>> order = NearestKeyframes(samples);
  IcpOptions icp = odometry_.options().icp;
  icp.max_rmse_mm = o_.max_rmse_mm;
  icp.min_overlap = o_.min_overlap;
  std::string last_reason = "no keyframe";
  for (int i = 0; i < std::min<int>(o_.feature_candidates, static_cast<int>(order.size())); ++i) {
    const int k = order[static_cast<size_t>(i)].second;
    const FeatureAlignResult a = AlignByFeatures(f, keyframes_.Features(k), features);
    if (!a.ok) {
      last_reason = a.reason;
      continue;
    }
    const Rigid3d guess = keyframes_.world_from_keyframe(k) * a.target_from_source;
    const IcpResult r = odometry_.Register(samples, guess, icp);
    if (!r.ok) {
      last_reason = "icp after features: " + r.reason;
      continue;
    }
    if (!VerifyReentry(samples, r, gap, &out->reentry, &last_reason)) {
      last_reason = "after features: " + last_reason;
      continue;
    }
    out->icp = r;
    out->world_from_cam = r.target_from_source;
    out->reason =
        "keyframe " + std::to_string(k) + ", " + std::to_string(a.inliers) + " feature inliers";
    return true;
  }
  out->reason = last_reason;
  return false;
}

}  // namespace d3d
