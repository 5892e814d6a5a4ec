#include "pipeline/register/tracker.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <utility>

#include "common/core/status.h"

namespace d3d {

const char* TrackingStateName(TrackingState s) {
  switch (s) {
    case TrackingState::kInitialising:
      return "initialising";
    case TrackingState::kTracking:
      return "tracking";
    case TrackingState::kLost:
      return "lost";
    case TrackingState::kRelocalised:
      return "relocalised";
  }
  return "?";
}

void LoopCorrectionOptions::Check() const {
  D3D_CHECK_MSG(min_shift_mm >= 0, "LoopCorrectionOptions: min_shift_mm must be >= 0");
  D3D_CHECK_MSG(every_keyframes >= 1, "LoopCorrectionOptions: every_keyframes must be >= 1");
  D3D_CHECK_MSG(check_candidates >= 1, "LoopCorrectionOptions: check_candidates must be >= 1");
  graph.Check();
}

void TrackerOptions::Check() const {
  loop_correction.Check();
  odometry.Check();
  motion.Check();
  relocaliser.Check();
  keyframes.Check();
  segments.Check();
}

Tracker::Tracker(const PinholeBrownConrady& camera, const TrackerOptions& options)
    : camera_(camera),
      o_(options),
      odometry_(camera, options.odometry),
      motion_(options.motion),
      keyframe_graph_(options.keyframes, options.odometry.icp, options.relocaliser.by_features),
      segments_(options.segments, &odometry_, &keyframe_graph_, options.relocaliser.by_features),
      relocaliser_(camera, options.relocaliser, &odometry_, &motion_, &keyframe_graph_,
                   &segments_) {
  camera_.Check();
  o_.Check();
}

Tracker::~Tracker() = default;

namespace {
double Ms(std::chrono::steady_clock::time_point a) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - a).count();
}
}  // namespace

TrackResult Tracker::Track(const cv::Mat& points, const cv::Mat& normals, const cv::Mat& quality,
                           const cv::Mat& texture, const ViewAugmenter& augment,
                           int64_t capture_ns) {
  CommitView();
  const auto t0 = std::chrono::steady_clock::now();
  bool joined_now = false;
  std::string join_attempt;
  Rigid3d main_from_display = Rigid3d::Identity();
  if (segments_.JoinDue()) {
    const int active = segments_.active();
    const Rigid3d display_from_segment = segments_.MainFromSegmentFrame(active);
    Rigid3d main_from_segment;
    joined_now = TryJoinSegment(active, &join_attempt, &main_from_segment);
    if (joined_now) main_from_display = main_from_segment * display_from_segment.inverse();
  }
  const Retractable before{true, state_, segments_.refused_in_row(), views_without_points_};
  const bool held_before =
      state_ == TrackingState::kTracking || state_ == TrackingState::kRelocalised;
  retractable_ = Retractable{};
  ++index_;
  motion_.BeginView(index_, capture_ns);
  anchor_.push_back(-1);
  kf_from_cam_.push_back(Rigid3d::Identity());
  view_log_.emplace_back();
  view_log_.back().map_inserts_before = odometry_.model().inserts();
  view_log_.back().edges_before = keyframe_graph_.edges();
  view_log_.back().deferred_edges_before = keyframe_graph_.deferred_edges();
  view_log_.back().capture_ns = capture_ns;
  view_log_.back().refused_in_row_before = segments_.refused_in_row();
  TrackResult out;
  const OdometryOptions& odo = o_.odometry;
  SurfacePoints& samples = view_samples_;
  SampleOrganised(points, normals, quality, odo.sample_stride, &samples);
  bool augmented = false;
  if (samples.size() < static_cast<size_t>(odo.min_view_samples) && augment &&
      !odometry_.model().empty() && state_ == TrackingState::kTracking &&
      index_ - motion_.last_view() <= 2) {
    // Too little of the view was anchored by its own burst (teeth without a readable marker): while
    // tracking from the view just before, the motion prediction is close enough for the augmenter
    // to try the model there.
    if (augment(motion_.Predict(), odometry_.model())) {
      SampleOrganised(points, normals, quality, odo.sample_stride, &samples);
      augmented = true;
    }
  }
  if (samples.size() < static_cast<size_t>(odo.min_view_samples)) {
    // Nothing to register (probe lifted, out of the measurement volume): refused, but the
    // tracking state is kept; the motion model restarts with the next view.
    out.state = state_;
    out.reason = "too few points in the view (" + std::to_string(samples.size()) + ")";
    out.too_few_points = true;
    ++views_without_points_;
    if (held_before) retractable_ = before;
    out.ms = Ms(t0);
    return out;
  }
  const bool lost = state_ == TrackingState::kLost;
  // A gap for the relocaliser: lost, or back after views with nothing to register.
  const bool back = BackFromNoPoints();
  const bool gap = lost || back;
  bool accepted = false;
  Rigid3d pose = motion_.last_pose();
  if (odometry_.model().empty()) {
    accepted = true;
    pose = Rigid3d::Identity();
    out.state = TrackingState::kTracking;
  } else if (!lost && back) {
    // The probe comes back after a stretch with nothing to register (lifted, out of range): a
    // re-entry, wherever the last pose predicts it; the local search and confirmation below.
    out.reason = "back after " + std::to_string(views_without_points_) + " views without points";
  } else if (!lost) {
    const Rigid3d pred = motion_.Predict();
    out.icp = odometry_.Register(samples, pred, odo.icp);
    if (!out.icp.ok) {
      out.reason = "icp: " + out.icp.reason;
      if (Coast(samples, points, normals, pred, &out)) {
        out.ms = Ms(t0);
        return out;
      }
    } else if (motion_.Consistent(out.icp.target_from_source, &out.reason)) {
      std::string why;
      if (relocaliser_.JumpsFromPrediction(out.icp.target_from_source) &&
          !relocaliser_.MeetsJumpStandard(samples, out.icp, gap, &why)) {
        out.reason = "icp jumped from the prediction: " + why;  // the local search tries it again
      } else {
        accepted = true;
        pose = out.icp.target_from_source;
        out.state = TrackingState::kTracking;
      }
    }
  } else {
    out.reason = "lost";
    if (relocaliser_.candidate().pending) {
      // The view after a re-entry candidate: it confirms it, or the candidate is dropped.
      const std::string how = relocaliser_.candidate().how;
      const int64_t at = relocaliser_.candidate().view;
      if (relocaliser_.Confirm(samples, gap, &out)) {
        accepted = true;
        pose = out.world_from_cam;
        out.state = TrackingState::kRelocalised;
        out.reason = "lost; relocalised: re-entry of view " + std::to_string(at) + " (" + how +
                     ") confirmed";
      } else {
        out.reason =
            "lost; re-entry of view " + std::to_string(at) + " not confirmed: " + out.reason;
      }
    }
  }
  // A view re-entering the model after a loss waits for the next view's confirmation (see
  // RelocaliserOptions::confirm_reentry); one refused while tracking is recovered at once.
  bool needs_confirmation = o_.relocaliser.confirm_reentry && relocaliser_.AfterGap(gap);
  auto reentered = [&](const std::string& why) {
    if (needs_confirmation) {
      relocaliser_.SetCandidate(index_, motion_.capture_ns(), out.world_from_cam, out.reason);
      out.reason =
          why + "; re-entry candidate (" + out.reason + "), to be confirmed by the next view";
      return false;
    }
    pose = out.world_from_cam;
    out.state = TrackingState::kRelocalised;
    out.reason = why + "; relocalised: " + out.reason;
    return true;
  };
  if (!accepted && !relocaliser_.candidate().pending && !keyframe_graph_.empty()) {
    // Local search first: ICP from the last accepted pose and from the keyframes nearest to it
    // (the probe usually comes back where it left the model).
    const std::string why = out.reason;
    bool from_prediction = false;
    if (relocaliser_.SearchLocally(samples, gap, &out, &from_prediction)) {
      // One bad view in a track that never left: no confirmation (direct_max_views).
      if (from_prediction && motion_.ViewsElapsed() <= o_.relocaliser.direct_max_views)
        needs_confirmation = false;
      accepted = reentered(why);
    } else {
      out.reason = why + "; local search failed: " + out.reason;
    }
  }
  if (!accepted && !relocaliser_.candidate().pending && o_.relocaliser.by_features &&
      !keyframe_graph_.empty()) {
    const std::string why = out.reason;
    if (relocaliser_.SearchByFeatures(samples, points, texture, gap, &out))
      accepted = reentered(why);
    else
      out.reason = why + "; relocalisation failed: " + out.reason;
  }
  if (!accepted && state_ != TrackingState::kInitialising && segments_.CountRefused()) {
    StartSegment(&pose, &out);  // the view cannot be placed: it starts a segment of its own
    accepted = true;
  }
  if (!accepted) {
    if (held_before && !joined_now) retractable_ = before;
    state_ = state_ == TrackingState::kInitialising ? state_ : TrackingState::kLost;
    out.state = state_;
    out.segment_joined = joined_now;
    out.main_from_display = main_from_display;
    out.join_attempt = join_attempt;
    out.ms = Ms(t0);
    return out;
  }
  segments_.set_refused_in_row(0);
  views_without_points_ = 0;
  odometry_.set_coast_run(0);
  if (augment && !odometry_.model().empty() && !augmented && augment(pose, odometry_.model())) {
    // The view gained points: register it again from its pose with all of them, when they are
    // enough to change the fit (a view whose own points were only the smooth palate, say).
    SurfacePoints& more = more_samples_;
    SampleOrganised(points, normals, quality, odo.sample_stride, &more);
    const bool enough = static_cast<double>(more.size()) >=
                        (1.0 + odo.reregister_min_gain) * static_cast<double>(samples.size());
    if (!enough) {
      std::swap(samples, more);  // fused and inserted at the pose found without them
    } else {
      IcpOptions fine = odo.icp;
      fine.levels.erase(fine.levels.begin(), fine.levels.begin() + odo.reregister_first_level);
      IcpResult again = odometry_.Register(more, pose, fine);
      if (again.ok && motion_.Consistent(again.target_from_source, nullptr)) {
        pose = again.target_from_source;
        out.icp = again;
        std::swap(samples, more);
      }
    }
  }
  out.accepted = true;
  out.world_from_cam = pose;
  if (out.state == TrackingState::kTracking && state_ == TrackingState::kTracking &&
      motion_.HasVelocity()) {
    const Rigid3d pred = motion_.Predict();
    out.prediction_offset_mm = TranslationDistanceMm(pose, pred);
    out.prediction_offset_deg = RotationAngleRad(pose, pred) * 180 / M_PI;
  }
  state_ = out.state;
  // No velocity across a re-entry, nor from the last pose of the segment before into a new
  // segment's frame (2 m apart: the next view's prediction would extrapolate that).
  const bool motion_restart = out.state == TrackingState::kRelocalised || out.new_segment;
  motion_.Advance(pose, motion_restart);
  // Into the tracking model unless its residual stands out from the recent views' (the map gate).
  ViewLog& log = view_log_.back();
  out.in_model = odometry_.AdmitToModel(out.icp, &log.rmse_pushed_mm);
  log.in_model = out.in_model;
  log.motion_restart = motion_restart;
  log.pose = pose;
  keyframe_graph_.Update(points, normals, texture, pose, index_, segments_.active(),
                         &out);  // does not read the model
  // Tagged with the keyframe the view anchors to: a loop correction moves its samples with it.
  if (out.in_model) odometry_.Insert(points, normals, pose, keyframe_graph_.current());
  log.current_since = keyframe_graph_.current_since();
  anchor_.back() = keyframe_graph_.current();
  kf_from_cam_.back() =
      keyframe_graph_.world_from_keyframe(keyframe_graph_.current()).inverse() * pose;
  if (o_.loop_correction.enabled && out.new_keyframe) CorrectOnLoop(&out);
  if (out.loop_corrected)
    out.world_from_cam = keyframe_graph_.world_from_keyframe(anchor_.back()) * kf_from_cam_.back();
  out.segment = segments_.active();
  out.in_main = segments_.InMain(segments_.active());
  out.segment_joined = joined_now;
  out.main_from_display = main_from_display;
  out.display_from_cam = segments_.MainFromSegmentFrame(segments_.active()) * out.world_from_cam;
  out.join_attempt = join_attempt;
  out.ms = Ms(t0);
  return out;
}

bool Tracker::Coast(const SurfacePoints& samples, const cv::Mat& points, const cv::Mat& normals,
                    const Rigid3d& prediction, TrackResult* out) {
  if (state_ == TrackingState::kInitialising ||
      motion_.ViewsElapsed() > o_.relocaliser.direct_max_views)
    return false;
  IcpResult fit;
  if (!odometry_.Coast(samples, out->icp, prediction, motion_, &fit)) return false;
  const Rigid3d pose = fit.target_from_source;
  out->icp = fit;
  motion_.Advance(pose, false);
  ViewLog& log = view_log_.back();
  log.coasted = true;
  log.pose = pose;
  // Into the tracking model (not the fused one): the next view overlaps the stretch it slides
  // along.
  odometry_.Insert(points, normals, pose, keyframe_graph_.current());
  out->state = state_;
  out->reason += "; coasting: tracked along its constrained directions, not fused (" +
                 std::to_string(odometry_.coast_run()) + " of " +
                 std::to_string(o_.odometry.max_coast_views) + " in a row)";
  return true;
}

void Tracker::CorrectOnLoop(TrackResult* out) {
  const LoopCorrectionOptions& lc = o_.loop_correction;
  const int n = keyframe_graph_.size();
  if (n - last_check_keyframes_ < lc.every_keyframes) return;
  // Every segment in the main frame: a segment apart keeps the main model it set out to join.
  if (segments_.joined() + 1 < segments_.size()) return;
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<PoseGraphEdge> loops;
  int tested = 0;
  const double drift_mm =
      keyframe_graph_.LoopDiscrepancyMm(n - 1, lc.check_candidates, &loops, &tested);
  ms_loop_correction_ += Ms(t0);
  if (tested == 0) return;  // no loop candidate: nothing ran, the next keyframe may check
  last_check_keyframes_ = n;
  if (drift_mm < 0) return;  // none overlaps, or the ICP failed
  if (drift_mm <= lc.min_shift_mm) return;
  ++loop_optimisations_;
  std::vector<Rigid3d> before(static_cast<size_t>(n));
  for (int k = 0; k < n; ++k)
    before[static_cast<size_t>(k)] = keyframe_graph_.world_from_keyframe(k);
  const auto t1 = std::chrono::steady_clock::now();
  PoseGraphSummary summary;
  const bool solved = keyframe_graph_.OptimizeNow(lc.graph, loops, &summary).ok();
  ms_loop_correction_ += Ms(t1);
  if (!solved) return;
  std::vector<Rigid3d> new_from_old(static_cast<size_t>(n));
  double shift = 0;
  for (int k = 0; k < n; ++k) {
    const size_t i = static_cast<size_t>(k);
    new_from_old[i] = keyframe_graph_.world_from_keyframe(k) * before[i].inverse();
    const Eigen::Vector3d c = before[i] * keyframe_graph_.keyframes()[i].centre_in_cam;
    shift = std::max(shift, (new_from_old[i] * c - c).norm());
  }
  out->loop_shift_mm = shift;
  if (shift <= lc.min_shift_mm) {
    // Too small to move the model: the graph keeps the poses the model was built at.
    for (int k = 0; k < n; ++k) keyframe_graph_.SetPose(k, before[static_cast<size_t>(k)]);
    return;
  }
  const auto t2 = std::chrono::steady_clock::now();
  odometry_.MoveModel(new_from_old);
  const int current = keyframe_graph_.current();
  motion_.MoveFrame(new_from_old[static_cast<size_t>(current)]);
  // The logged poses (UndoFrom's replay) in the corrected frame; the moved model has no undo
  // journal, so no view before this one can be undone.
  // (A coasted view has no anchor: it moves with the current keyframe.)
  for (size_t v = 0; v < view_log_.size(); ++v) {
    const int a = anchor_[v] >= 0 ? anchor_[v] : view_log_[v].coasted ? current : -1;
    if (a >= 0) view_log_[v].pose = new_from_old[static_cast<size_t>(a)] * view_log_[v].pose;
  }
  relocaliser_.DropCandidate();
  ++loop_corrections_;
  max_loop_shift_mm_ = std::max(max_loop_shift_mm_, shift);
  out->loop_corrected = true;
  ms_loop_correction_ += Ms(t2);
}

void Tracker::StartSegment(Rigid3d* pose, TrackResult* out) {
  segments_.Start(index_, motion_.last_pose(), pose, out);
  // The new segment starts its own chain: no keyframe to anchor to, no motion to predict from, no
  // candidate re-entry, its own residual history; undo does not reach back before it.
  keyframe_graph_.ForgetCurrent();
  relocaliser_.DropCandidate();
  motion_.ForgetVelocity();
  odometry_.ForgetResiduals();
}

bool Tracker::TryJoinSegment(int s, std::string* why, Rigid3d* main_from_segment, bool at_end) {
  const auto t0 = std::chrono::steady_clock::now();
  Rigid3d t;
  const bool joined = JoinSegmentNow(s, at_end, why, &t);
  if (joined && main_from_segment != nullptr) *main_from_segment = t;
  char ms[32];
  std::snprintf(ms, sizeof ms, " (%.0f ms)", Ms(t0));
  *why += ms;
  return joined;
}

bool Tracker::JoinSegmentNow(int s, bool at_end, std::string* why, Rigid3d* main_from_segment) {
  SegmentJoinResult r;
  int anchor = -1;
  std::string how;
  if (!segments_.FindJoin(s, at_end, &r, &anchor, &how, why)) return false;
  const Rigid3d& T = r.main_from_segment;
  *main_from_segment = T;
  // Verified like a re-entry: the keyframe the join rests on, and the segment's newest, at their
  // joined poses do not contradict what the main keyframes near them saw.
  const std::vector<Keyframe>& kfs = keyframe_graph_.keyframes();
  const int newest = segments_.NewestKeyframe(s);
  std::vector<int> checked = {anchor};
  if (newest != anchor) checked.push_back(newest);
  for (const int k : checked) {
    const ReentryEvidence evidence = relocaliser_.CheckReentry(
        kfs[static_cast<size_t>(k)].samples, T * keyframe_graph_.world_from_keyframe(k));
    if (!evidence.ok) {
      *why = "join: " + evidence.reason;
      return false;
    }
  }
  // Merge: the segment's keyframes, model samples (segments.h), views' logged poses and motion
  // state into the main frame.
  for (int64_t v = 0; v < views(); ++v)
    if (ViewSegment(v) == s)
      view_log_[static_cast<size_t>(v)].pose = T * view_log_[static_cast<size_t>(v)].pose;
  segments_.Merge(s, T, anchor, index_);
  if (segments_.active() == s) {
    motion_.MoveFrame(T);
    relocaliser_.DropCandidate();
  }
  // The rebuilt model has no undo journal: undo starts again from here.
  for (ViewLog& log : view_log_) log.map_inserts_before = 0;
  *why = "joined by " + how + ": " + std::to_string(r.icp.correspondences) + " samples, rmse " +
         std::to_string(r.icp.rmse_mm * 1000) + " um";
  return true;
}

bool Tracker::RetractLoss() {
  if (!retractable_.valid) return false;
  retracted_ = true;
  retracted_refused_in_row_ = segments_.refused_in_row();
  retracted_last_view_ = motion_.last_view();
  state_ = retractable_.state;
  segments_.set_refused_in_row(retractable_.refused_in_row);
  views_without_points_ = retractable_.views_without_points;
  relocaliser_.DropCandidate();
  retractable_ = Retractable{};
  return true;
}

bool Tracker::ReinstateLoss() {
  if (!retracted_) return false;
  retracted_ = false;
  if (motion_.last_view() != retracted_last_view_ || state_ == TrackingState::kLost) return true;
  state_ = TrackingState::kLost;
  segments_.set_refused_in_row(std::max(segments_.refused_in_row(), retracted_refused_in_row_));
  return true;
}

int Tracker::ViewSegment(int64_t view) const {
  if (view < 0 || view >= views() || anchor_[static_cast<size_t>(view)] < 0) return -1;
  return keyframes()[static_cast<size_t>(anchor_[static_cast<size_t>(view)])].segment;
}

int Tracker::JoinApartSegments(std::vector<std::string>* attempts) {
  CommitView();
  int joined = 0;
  bool model_changed = true;  // since the join features were made (a join rebuilds the model)
  for (int round = 0, joined_in_round = 1; joined_in_round > 0; ++round) {
    joined_in_round = 0;
    for (int seg = 1; seg < segments_.size(); ++seg) {
      if (segments_.InMain(seg)) continue;
      if (model_changed) segments_.RefreshJoinTarget();  // the main model as it is now
      std::string why;
      model_changed = TryJoinSegment(seg, &why, nullptr, true);
      joined_in_round += model_changed;
      if (attempts != nullptr)
        attempts->push_back("segment " + std::to_string(seg) + (round > 0 ? ", again: " : ": ") +
                            why);
    }
    joined += joined_in_round;
  }
  return joined;
}

Status Tracker::Optimize(const PoseGraphOptions& options, PoseGraphSummary* summary) {
  return keyframe_graph_.Optimize(options, summary);
}

int64_t Tracker::first_undoable_view() const {
  // Views' Insert counts do not decrease: the first view whose model state the journal still has.
  const int64_t oldest = odometry_.model().oldest_undoable_insert();
  const auto it =
      std::lower_bound(view_log_.begin(), view_log_.end(), oldest,
                       [](const ViewLog& v, int64_t n) { return v.map_inserts_before < n; });
  return std::max(segments_.undo_barrier_view(), static_cast<int64_t>(it - view_log_.begin()));
}

bool Tracker::BackFromNoPoints() const {
  return views_without_points_ > 0 && views_without_points_ + 1 > o_.relocaliser.direct_max_views;
}

Tracker::UndoResult Tracker::UndoFrom(int64_t first_view) {
  CommitView();
  UndoResult r;
  if (first_view > views() || first_view < first_undoable_view()) {
    r.reason = "view " + std::to_string(first_view) + " is outside what can be undone (views " +
               std::to_string(first_undoable_view()) + " to " + std::to_string(views()) + ")";
    return r;
  }
  const size_t f = static_cast<size_t>(first_view);
  const bool logged = f < view_log_.size();
  if (logged) {
    const bool rolled_back = odometry_.RollBackTo(view_log_[f].map_inserts_before);
    D3D_CHECK_MSG(rolled_back,
                  "Tracker::UndoFrom: the model's journal does not reach view " << first_view);
  }
  for (size_t v = f; v < anchor_.size(); ++v) {
    r.views_undone += anchor_[v] >= 0;
    anchor_[v] = -1;
  }
  r.keyframes_undone =
      keyframe_graph_.DropFrom(first_view, logged, logged ? view_log_[f].edges_before : 0,
                               logged ? view_log_[f].deferred_edges_before : 0);
  // The current keyframe as the last kept accepted view left it (the one it anchored to).
  int current = -1;
  int64_t since = -1;
  for (size_t v = f; v-- > 0;)
    if (anchor_[v] >= 0) {
      current = anchor_[v];
      since = view_log_[v].current_since;
      break;
    }
  keyframe_graph_.SetCurrent(current, since);
  // The motion state, residual history and map gate as the kept views left them (replayed in
  // order).
  odometry_.ForgetResiduals();
  motion_.Reset();
  int coast_run = 0;
  for (size_t v = 0; v < f; ++v) {
    const ViewLog& log = view_log_[v];
    if (log.coasted) {
      motion_.AdvanceAt(static_cast<int64_t>(v), log.pose, log.capture_ns, false);
      ++coast_run;
      continue;
    }
    if (anchor_[v] < 0) continue;
    if (segments_.StartsAt(static_cast<int64_t>(v))) odometry_.ForgetResiduals();
    coast_run = 0;
    odometry_.ReplayAdmission(log.rmse_pushed_mm, log.in_model);
    motion_.AdvanceAt(static_cast<int64_t>(v), log.pose, log.capture_ns, log.motion_restart);
  }
  odometry_.set_coast_run(coast_run);
  relocaliser_.DropCandidate();
  retractable_ = Retractable{};  // the last view's loss is no longer the state's to take back
  retracted_ = false;
  // The views refused in a row before first_view count toward a new segment; the undone ones do
  // not.
  if (logged) segments_.set_refused_in_row(view_log_[f].refused_in_row_before);
  views_without_points_ = 0;  // the next view is searched as after a loss (state kLost) anyway
  state_ = motion_.last_view() < 0 ? TrackingState::kInitialising : TrackingState::kLost;
  if (motion_.last_view() < 0)
    D3D_CHECK_MSG(odometry_.model().empty(),
                  "Tracker::UndoFrom: no view left but the model is not empty");
  r.ok = true;
  return r;
}

bool Tracker::ViewPose(int64_t view, Rigid3d* world_from_cam) const {
  if (view < 0 || view >= views() || anchor_[static_cast<size_t>(view)] < 0) return false;
  *world_from_cam = keyframe_graph_.world_from_keyframe(anchor_[static_cast<size_t>(view)]) *
                    kf_from_cam_[static_cast<size_t>(view)];
  return true;
}

}  // namespace d3d
