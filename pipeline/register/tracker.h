// Frame-to-model tracking of a hand-held scan, with tracking-loss detection, relocalisation,
// keyframes, a loop-closing pose graph and scan segments. One Tracker per scan, driven by one
// thread. The Tracker only sequences its parts per view and keeps the undo log:
//   odometry.h        frame-to-model ICP, the tracking model, the map gate, coasting
//   motion_model.h    the prediction and the motion check
//   relocaliser.h     local search, feature relocalisation, re-entry checks and confirmation
//   keyframe_graph.h  keyframes, their reuse, pose-graph edges and loop closures, keyframe features
//   segments.h        segments started when views cannot be placed, and their joins
//
// Per view (an organised cloud in the camera frame):
//  1. Prediction: constant velocity from the last two accepted poses, over skipped views too.
//  2. Frame-to-model ICP against the model of every accepted view. A view with too few points
//     (probe lifted, out of range) is skipped without a state change.
//  3. Checks: ICP ok (overlap, residual, degeneracy) and a consistent motion; a pose that jumps
//  from
//     the prediction must meet a re-entry's standard. A view failing them is refused (not fused,
//     not added to the model) and the state becomes kLost; optionally one that fits but is
//     degenerate is coasted instead (not fused, the track kept).
//  4. Relocalisation (when ICP fails, and for every view while lost): the local search, then
//     feature relocalisation; a return after a loss waits for the next view's confirmation.
//  4b. Segments: views that still cannot be placed start a segment of their own frame, joined to
//     the main model once they overlap it.
//  5. Keyframes and loop closure: the view becomes a keyframe (or reuses one) when it leaves the
//     current keyframe; a new keyframe gets its odometry and loop edges.
//  6. Loop correction (LoopCorrectionOptions): a new keyframe that finds the drift since an older
//     one it overlaps has the pose graph solved at once, and the tracking model moves with it.
// Optimize() solves the pose graph and re-expresses every accepted view through its anchor
// keyframe: world_from_cam = world_from_keyframe (optimised) · keyframe_from_cam (tracked).
// UndoFrom() takes the newest views back out (the host's "undo last seconds"): they become refused
// views, and the model, keyframes, pose graph and motion state are what they were before them
// (the model exactly, through PointMap's undo journal: OdometryOptions::map.undo_inserts).
//
// Owns, besides its parts: the tracking state, the view index, the motion model, the per-view
// anchors and the undo log (ViewLog), and Track()'s sample buffers. Track()'s thread only.
#pragma once

#include <functional>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "calib/model/camera_model.h"
#include "pipeline/register/keyframe_graph.h"
#include "pipeline/register/motion_model.h"
#include "pipeline/register/odometry.h"
#include "pipeline/register/point_map.h"
#include "pipeline/register/pose_graph.h"
#include "pipeline/register/relocaliser.h"
#include "pipeline/register/segments.h"
#include "pipeline/register/track_result.h"

namespace d3d {

// Loop correction during the scan: when a new keyframe closes a loop whose ICP puts it more than
// min_shift_mm from where the track has it (KeyframeGraph::LoopDiscrepancyMm: the drift since),
// the pose graph is optimised then (KeyframeGraph::OptimizeNow) instead of only at the end, and
// the tracking model's samples move with the keyframes they were seen from (PointMap::MoveByTag),
// the motion model with the current keyframe. The track then goes on in the corrected frame: a
// pass that comes back over ground scanned long before meets it where the loop says it is, not
// where the drift since put it (docs/decisions/0020). The views already fused live were fused at
// their poses before the correction; the scan fuses them again at the end (scan_chain.h).
struct LoopCorrectionOptions {
  bool enabled = false;
  // The drift (mm) a loop must show to be corrected, and that the optimised graph must move some
  // keyframe's surface centre by for the model to move (below it the graph keeps its tracked
  // poses; the loop edges stay).
  double min_shift_mm = 0.1;
  int check_candidates = 1;  // loop candidates registered for a check (one ICP each)
  // At most one check per this many new keyframes (a keyframe without a loop candidate is no
  // check): drift grows slowly, and each check costs keyframe ICPs on Track()'s thread.
  int every_keyframes = 3;
  PoseGraphOptions graph;
  void Check() const;  // throws std::invalid_argument
};

struct TrackerOptions {
  OdometryOptions odometry;        // frame-to-model ICP and the tracking model
  MotionModelOptions motion;       // prediction and the motion check
  RelocaliserOptions relocaliser;  // finding the model again, and the re-entry standard
  KeyframeGraphOptions keyframes;  // keyframes, pose-graph edges, loop closures
  SegmentOptions segments;         // segments apart and their joins
  LoopCorrectionOptions loop_correction;
  void Check() const;  // throws std::invalid_argument
};

class Tracker {
 public:
  // camera: intrinsics of the organised views (their H×W). Throws for invalid options.
  Tracker(const PinholeBrownConrady& camera, const TrackerOptions& options = {});
  ~Tracker();

  // Called once per accepted view (not the first), with its pose, before the view enters the model:
  // it may add points to the view, writing into the same buffers as the points, normals and quality
  // given to Track (e.g. surfaces the model confirms: pipeline/chain/model_anchor.h), and returns
  // true if it did. Track then runs ICP again from that pose with all the points (when they grew by
  // OdometryOptions::reregister_min_gain) and takes the new pose if that ICP is ok and a consistent
  // motion. A view with too few points for ICP, right after an accepted one while tracking, is
  // offered to it once at the motion prediction instead (then not again after its ICP). "Right
  // after": at most one view refused in between.
  using ViewAugmenter = std::function<bool(const Rigid3d& world_from_cam, const PointMap& model)>;

  // points, normals: H×W CV_32FC3 camera frame (mm, NaN = none); quality H×W CV_32F or empty;
  // texture H×W CV_8U or empty (then relocalisation uses range features only).
  // capture_ns: the view's capture time (ns, any epoch), used with
  // TrackerOptions::motion.view_period_ns.
  TrackResult Track(const cv::Mat& points, const cv::Mat& normals, const cv::Mat& quality,
                    const cv::Mat& texture, const ViewAugmenter& augment = {},
                    int64_t capture_ns = 0);

  TrackingState state() const { return state_; }
  // With KeyframeGraphOptions::feature_timing kWorker or kOnDemand, a keyframe's features may still
  // be pending (empty) here.
  const std::vector<Keyframe>& keyframes() const { return keyframe_graph_.keyframes(); }
  int64_t keyframe_bytes() const {
    return keyframe_graph_.bytes();
  }  // the keyframes' Keyframe::bytes(), summed
  int keyframes_reused() const {
    return keyframe_graph_.reused();
  }  // times an older keyframe became current again
  int current_keyframe() const {
    return keyframe_graph_.current();
  }  // the keyframe views anchor to now (−1: none yet)
  const PoseGraph& graph() const { return keyframe_graph_.graph(); }
  int64_t views() const { return static_cast<int64_t>(anchor_.size()); }
  const PointMap& model() const {
    return odometry_.model();
  }  // without a pending insert (see CommitView)
  // Runs the model insert Track() left pending (OdometryOptions::defer_model_insert); nothing when
  // none is. Returns its time (ms).
  double CommitView() { return odometry_.Commit(); }
  bool insert_pending() const { return odometry_.insert_pending(); }

  // Optimises the pose graph (loop closures) and returns the summary.
  [[nodiscard]] Status Optimize(const PoseGraphOptions& options, PoseGraphSummary* summary);

  // The first view UndoFrom can take back: the model's undo journal (odometry.map.undo_inserts)
  // reaches back to it. views() when it reaches no view (no journal).
  int64_t first_undoable_view() const;
  struct UndoResult {
    bool ok = false;
    std::string reason;        // why not (ok = false)
    int64_t views_undone = 0;  // accepted views taken back
    int keyframes_undone = 0;
  };
  // Takes back views first_view … views() − 1, before Optimize (after it the graph's poses are no
  // longer the tracked ones): each becomes a refused view (ViewPose false); the tracking model
  // loses their samples (the running means they updated get their old values back), the keyframes
  // made from them go with their pose-graph nodes and every edge touching those, and the motion
  // model, residual history and map gate restart from the last view kept. The next view is then
  // searched as after a loss (state kLost: local search, features, confirmed re-entry), or starts a
  // new model (kInitialising) when no accepted view is left. View indices go on counting. Not ok
  // (nothing changed) when first_view < first_undoable_view() or first_view > views().
  UndoResult UndoFrom(int64_t first_view);
  // Pose of view i after Optimize (its tracked pose before): false if the view was refused.
  bool ViewPose(int64_t view, Rigid3d* world_from_cam) const;
  int loop_edges() const { return keyframe_graph_.loop_edges(); }
  // Loop corrections made during the scan (LoopCorrectionOptions) and the largest keyframe shift
  // of any of them (mm).
  int loop_corrections() const { return loop_corrections_; }
  double max_loop_shift_mm() const { return max_loop_shift_mm_; }
  int loop_optimisations() const { return loop_optimisations_; }     // pose-graph solves they ran
  double ms_loop_correction() const { return ms_loop_correction_; }  // their time, checks included
  // Segments (TrackerOptions::segments): how many, whether segment s lies in the main frame (the
  // first, or joined to it), and the segment of view i (−1: refused).
  int segments() const { return segments_.size(); }
  int segments_joined() const { return segments_.joined(); }
  bool SegmentInMain(int segment) const { return segments_.InMain(segment); }
  int ViewSegment(int64_t view) const;
  // Segment s's frame moved back to the main frame's origin (a translation: not a registration, the
  // two stay unrelated); identity for the main one.
  Rigid3d MainFromSegmentFrame(int segment) const {
    return segments_.MainFromSegmentFrame(segment);
  }
  // A last join attempt for every segment not joined yet (at the end of a scan, before Optimize),
  // wider than during the scan (SegmentOptions::join_starts_at_end): returns how many joined;
  // *attempts (optional) gets one line per segment tried: "segment S: " and what the attempt found.
  // A segment that joins brings new ground into the main model: the others still apart are tried
  // again ("segment S, again: "), until a round joins none.
  int JoinApartSegments(std::vector<std::string>* attempts = nullptr);
  // Takes back what the last view did to the tracking state when it was refused right after the
  // track was held (kTracking or kRelocalised): the state, the refused-in-a-row count, the count of
  // views without points and any re-entry candidate are put back as before it; the view stays
  // refused. A view from the gap before it (a live host's dropped burst: host/app/gap_bridge.h) is
  // then tracked from the prediction, as it would have been had it come first, instead of searched
  // as a re-entry. False (nothing changed) when the last view was not such a refusal, or after the
  // next Track or an UndoFrom.
  bool RetractLoss();
  // Puts a retracted loss back (the bridge found nothing to place): the tracker is lost as the
  // refused view had left it, unless a view was placed since or it is lost again already. False
  // when there is no retracted loss.
  bool ReinstateLoss();

 private:
  // The views since the last placed one, this one included, are more than
  // RelocaliserOptions::direct_max_views and all but this one had too few points (counted as they
  // came, whatever their capture times: a live host's dropped bursts are no such views). The view
  // is then a re-entry (local search, re-entry standard, confirmation), not tracked from the
  // prediction, which a lifted probe leaves seconds behind (docs/decisions/0010).
  bool BackFromNoPoints() const;
  // Coasts the view (OdometryOptions::max_coast_views) when its ICP from `prediction` allows it:
  // true and *out filled (refused, the state kept), false when it does not apply.
  bool Coast(const SurfacePoints& samples, const cv::Mat& points, const cv::Mat& normals,
             const Rigid3d& prediction, TrackResult* out);
  // The loop correction of a new keyframe (LoopCorrectionOptions), when it is due; *out gets the
  // shift (TrackResult::loop_shift_mm).
  void CorrectOnLoop(TrackResult* out);
  // Starts a new segment with this view (accepted at *pose, in the segment's frame).
  void StartSegment(Rigid3d* pose, TrackResult* out);
  // Tries to join segment s to the main model; true when it did (then merged). *why: what it
  // found, and its time. *main_from_segment (optional): the join's transform, when it joined.
  // at_end: the end of the scan's wider try (SegmentOptions::join_starts_at_end).
  bool TryJoinSegment(int s, std::string* why, Rigid3d* main_from_segment = nullptr,
                      bool at_end = false);
  bool JoinSegmentNow(int s, bool at_end, std::string* why,
                      Rigid3d* main_from_segment);  // the same, untimed

  PinholeBrownConrady camera_;
  TrackerOptions o_;
  // The parts, in construction order (each refers to those before it).
  Odometry odometry_;
  MotionModel motion_;  // the last placed poses: prediction, motion check
  KeyframeGraph keyframe_graph_;
  Segments segments_;
  Relocaliser relocaliser_;
  TrackingState state_ = TrackingState::kInitialising;
  int64_t index_ = -1;  // current view index
  int loop_corrections_ = 0, loop_optimisations_ = 0;
  double max_loop_shift_mm_ = 0, ms_loop_correction_ = 0;
  int last_check_keyframes_ = 0;  // keyframes there were at the last loop check
  int views_without_points_ = 0;  // views with too few points since the last placed view
  // The last view's loss, for RetractLoss: whether it may be taken back, and the state and
  // refused-in-a-row count before it.
  struct Retractable {
    bool valid = false;
    TrackingState state = TrackingState::kInitialising;
    int refused_in_row = 0;
    int views_without_points = 0;
  };
  Retractable retractable_;
  // After RetractLoss: the refused-in-a-row count the loss had left, and the last placed view then
  // (ReinstateLoss applies while it is still the last).
  bool retracted_ = false;
  int retracted_refused_in_row_ = 0;
  int64_t retracted_last_view_ = -1;
  // Track()'s samples of the view (for ICP; more_samples_ after augmentation), refilled every view
  // with their buffers reused.
  SurfacePoints view_samples_, more_samples_;
  // Per view: anchor keyframe (−1 = refused) and keyframe_from_cam.
  std::vector<int> anchor_;
  std::vector<Rigid3d> kf_from_cam_;
  // Per view, what UndoFrom needs to replay the state the kept views left: the model's Insert count
  // at its start, and for an accepted view its pose, capture time, residual pushed to the map gate
  // (< 0: none), whether it entered the model, whether it was a re-entry, and the view that made
  // its keyframe current (the keyframe itself is anchor_'s), and the pose graph's edges and the
  // deferred ones at its start (a keyframe reuse adds an edge between two older keyframes).
  struct ViewLog {
    int64_t map_inserts_before = 0;
    size_t edges_before = 0, deferred_edges_before = 0;
    int64_t current_since = -1;
    int64_t capture_ns = 0;
    int refused_in_row_before =
        0;  // Segments::refused_in_row() when the view came (UndoFrom restores it)
    double rmse_pushed_mm = -1;
    bool in_model = false;
    bool motion_restart = false;  // no velocity across it: a re-entry or a segment's first view
    bool coasted = false;         // refused but carried the motion model (max_coast_views)
    Rigid3d pose = Rigid3d::Identity();
  };
  std::vector<ViewLog> view_log_;
};

}  // namespace d3d
