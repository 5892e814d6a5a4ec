// The tracker's relocaliser: finds a view on the model again when frame-to-model ICP from the
// prediction failed, after a gap or a loss, and holds every such return (and every tracked pose
// that jumps from the prediction) to a standard a neighbouring-tooth fit cannot meet.
//  - Local search: ICP from the prediction, the last accepted pose and the local_candidates
//    keyframes nearest to it (the probe usually comes back where it left), with a wide first gate;
//    the result must be a consistent motion over the views elapsed. After a gap every start is
//    tried, and two passing fits apart make the return ambiguous (ambiguity_mm).
//  - Feature relocalisation: SIFT features of the view (features.h) matched to the keyframes
//    nearest the last accepted view, RANSAC → ICP against the model.
//  - Verification of a re-entry (VerifyReentry): after a gap or a jump, well constrained
//    (min_eigen_ratio); and the re-entry check against the keyframes near the pose
//    (reentry_check.h).
//  - Confirmation: after a loss a found view is a candidate, and the next view must confirm it
//    (ICP from the candidate's pose, a consistent motion since it).
//
// Owns: the re-entry check and its keyframe list (reused), and the pending re-entry candidate. It
// reads the tracking model through the odometry (odometry.h), the motion model, the keyframes
// (keyframe_graph.h; extracting pending features) and the active segment (segments.h). Track()'s
// thread only.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "calib/model/camera_model.h"
#include "pipeline/register/keyframe_graph.h"
#include "pipeline/register/motion_model.h"
#include "pipeline/register/odometry.h"
#include "pipeline/register/reentry_check.h"
#include "pipeline/register/segments.h"
#include "pipeline/register/track_result.h"

namespace d3d {

struct RelocaliserOptions {
  bool by_features = true;  // feature relocalisation (and the keyframes' features) on
  int feature_candidates =
      6;                     // keyframes matched by features, nearest the last accepted view first
  int local_candidates = 4;  // local search: ICP from the last pose and this many nearest keyframes
  double local_search_gate_mm = 4.0;  // first-level association gate of the local search
  // A re-entering view's (local search, features, confirmation) ICP residual (mm) and overlap
  // limits, stricter than tracking's, which a neighbouring-tooth fit after a gap can pass
  // (docs/decisions/0008).
  double max_rmse_mm = 0.04;
  double min_overlap = 0.5;
  // After a loss, a found view is a re-entry candidate (refused, state kLost) that the next view
  // with points must confirm: one view can fit a neighbouring tooth, two in a row rarely agree on
  // it. The cost: the first view of every re-entry after a loss is not fused. false: accepted at
  // once.
  bool confirm_reentry = true;
  // ... except a re-entry ICP from the prediction finds at most this many views (by time with
  // motion.view_period_ns) after the last accepted one: one bad view in a track that never left,
  // resumed at once. Also the limit of "tracking" for a gap (views with too few points in a row
  // count: docs/decisions/0010) and for coasting. 0 = always confirm.
  double direct_max_views = 2.0;
  // A re-entry after a gap (lost, or more than direct_max_views since the last accepted view) or a
  // jump must be well constrained: ICP's eigenvalue ratio at least this (a smooth stretch slides;
  // docs/decisions/0003). 0 = no such limit.
  double min_eigen_ratio = 0.02;
  // After a gap, two fits of the local search that both pass but lie more than this apart (view
  // centre, mm) or 2° make the return ambiguous: refused. 0 = the first fit that passes is taken.
  double ambiguity_mm = 0.5;
  // A pose farther than these from the motion prediction (per view it spans, at least one) is a
  // jump, not a hand's motion: it must meet a re-entry's standard (max_rmse_mm, min_overlap,
  // min_eigen_ratio, the re-entry check) or the view is refused (docs/decisions/0007). 0 = off.
  double jump_check_mm = 1.5;
  double jump_check_deg = 3.0;
  // Every re-entry pose must be consistent with what the keyframes near it saw (reentry_check.h).
  ReentryCheckOptions check;
  void Check() const;  // throws std::invalid_argument
};

class Relocaliser {
 public:
  // camera: intrinsics of the views (the re-entry check). Throws for invalid options.
  Relocaliser(const PinholeBrownConrady& camera, const RelocaliserOptions& options,
              const Odometry* odometry, const MotionModel* motion, KeyframeGraph* keyframes,
              const Segments* segments);
  const RelocaliserOptions& options() const { return o_; }

  // A return to the model after a gap or a loss. gap (here and below): the tracker knows of one
  // (state kLost, or back after views without points: Tracker::BackFromNoPoints); more than
  // direct_max_views views since the last accepted one are a gap too.
  bool AfterGap(bool gap) const;
  // Whether `pose` lies farther from the motion prediction than jump_check_mm / jump_check_deg.
  bool JumpsFromPrediction(const Rigid3d& pose) const;
  // A tracked view's fit (ICP result r of `samples`) that jumped: the re-entry's residual and
  // overlap limits, then VerifyReentry. False with *why.
  bool MeetsJumpStandard(const SurfacePoints& samples, const IcpResult& r, bool gap,
                         std::string* why);
  // The re-entry check of `samples` (camera frame) at world_from_cam against the keyframes nearest
  // to it (their current graph poses).
  ReentryEvidence CheckReentry(const SurfacePoints& samples, const Rigid3d& world_from_cam);

  // Local search; on success out->icp, world_from_cam, reentry and reason are set, and
  // *from_prediction tells whether the fit started from the motion prediction. False with
  // out->reason.
  bool SearchLocally(const SurfacePoints& samples, bool gap, TrackResult* out,
                     bool* from_prediction);
  // Feature relocalisation of the view (points H×W CV_32FC3, texture H×W CV_8U or empty; samples
  // from them); the same outputs.
  bool SearchByFeatures(const SurfacePoints& samples, const cv::Mat& points, const cv::Mat& texture,
                        bool gap, TrackResult* out);

  // The pending re-entry candidate (confirm_reentry).
  struct Candidate {
    bool pending = false;
    int64_t view = -1, capture_ns = 0;
    Rigid3d world_from_cam = Rigid3d::Identity();
    std::string how;
  };
  const Candidate& candidate() const { return candidate_; }
  void SetCandidate(int64_t view, int64_t capture_ns, const Rigid3d& world_from_cam,
                    const std::string& how);
  void DropCandidate() { candidate_ = Candidate{}; }
  // ICP of this view from the candidate's pose (the candidate is no longer pending after); true
  // with out->icp and world_from_cam when it confirms it, false with out->reason.
  bool Confirm(const SurfacePoints& samples, bool gap, TrackResult* out);

 private:
  // ICP of the local search and of a confirmation: the tracking ICP with the first level's gate
  // widened to local_search_gate_mm and the residual limit max_rmse_mm.
  IcpOptions LocalSearchIcp() const;
  // The checks of a re-entry pose (ICP result r of `samples`) beyond ICP's own: after a gap or a
  // jump, well constrained; and the re-entry check, whose evidence goes to *evidence. False with
  // *why when one fails (*evidence untouched when the first did).
  bool VerifyReentry(const SurfacePoints& samples, const IcpResult& r, bool gap,
                     ReentryEvidence* evidence, std::string* why);
  // Keyframes of the active segment by the distance of their centre from the view's centre at the
  // last accepted pose, nearest first.
  std::vector<std::pair<double, int>> NearestKeyframes(const SurfacePoints& samples) const;

  RelocaliserOptions o_;
  const Odometry& odometry_;
  const MotionModel& motion_;
  KeyframeGraph& keyframes_;
  const Segments& segments_;
  ReentryCheck reentry_check_;
  std::vector<ReentryKeyframe> reentry_kfs_;  // CheckReentry's keyframes, reused
  Candidate candidate_;
};

}  // namespace d3d
