// What Track() found for one view: the tracking state and the per-view result that every part of
// the tracker (odometry.h, relocaliser.h, keyframe_graph.h, segments.h) fills its piece of.
#pragma once

#include <limits>
#include <string>

#include "common/core/rigid.h"
#include "pipeline/register/icp.h"
#include "pipeline/register/reentry_check.h"

namespace d3d {

enum class TrackingState { kInitialising, kTracking, kLost, kRelocalised };
const char* TrackingStateName(
    TrackingState s);  // "initialising", "tracking", "lost", "relocalised"

struct TrackResult {
  TrackingState state = TrackingState::kInitialising;
  bool accepted = false;  // pose valid and view added to the model (fuse it)
  Rigid3d world_from_cam = Rigid3d::Identity();
  std::string reason;  // why refused, or how relocalised
  IcpResult icp;
  bool new_keyframe = false;
  bool keyframe_reused =
      false;  // an older keyframe became the current one (KeyframeGraphOptions::reuse_radius_mm)
  bool in_model =
      false;  // the view's samples entered the tracking model (OdometryOptions::map_max_rmse_ratio)
  ReentryEvidence
      reentry;      // the re-entry check of the pose found after a loss (keyframes 0: none ran)
  int segment = 0;  // the segment of the view (accepted views)
  bool new_segment = false;     // the view started that segment
  bool segment_joined = false;  // the segment was joined to the main model before this view
  // Where a preview may draw a view of a segment apart (accepted, !in_main): world_from_cam with
  // the segment's frame moved back to the main frame's origin (MainFromSegmentFrame), beside where
  // the model was lost; not registered to it. In the main frame: world_from_cam.
  Rigid3d display_from_cam = Rigid3d::Identity();
  // segment_joined: carries what was drawn at that segment's display_from_cam poses into the main
  // frame.
  Rigid3d main_from_display = Rigid3d::Identity();
  std::string join_attempt;  // what a join attempt before this view found (empty: none was made)
  // The pose is in the main frame (the first segment, or one joined to it): fuse the view into the
  // main model only then.
  bool in_main = true;
  int loops_added = 0;
  // A loop correction optimised the pose graph at this view (TrackerOptions::loop_correction): the
  // largest shift of a keyframe's surface centre (mm); the model moved when above its
  // min_shift_mm. 0: none ran.
  double loop_shift_mm = 0;
  bool loop_corrected = false;
  // Accepted views: how far (camera centre, mm) the pose lies from the motion model's prediction;
  // NaN when there was none (the first views, a re-entry, a new segment).
  double prediction_offset_mm = std::numeric_limits<double>::quiet_NaN();
  double prediction_offset_deg = std::numeric_limits<double>::quiet_NaN();
  double ms = 0;
  // Refused before registration: the view had too few points to register (a lifted probe, a view
  // out of the measurement volume), not a view the tracker failed to place.
  bool too_few_points = false;
};

}  // namespace d3d
