// The tracker's motion model: constant velocity of the probe from the last two placed views, and
// the check that a registered pose is a motion the hand can make. One per Tracker, on Track()'s
// thread. Poses are world_from_cam (mm); views are counted in Track() calls.
#pragma once

#include <cstdint>
#include <string>

#include "common/core/rigid.h"

namespace d3d {

struct MotionModelOptions {
  double max_step_mm = 2.5;  // per view: larger motion is "inconsistent motion"
  double max_step_deg = 10.0;
  // The time of one view (ns) when views are not evenly spaced (a live host processes the newest
  // burst whenever it is free, so the gaps between its views vary): with it and the views' capture
  // times, the prediction is constant velocity per unit time and the max_step limits scale with
  // the time elapsed (in views of this length) rather than with the views counted. 0: views are
  // evenly spaced (d3d-fuse, lossless replay); capture times are then not used.
  int64_t view_period_ns = 0;
  void Check() const;  // throws std::invalid_argument
};

class MotionModel {
 public:
  explicit MotionModel(const MotionModelOptions& options = {});
  const MotionModelOptions& options() const { return o_; }

  // The view `view` (capture time capture_ns, 0 = unknown) is about to be placed.
  void BeginView(int64_t view, int64_t capture_ns);
  // The pose the current view is expected at: the last placed pose moved on by the last step, per
  // view elapsed (or per unit time, see view_period_ns); the last pose when there is no step (one
  // view placed, or a restart) or more than 8 steps elapsed.
  Rigid3d Predict() const;
  // Whether Predict() extrapolates a step (two placed views since the last restart).
  bool HasVelocity() const { return prev_view_ >= 0 && last_view_ > prev_view_; }
  // Views (or view periods) since the last placed view.
  double ViewsElapsed() const { return ViewsSince(last_view_, last_ns_); }
  // Views (or view periods, when both capture times are known) since view `view` captured at
  // capture_ns (a re-entry candidate, say).
  double ViewsSince(int64_t view, int64_t capture_ns) const;
  // `pose` is a motion from `from` within max_step_mm / max_step_deg × views; else false and
  // *why (if not null) says by how much.
  bool ConsistentFrom(const Rigid3d& from, double views, const Rigid3d& pose,
                      std::string* why) const;
  // The same from the last placed pose over ViewsElapsed().
  bool Consistent(const Rigid3d& pose, std::string* why) const {
    return ConsistentFrom(last_pose_, ViewsElapsed(), pose, why);
  }

  // The current view was placed at `pose`; `restart`: no velocity across it (a re-entry).
  void Advance(const Rigid3d& pose, bool restart);
  // The same for view `view` of the past (replaying a history after an undo).
  void AdvanceAt(int64_t view, const Rigid3d& pose, int64_t capture_ns, bool restart);
  // The next view gets no step to extrapolate (a new segment starts its own chain).
  void ForgetVelocity() { prev_view_ = -1; }
  // The poses re-expressed in another frame: new_world_from_old · pose (a segment joined).
  void MoveFrame(const Rigid3d& new_from_old);
  // Nothing placed yet.
  void Reset();

  const Rigid3d& last_pose() const { return last_pose_; }
  int64_t last_view() const { return last_view_; }  // −1: none placed
  int64_t view() const { return view_; }
  int64_t capture_ns() const { return capture_ns_; }
  // view_period_ns and the capture times are in use for the current view.
  bool Timed() const { return TimedSince(last_ns_); }

 private:
  bool TimedSince(int64_t capture_ns) const;  // by time from capture_ns to the current view
  MotionModelOptions o_;
  int64_t view_ = -1, capture_ns_ = 0;  // the view being placed
  Rigid3d last_pose_ = Rigid3d::Identity(), prev_pose_ = Rigid3d::Identity();
  int64_t last_view_ = -1, prev_view_ = -1;
  int64_t last_ns_ = 0, prev_ns_ = 0;
};

}  // namespace d3d
