#include "pipeline/register/reentry_check.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "common/core/status.h"

namespace d3d {

void ReentryCheckOptions::Check() const {
  D3D_CHECK_MSG(keyframes >= 1, "ReentryCheckOptions: keyframes must be >= 1, got " << keyframes);
  D3D_CHECK_MSG(max_centre_distance_mm > 0,
                "ReentryCheckOptions: max_centre_distance_mm must be > 0");
  D3D_CHECK_MSG(grid_scale > 0 && grid_scale <= 1,
                "ReentryCheckOptions: grid_scale must be in (0, 1], got " << grid_scale);
  D3D_CHECK_MSG(
      agree_mm > 0 && margin_mm >= agree_mm,
      "ReentryCheckOptions: need 0 < agree_mm <= margin_mm, got " << agree_mm << ", " << margin_mm);
  D3D_CHECK_MSG(max_violation_fraction >= 0 && max_violation_fraction <= 1,
                "ReentryCheckOptions: max_violation_fraction must be in [0, 1]");
  D3D_CHECK_MSG(min_tested >= 1, "ReentryCheckOptions: min_tested must be >= 1");
}

ReentryCheck::ReentryCheck(const PinholeBrownConrady& camera, const ReentryCheckOptions& options)
    : o_(options) {
  o_.Check();
  camera.Check();
  grid_ = PinholeIntrinsics::Of(camera).Scaled(o_.grid_scale);
  grid_.width = std::max(grid_.width, 3);
  grid_.height = std::max(grid_.height, 3);
}

void ReentryCheck::DepthGrid(const SurfacePoints& samples, cv::Mat* depth) const {
  depth->create(grid_.height, grid_.width, CV_32F);
  depth->setTo(std::numeric_limits<float>::infinity());
  for (const Eigen::Vector3f& p : samples.points) {
    if (!(p.z() > 0)) continue;
    const int u = static_cast<int>(std::lround(grid_.fx * p.x() / p.z() + grid_.cx));
    const int v = static_cast<int>(std::lround(grid_.fy * p.y() / p.z() + grid_.cy));
    if (u < 0 || v < 0 || u >= grid_.width || v >= grid_.height) continue;
    float& d = depth->at<float>(v, u);
    d = std::min(d, p.z());
  }
}

void ReentryCheck::Compare(const SurfacePoints& points, const Rigid3d& b_from_a,
                           const cv::Mat& depth_b, ReentryEvidence* e) const {
  const Eigen::Matrix3f R = b_from_a.linear().cast<float>();
  const Eigen::Vector3f t = b_from_a.translation().cast<float>();
  const float margin = static_cast<float>(o_.margin_mm), agree = static_cast<float>(o_.agree_mm);
  for (const Eigen::Vector3f& pa : points.points) {
    const Eigen::Vector3f p = R * pa + t;
    if (!(p.z() > 0)) continue;
    const int u = static_cast<int>(std::lround(grid_.fx * p.x() / p.z() + grid_.cx));
    const int v = static_cast<int>(std::lround(grid_.fy * p.y() / p.z() + grid_.cy));
    if (u < 1 || v < 1 || u >= grid_.width - 1 || v >= grid_.height - 1) continue;
    int with_depth = 0;
    float nearest = std::numeric_limits<float>::infinity();
    bool agrees = false;
    for (int dv = -1; dv <= 1; ++dv) {
      const float* row = depth_b.ptr<float>(v + dv);
      for (int du = -1; du <= 1; ++du) {
        const float d = row[u + du];
        if (!std::isfinite(d)) continue;
        ++with_depth;
        nearest = std::min(nearest, d);
        agrees = agrees || std::abs(d - p.z()) <= agree;
      }
    }
    if (agrees)
      ++e->agreeing;
    else if (with_depth >= 5 && nearest > p.z() + margin)
      ++e->seen_through;
  }
}

ReentryEvidence ReentryCheck::Test(const SurfacePoints& view_in_cam, const Rigid3d& world_from_cam,
                                   const std::vector<ReentryKeyframe>& keyframes) {
  ReentryEvidence e;
  if (!o_.enabled) return e;
  bool view_grid = false;
  const Eigen::Vector3d centre = world_from_cam * view_in_cam.Centroid();
  for (const ReentryKeyframe& kf : keyframes) {
    if (e.keyframes >= o_.keyframes) break;
    if (kf.samples == nullptr || kf.samples->empty()) continue;
    if ((kf.centre_in_world - centre).norm() > o_.max_centre_distance_mm) continue;
    if (!view_grid) {
      DepthGrid(view_in_cam, &view_depth_);
      view_grid = true;
    }
    const Rigid3d kf_from_view = kf.world_from_cam.inverse() * world_from_cam;
    DepthGrid(*kf.samples, &kf_depth_);
    Compare(view_in_cam, kf_from_view, kf_depth_, &e);  // view points the keyframe saw through
    Compare(*kf.samples, kf_from_view.inverse(), view_depth_,
            &e);  // keyframe points the view saw through
    ++e.keyframes;
  }
  const int64_t tested = e.agreeing + e.seen_through;
  if (tested >= o_.min_tested && e.violation_fraction() > o_.max_violation_fraction) {
    e.ok = false;
    char why[160];
    std::snprintf(why, sizeof why,
                  "seen-through space: %.1f %% of %lld points against %d keyframes (limit %.1f %%)",
                  100 * e.violation_fraction(), static_cast<long long>(tested), e.keyframes,
                  100 * o_.max_violation_fraction);
    e.reason = why;
  }
  return e;
}

}  // namespace d3d
