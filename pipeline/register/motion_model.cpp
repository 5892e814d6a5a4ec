#include "pipeline/register/motion_model.h"

#include <cmath>

#include "common/core/status.h"

namespace d3d {

void MotionModelOptions::Check() const {
  D3D_CHECK_MSG(max_step_mm > 0 && max_step_deg > 0,
                "MotionModelOptions: max_step_mm and max_step_deg must be > 0");
  D3D_CHECK_MSG(view_period_ns >= 0,
                "MotionModelOptions: view_period_ns must be >= 0 (0 = evenly spaced views)");
}

MotionModel::MotionModel(const MotionModelOptions& options) : o_(options) { o_.Check(); }

void MotionModel::BeginView(int64_t view, int64_t capture_ns) {
  view_ = view;
  capture_ns_ = capture_ns;
}

bool MotionModel::TimedSince(int64_t capture_ns) const {
  return o_.view_period_ns > 0 && capture_ns_ > 0 && capture_ns > 0 && capture_ns_ > capture_ns;
}

double MotionModel::ViewsSince(int64_t view, int64_t capture_ns) const {
  if (TimedSince(capture_ns))
    return static_cast<double>(capture_ns_ - capture_ns) / static_cast<double>(o_.view_period_ns);
  return static_cast<double>(view_ - view);
}

Rigid3d MotionModel::Predict() const {
  if (!HasVelocity()) return last_pose_;
  const Rigid3d step = prev_pose_.inverse() * last_pose_;
  double k = static_cast<double>(view_ - last_view_) / static_cast<double>(last_view_ - prev_view_);
  if (Timed() && prev_ns_ > 0 && last_ns_ > prev_ns_)
    k = static_cast<double>(capture_ns_ - last_ns_) / static_cast<double>(last_ns_ - prev_ns_);
  return k <= 8 ? Rigid3d(last_pose_ * InterpolateRigid(Rigid3d::Identity(), step, k)) : last_pose_;
}

bool MotionModel::ConsistentFrom(const Rigid3d& from, double views, const Rigid3d& pose,
                                 std::string* why) const {
  const double step_mm = TranslationDistanceMm(pose, from);
  const double step_deg = RotationAngleRad(pose, from) * 180 / M_PI;
  if (step_mm > o_.max_step_mm * views || step_deg > o_.max_step_deg * views) {
    if (why)
      *why = "inconsistent motion (" + std::to_string(step_mm) + " mm, " +
             std::to_string(step_deg) + " deg)";
    return false;
  }
  return true;
}

void MotionModel::Advance(const Rigid3d& pose, bool restart) {
  AdvanceAt(view_, pose, capture_ns_, restart);
}

void MotionModel::AdvanceAt(int64_t view, const Rigid3d& pose, int64_t capture_ns, bool restart) {
  prev_pose_ = last_pose_;
  prev_view_ = restart ? -1 : last_view_;
  prev_ns_ = last_ns_;
  last_pose_ = pose;
  last_view_ = view;
  last_ns_ = capture_ns;
}

void MotionModel::MoveFrame(const Rigid3d& new_from_old) {
  last_pose_ = new_from_old * last_pose_;
  prev_pose_ = new_from_old * prev_pose_;
}

void MotionModel::Reset() {
  last_view_ = prev_view_ = -1;
  last_pose_ = prev_pose_ = Rigid3d::Identity();
  last_ns_ = prev_ns_ = 0;
}

}  // namespace d3d
