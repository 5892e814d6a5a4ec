#include "pipeline/register/tracker.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <thread>
#include <utility>

#include "common/core/status.h"

namespace d3d {

const char* TrackingStateName(TrackingState s) {
  switch (s) {
    case TrackingState::kInitialising: return "initialising";
    case TrackingState::kTracking: return "tracking";
    case TrackingState::kLost: return "lost";
    case TrackingState::kRelocalised: return "relocalised";
  }
  return "?";
}

const char* AssociationName(Association a) {
  switch (a) {
    case Association::kProjective: return "projective";
    case Association::kKdTree: return "kdtree";
    case Association::kGrid: return "grid";
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
  // Coarse levels pure point-to-plane and ended at a few micrometres (see tracker.h).
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

FeatureOptions HalfScaleFeatures() {
  FeatureOptions o;
  o.image_scale = 0.5;
  return o;
}

void TrackerOptions::Check() const {
  icp.Check();
  map.Check();
  features.Check();
  D3D_CHECK_MSG(grid_decimate_min_gate_mm >= 0, "TrackerOptions: grid_decimate_min_gate_mm >= 0 (0 = off)");
  D3D_CHECK_MSG(sample_stride >= 1 && map_stride >= 1 && keyframe_stride >= 1, "TrackerOptions: strides >= 1");
  D3D_CHECK_MSG(target_scale > 0 && target_scale <= 2 && target_splat >= 0 && target_window >= 0, "TrackerOptions: target");
  motion.Check();
  D3D_CHECK_MSG(keyframe_overlap > 0 && keyframe_overlap <= 1, "TrackerOptions: keyframe_overlap in (0, 1]");
  D3D_CHECK_MSG(keyframe_max_rotation_deg >= 0 && keyframe_max_views >= 0,
                "TrackerOptions: keyframe_max_rotation_deg and keyframe_max_views >= 0 (0 = off)");
  D3D_CHECK_MSG(max_coast_views >= 0, "TrackerOptions: max_coast_views >= 0 (0 = off)");
  D3D_CHECK_MSG(coast_min_eigen_ratio > 0 && coast_min_eigen_ratio < 1, "TrackerOptions: coast_min_eigen_ratio must be in (0, 1)");
  D3D_CHECK_MSG(keyframe_jump_mm >= 0 && keyframe_jump_deg >= 0, "TrackerOptions: keyframe_jump_mm and keyframe_jump_deg >= 0 (0 = off)");
  D3D_CHECK_MSG(keyframe_reuse_radius_mm >= 0 && keyframe_reuse_candidates >= 1,
                "TrackerOptions: keyframe_reuse_radius_mm >= 0 (0 = off) and keyframe_reuse_candidates >= 1");
  D3D_CHECK_MSG(relocalise_candidates >= 1 && loop_min_separation >= 1 && max_loop_candidates >= 0 && near_loop_candidates >= 0,
                "TrackerOptions: counts");
  D3D_CHECK_MSG(edge_information_scale > 0, "TrackerOptions: edge_information_scale > 0");
  D3D_CHECK_MSG(tracked_edge_information_factor >= 0, "TrackerOptions: tracked_edge_information_factor >= 0 (0 = none)");
  D3D_CHECK_MSG(near_loop_information_factor > 0 && near_loop_information_factor <= 1,
                "TrackerOptions: near_loop_information_factor in (0, 1]");
  D3D_CHECK_MSG(reregister_min_gain >= 0, "TrackerOptions: reregister_min_gain >= 0");
  D3D_CHECK_MSG(reregister_first_level >= 0 && reregister_first_level < static_cast<int>(icp.levels.size()),
                "TrackerOptions: reregister_first_level must index icp.levels");
  D3D_CHECK_MSG(reentry_direct_max_views >= 0, "TrackerOptions: reentry_direct_max_views >= 0");
  D3D_CHECK_MSG(reentry_min_eigen_ratio >= 0 && reentry_min_eigen_ratio < 1, "TrackerOptions: reentry_min_eigen_ratio in [0, 1)");
  D3D_CHECK_MSG(reentry_ambiguity_mm >= 0, "TrackerOptions: reentry_ambiguity_mm >= 0 (0 = off)");
  D3D_CHECK_MSG(jump_check_mm >= 0 && jump_check_deg >= 0, "TrackerOptions: jump_check_mm and jump_check_deg >= 0 (0 = off)");
  reentry_check.Check();
  D3D_CHECK_MSG(segment_after_views >= 0 && max_segments >= 1 && segment_join_every >= 1 && segment_join_feature_keyframes >= 0,
                "TrackerOptions: segment_after_views >= 0 (0 = off), max_segments >= 1, segment_join_every >= 1, "
                "segment_join_feature_keyframes >= 0");
  segment_join.Check();
  D3D_CHECK_MSG(map_max_rmse_ratio == 0 || map_max_rmse_ratio >= 1, "TrackerOptions: map_max_rmse_ratio 0 (off) or >= 1");
  D3D_CHECK_MSG(map_gate_min_overlap >= 0 && map_gate_min_overlap <= 1 && map_gate_max_run >= 0,
                "TrackerOptions: map_gate_min_overlap in [0, 1], map_gate_max_run >= 0");
  D3D_CHECK_MSG(odometry_sigma_mm > 0 && odometry_sigma_rad > 0 && loop_sigma_mm > 0 && loop_sigma_rad > 0, "TrackerOptions: sigmas");
}

// Keyframe features on a thread of their own (TrackerOptions::keyframe_feature_timing kWorker). The
// tracker's thread submits a keyframe's points and texture (copied into the job's own buffers) and
// collects the results; the worker touches only the job it took, and its queues under mu_.
class Tracker::FeatureWorker {
 public:
  explicit FeatureWorker(const FeatureOptions& options) : o_(options), thread_([this] { Run(); }) {}
  ~FeatureWorker() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stop_ = true;
    }
    work_cv_.notify_one();
    thread_.join();
  }
  // Copies points and texture into a job's buffers (reused from finished jobs: after the first few
  // keyframes a submission allocates nothing) and queues it.
  void Submit(size_t keyframe, const cv::Mat& points, const cv::Mat& texture) {
    Job job;
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (!spare_.empty()) {
        job = std::move(spare_.back());
        spare_.pop_back();
      }
    }
    job.keyframe = keyframe;
    points.copyTo(job.points);
    texture.copyTo(job.texture);
    {
      std::lock_guard<std::mutex> lock(mu_);
      jobs_.push_back(std::move(job));
      ++pending_;
    }
    work_cv_.notify_one();
  }
  // Waits until every submitted job is done; returns (keyframe, features) of those not yet taken.
  std::vector<std::pair<size_t, ViewFeatures>> WaitAll() {
    std::unique_lock<std::mutex> lock(mu_);
    done_cv_.wait(lock, [this] { return pending_ == 0; });
    return std::exchange(done_, {});
  }

 private:
  struct Job {
    size_t keyframe = 0;
    cv::Mat points, texture;
  };
  void Run() {
    for (;;) {
      Job job;
      {
        std::unique_lock<std::mutex> lock(mu_);
        work_cv_.wait(lock, [this] { return stop_ || !jobs_.empty(); });
        if (jobs_.empty()) return;  // stop_ and nothing left
        job = std::move(jobs_.front());
        jobs_.pop_front();
      }
      ViewFeatures f = ExtractViewFeatures(job.points, job.texture, o_);
      {
        std::lock_guard<std::mutex> lock(mu_);
        done_.emplace_back(job.keyframe, std::move(f));
        spare_.push_back(std::move(job));
        --pending_;
      }
      done_cv_.notify_all();
    }
  }
  const FeatureOptions o_;
  std::mutex mu_;
  std::condition_variable work_cv_, done_cv_;
  std::deque<Job> jobs_;
  std::vector<Job> spare_;  // finished jobs' buffers, for the next submissions
  std::vector<std::pair<size_t, ViewFeatures>> done_;
  size_t pending_ = 0;
  bool stop_ = false;
  std::thread thread_;  // last: started once the members above exist
};

void Tracker::CollectKeyframeFeatures() {
  if (!feature_worker_) return;
  for (auto& [k, f] : feature_worker_->WaitAll()) keyframes_[k].features = std::move(f);
}

Tracker::Tracker(const PinholeBrownConrady& camera, const TrackerOptions& options)
    : camera_(camera), o_(options), reentry_check_(camera, options.reentry_check), map_(options.map), motion_(options.motion) {
  camera_.Check();
  o_.Check();
  pinhole_ = PinholeIntrinsics::Of(camera).Scaled(o_.target_scale);
  if (o_.keyframe_feature_timing == TrackerOptions::FeatureTiming::kWorker && o_.relocalise)
    feature_worker_ = std::make_unique<FeatureWorker>(o_.features);
}

Tracker::~Tracker() = default;

namespace {
// Segment s's frame is the main one moved by s · kSegmentSpacingMm along x: a scan spans ~100 mm
// around the first view, so the segments never meet (the model's voxel keys reach ±80 m).
constexpr double kSegmentSpacingMm = 2000.0;
int SegmentOfPoint(const Eigen::Vector3f& p) { return static_cast<int>(std::lround(p.x() / kSegmentSpacingMm)); }
}  // namespace

IcpResult Tracker::RunIcp(const SurfacePoints& source, const Rigid3d& initial, const IcpOptions& icp) const {
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
  const double shift_x = -kSegmentSpacingMm * std::round(initial.translation().x() / kSegmentSpacingMm);
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

namespace {
double Ms(std::chrono::steady_clock::time_point a) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - a).count();
}

constexpr double kOverlapVoxelMm = 0.1;  // voxel of the overlap index between keyframes

// The occupancy map of samples `b` (their own frame) that OverlapIndex measures against.
std::unique_ptr<PointMap> OccupancyMap(const SurfacePoints& b, double voxel_mm) {
  PointMapOptions o;
  o.voxel_mm = voxel_mm;
  o.block_mm = std::max(2.0, voxel_mm);
  auto m = std::make_unique<PointMap>(o);
  m->Insert(b, Rigid3d::Identity());
  return m;
}

// Fraction of `a` (frame A) that lies in occupied voxels of `b` (frame B) given B_from_A.
double OverlapIndex(const SurfacePoints& a, const SurfacePoints& b, const Rigid3d& b_from_a, double voxel_mm) {
  return OccupancyMap(b, voxel_mm)->Overlap(a, b_from_a);
}

// Multiplies an edge's weight by `factor`: its information matrix, or (an edge on σs) its
// variances by 1/factor.
void ScaleInformation(double factor, PoseGraphEdge* e) {
  e->information *= factor;
  e->sigma_translation_mm /= std::sqrt(factor);
  e->sigma_rotation_rad /= std::sqrt(factor);
}
}  // namespace

TrackResult Tracker::Track(const cv::Mat& points, const cv::Mat& normals, const cv::Mat& quality, const cv::Mat& texture,
                           const ViewAugmenter& augment, int64_t capture_ns) {
  CommitView();
  const auto t0 = std::chrono::steady_clock::now();
  bool joined_now = false;
  std::string join_attempt;
  Rigid3d main_from_display = Rigid3d::Identity();
  if (active_segment_ > 0 && !segments_[static_cast<size_t>(active_segment_)].joined) {
    Segment& seg = segments_[static_cast<size_t>(active_segment_)];
    if (keyframes_.size() >= seg.keyframes_at_attempt + static_cast<size_t>(o_.segment_join_every)) {
      seg.keyframes_at_attempt = keyframes_.size();
      const Rigid3d display_from_segment = MainFromSegmentFrame(active_segment_);
      Rigid3d main_from_segment;
      joined_now = TryJoinSegment(active_segment_, &join_attempt, &main_from_segment);
      if (joined_now) main_from_display = main_from_segment * display_from_segment.inverse();
    }
  }
  ++index_;
  motion_.BeginView(index_, capture_ns);
  anchor_.push_back(-1);
  kf_from_cam_.push_back(Rigid3d::Identity());
  view_log_.emplace_back();
  view_log_.back().map_inserts_before = map_.inserts();
  view_log_.back().edges_before = graph_.edges().size();
  view_log_.back().deferred_edges_before = deferred_edges_.size();
  view_log_.back().capture_ns = capture_ns;
  view_log_.back().lost_with_points_before = lost_with_points_;
  TrackResult out;
  SurfacePoints& samples = view_samples_;
  SampleOrganised(points, normals, quality, o_.sample_stride, &samples);
  bool augmented = false;
  if (samples.size() < static_cast<size_t>(o_.min_view_samples) && augment && !map_.empty() &&
      state_ == TrackingState::kTracking && index_ - motion_.last_view() <= 2) {
    // Too little of the view was anchored by its own burst (teeth without a readable marker): while
    // tracking from the view just before, the motion prediction is close enough for the augmenter
    // to try the model there.
    if (augment(motion_.Predict(), map_)) {
      SampleOrganised(points, normals, quality, o_.sample_stride, &samples);
      augmented = true;
    }
  }
  if (samples.size() < static_cast<size_t>(o_.min_view_samples)) {
    // Nothing to register (probe lifted, out of the measurement volume): refused, but the
    // tracking state is kept; the motion model restarts with the next view.
    out.state = state_;
    out.reason = "too few points in the view (" + std::to_string(samples.size()) + ")";
    out.ms = Ms(t0);
    return out;
  }
  bool accepted = false;
  Rigid3d pose = motion_.last_pose();
  if (map_.empty()) {
    accepted = true;
    pose = Rigid3d::Identity();
    out.state = TrackingState::kTracking;
  } else if (state_ != TrackingState::kLost) {
    const Rigid3d pred = motion_.Predict();
    out.icp = RunIcp(samples, pred, o_.icp);
    if (!out.icp.ok) {
      out.reason = "icp: " + out.icp.reason;
      if (Coast(samples, points, normals, pred, &out)) {
        out.ms = Ms(t0);
        return out;
      }
    } else if (motion_.Consistent(out.icp.target_from_source, &out.reason)) {
      std::string why;
      if (JumpsFromPrediction(out.icp.target_from_source) && !MeetsJumpStandard(samples, out.icp, &why)) {
        out.reason = "icp jumped from the prediction: " + why;  // the local search tries it again
      } else {
        accepted = true;
        pose = out.icp.target_from_source;
        out.state = TrackingState::kTracking;
      }
    }
  } else {
    out.reason = "lost";
    if (candidate_.pending) {
      // The view after a re-entry candidate: it confirms it, or the candidate is dropped.
      const std::string how = candidate_.how;
      const int64_t at = candidate_.view;
      if (ConfirmReentry(samples, &out)) {
        accepted = true;
        pose = out.world_from_cam;
        out.state = TrackingState::kRelocalised;
        out.reason = "lost; relocalised: re-entry of view " + std::to_string(at) + " (" + how + ") confirmed";
      } else {
        out.reason = "lost; re-entry of view " + std::to_string(at) + " not confirmed: " + out.reason;
      }
    }
  }
  // A view re-entering the model after a loss waits for the next view's confirmation (see
  // TrackerOptions::confirm_reentry); one refused while tracking is recovered at once.
  bool needs_confirmation = o_.confirm_reentry && AfterGap();
  auto reentered = [&](const std::string& why) {
    if (needs_confirmation) {
      candidate_.pending = true;
      candidate_.view = index_;
      candidate_.capture_ns = motion_.capture_ns();
      candidate_.world_from_cam = out.world_from_cam;
      candidate_.how = out.reason;
      out.reason = why + "; re-entry candidate (" + out.reason + "), to be confirmed by the next view";
      return false;
    }
    pose = out.world_from_cam;
    out.state = TrackingState::kRelocalised;
    out.reason = why + "; relocalised: " + out.reason;
    return true;
  };
  if (!accepted && !candidate_.pending && !keyframes_.empty()) {
    // Local search first: ICP from the last accepted pose and from the keyframes nearest to it
    // (the probe usually comes back where it left the model).
    const std::string why = out.reason;
    bool from_prediction = false;
    if (RelocaliseLocally(samples, &out, &from_prediction)) {
      // One bad view in a track that never left: no confirmation (reentry_direct_max_views).
      if (from_prediction && motion_.ViewsElapsed() <= o_.reentry_direct_max_views) needs_confirmation = false;
      accepted = reentered(why);
    } else {
      out.reason = why + "; local search failed: " + out.reason;
    }
  }
  if (!accepted && !candidate_.pending && o_.relocalise && !keyframes_.empty()) {
    const std::string why = out.reason;
    if (Relocalise(samples, points, texture, &out)) accepted = reentered(why);
    else out.reason = why + "; relocalisation failed: " + out.reason;
  }
  if (!accepted && state_ != TrackingState::kInitialising && o_.segment_after_views > 0 &&
      ++lost_with_points_ > o_.segment_after_views && static_cast<int>(segments_.size()) < o_.max_segments) {
    StartSegment(&pose, &out);  // the view cannot be placed: it starts a segment of its own
    accepted = true;
  }
  if (!accepted) {
    state_ = state_ == TrackingState::kInitialising ? state_ : TrackingState::kLost;
    out.state = state_;
    out.segment_joined = joined_now;
    out.main_from_display = main_from_display;
    out.join_attempt = join_attempt;
    out.ms = Ms(t0);
    return out;
  }
  lost_with_points_ = 0;
  coast_run_ = 0;
  if (augment && !map_.empty() && !augmented && augment(pose, map_)) {
    // The view gained points: register it again from its pose with all of them, when they are
    // enough to change the fit (a view whose own points were only the smooth palate, say).
    SurfacePoints& more = more_samples_;
    SampleOrganised(points, normals, quality, o_.sample_stride, &more);
    const bool enough = static_cast<double>(more.size()) >= (1.0 + o_.reregister_min_gain) * static_cast<double>(samples.size());
    if (!enough) {
      std::swap(samples, more);  // fused and inserted at the pose found without them
    } else {
      IcpOptions fine = o_.icp;
      fine.levels.erase(fine.levels.begin(), fine.levels.begin() + o_.reregister_first_level);
      IcpResult again = RunIcp(more, pose, fine);
      if (again.ok && motion_.Consistent(again.target_from_source, nullptr)) {
        pose = again.target_from_source;
        out.icp = again;
        std::swap(samples, more);
      }
    }
  }
  out.accepted = true;
  out.world_from_cam = pose;
  if (out.state == TrackingState::kTracking && state_ == TrackingState::kTracking && motion_.HasVelocity()) {
    const Rigid3d pred = motion_.Predict();
    out.prediction_offset_mm = TranslationDistanceMm(pose, pred);
    out.prediction_offset_deg = RotationAngleRad(pose, pred) * 180 / M_PI;
  }
  state_ = out.state;
  // No velocity across a re-entry, nor from the last pose of the segment before into a new
  // segment's frame (2 m apart: the next view's prediction would extrapolate that).
  const bool motion_restart = out.state == TrackingState::kRelocalised || out.new_segment;
  motion_.Advance(pose, motion_restart);
  // Into the tracking model unless its residual stands out from the recent views' (see
  // map_max_rmse_ratio); the first view (no ICP) always enters.
  out.in_model = true;
  if (out.icp.ok && out.icp.rmse_mm > 0) {
    if (o_.map_max_rmse_ratio > 0 && recent_rmse_mm_.size() >= 8 && out.icp.overlap >= o_.map_gate_min_overlap &&
        gated_run_ < o_.map_gate_max_run) {
      std::vector<double> sorted = recent_rmse_mm_;
      std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2), sorted.end());
      out.in_model = out.icp.rmse_mm <= o_.map_max_rmse_ratio * sorted[sorted.size() / 2];
    }
    PushRecentRmse(out.icp.rmse_mm);
    view_log_.back().rmse_pushed_mm = out.icp.rmse_mm;
  }
  gated_run_ = out.in_model ? 0 : gated_run_ + 1;
  ViewLog& log = view_log_.back();
  log.in_model = out.in_model;
  log.motion_restart = motion_restart;
  log.pose = pose;
  if (out.in_model) {
    InsertIntoModel(points, normals, pose);
  }
  MaybeKeyframe(samples, points, normals, texture, pose, &out);  // does not read the model
  view_log_.back().current_since = current_since_;
  anchor_.back() = current_kf_;
  kf_from_cam_.back() = graph_.pose(keyframes_[static_cast<size_t>(current_kf_)].node).inverse() * pose;
  out.segment = active_segment_;
  out.in_main = SegmentInMain(active_segment_);
  out.segment_joined = joined_now;
  out.main_from_display = main_from_display;
  out.display_from_cam = MainFromSegmentFrame(active_segment_) * out.world_from_cam;
  out.join_attempt = join_attempt;
  out.ms = Ms(t0);
  return out;
}

bool Tracker::Coast(const SurfacePoints& samples, const cv::Mat& points, const cv::Mat& normals, const Rigid3d& prediction,
                    TrackResult* out) {
  const IcpOptions& icp = o_.icp;
  if (o_.max_coast_views <= 0 || coast_run_ >= o_.max_coast_views || state_ == TrackingState::kInitialising ||
      motion_.ViewsElapsed() > o_.reentry_direct_max_views)
    return false;
  // Refused for its degeneracy alone: it fits the model where it overlaps it.
  auto fits = [&](const IcpResult& r) {
    return r.correspondences >= icp.min_correspondences && r.overlap >= icp.min_overlap && r.rmse_mm <= icp.max_rmse_mm;
  };
  if (!fits(out->icp) || out->icp.eigen_ratio >= icp.min_eigen_ratio) return false;
  // ICP again from the prediction, stepping only along the well-constrained directions.
  IcpOptions remapped = icp;
  remapped.remap_min_eigen_ratio = o_.coast_min_eigen_ratio;
  const IcpResult r = RunIcp(samples, prediction, remapped);
  if (!fits(r)) return false;
  const Rigid3d pose = r.target_from_source;
  if (!motion_.Consistent(pose, nullptr)) return false;
  out->icp = r;
  ++coast_run_;
  motion_.Advance(pose, false);
  ViewLog& log = view_log_.back();
  log.coasted = true;
  log.pose = pose;
  // Into the tracking model (not the fused one): the next view overlaps the stretch it slides along.
  InsertIntoModel(points, normals, pose);
  out->state = state_;
  out->reason += "; coasting: tracked along its constrained directions, not fused (" + std::to_string(coast_run_) + " of " +
                 std::to_string(o_.max_coast_views) + " in a row)";
  return true;
}

void Tracker::InsertIntoModel(const cv::Mat& points, const cv::Mat& normals, const Rigid3d& pose) {
  SampleOrganised(points, normals, cv::Mat(), o_.map_stride, &map_samples_);
  insert_pending_ = true;
  pending_pose_ = pose;
  if (!o_.defer_model_insert) CommitView();
}

double Tracker::CommitView() {
  if (!insert_pending_) return 0;
  const auto t0 = std::chrono::steady_clock::now();
  insert_pending_ = false;
  map_.Insert(map_samples_, pending_pose_);
  return Ms(t0);
}

IcpOptions Tracker::LocalSearchIcp() const {
  IcpOptions icp = o_.icp;
  icp.levels.front().max_distance_mm = std::max(icp.levels.front().max_distance_mm, o_.local_search_gate_mm);
  // Its wide first level keeps IcpOptions' point-to-point share, which widens the basin: a
  // re-entry starts from a pose up to millimetres off, tracking from one a view's motion off.
  icp.levels.front().point_to_plane_weight = IcpOptions().levels.front().point_to_plane_weight;
  // A view found this way re-enters the model (after ICP from the prediction failed, or after a gap
  // or a loss) and must meet relocalise_max_rmse_mm like a feature relocalisation: on the typodont,
  // views fitted onto the neighbouring, similar tooth after a gap came back at 59–60 µm (6.7 and
  // 31 mm off) under tracking's 60 µm, while every correct re-entry on the real arch was at 11–31 µm.
  icp.max_rmse_mm = std::min(icp.max_rmse_mm, o_.relocalise_max_rmse_mm);
  return icp;
}

bool Tracker::ConfirmReentry(const SurfacePoints& samples, TrackResult* out) {
  candidate_.pending = false;
  const IcpResult r = RunIcp(samples, candidate_.world_from_cam, LocalSearchIcp());
  if (!r.ok) {
    out->reason = "icp: " + r.reason;
    return false;
  }
  const double views = motion_.ViewsSince(candidate_.view, candidate_.capture_ns);
  if (!motion_.ConsistentFrom(candidate_.world_from_cam, views, r.target_from_source, &out->reason)) return false;
  if (!VerifyReentry(samples, r, &out->reentry, &out->reason)) return false;
  out->icp = r;
  out->world_from_cam = r.target_from_source;
  return true;
}

bool Tracker::AfterGap() const { return state_ == TrackingState::kLost || motion_.ViewsElapsed() > o_.reentry_direct_max_views; }

bool Tracker::JumpsFromPrediction(const Rigid3d& pose) const {
  if (motion_.last_view() < 0) return false;
  // The prediction's error grows with the time it spans (a live host's views come unevenly).
  const double views = std::max(1.0, motion_.ViewsElapsed());
  const Rigid3d pred = motion_.Predict();
  return (o_.jump_check_mm > 0 && TranslationDistanceMm(pose, pred) > o_.jump_check_mm * views) ||
         (o_.jump_check_deg > 0 && RotationAngleRad(pose, pred) * 180 / M_PI > o_.jump_check_deg * views);
}

bool Tracker::MeetsJumpStandard(const SurfacePoints& samples, const IcpResult& r, std::string* why) {
  char what[160];
  if (r.rmse_mm > o_.relocalise_max_rmse_mm || r.overlap < o_.relocalise_min_overlap) {
    std::snprintf(what, sizeof what, "rmse %.1f um, overlap %.2f (a jump needs <= %.1f um, >= %.2f)", r.rmse_mm * 1000, r.overlap,
                  o_.relocalise_max_rmse_mm * 1000, o_.relocalise_min_overlap);
    *why = what;
    return false;
  }
  ReentryEvidence evidence;
  return VerifyReentry(samples, r, &evidence, why);
}

bool Tracker::VerifyReentry(const SurfacePoints& samples, const IcpResult& r, ReentryEvidence* evidence, std::string* why) {
  if ((AfterGap() || JumpsFromPrediction(r.target_from_source)) && r.eigen_ratio < o_.reentry_min_eigen_ratio) {
    *why = "degenerate re-entry (eigen ratio " + std::to_string(r.eigen_ratio) + " < " + std::to_string(o_.reentry_min_eigen_ratio) + ")";
    return false;
  }
  *evidence = CheckReentry(samples, r.target_from_source);
  if (evidence->ok) return true;
  *why = evidence->reason;
  return false;
}

ReentryEvidence Tracker::CheckReentry(const SurfacePoints& samples, const Rigid3d& world_from_cam) {
  // The keyframes whose surface centre is nearest the view's at the candidate pose (their current
  // graph poses).
  const Eigen::Vector3d centre = world_from_cam * samples.Centroid();
  std::vector<std::pair<double, int>> order;
  for (int k = 0; k < static_cast<int>(keyframes_.size()); ++k) {
    const Keyframe& kf = keyframes_[static_cast<size_t>(k)];
    const double d = (graph_.pose(kf.node) * kf.centre_in_cam - centre).norm();
    if (d <= o_.reentry_check.max_centre_distance_mm) order.emplace_back(d, k);
  }
  const size_t n = std::min(order.size(), static_cast<size_t>(o_.reentry_check.keyframes));
  std::partial_sort(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(n), order.end());
  reentry_kfs_.clear();
  for (size_t i = 0; i < n; ++i) {
    const Keyframe& kf = keyframes_[static_cast<size_t>(order[i].second)];
    const Rigid3d world_from_kf = graph_.pose(kf.node);
    reentry_kfs_.push_back({&kf.samples, world_from_kf, world_from_kf * kf.centre_in_cam});
  }
  return reentry_check_.Test(samples, world_from_cam, reentry_kfs_);
}


void Tracker::ForgetResiduals() {
  recent_rmse_mm_.clear();
  recent_rmse_next_ = 0;
  gated_run_ = 0;
}

bool Tracker::SegmentStartsAt(int64_t view) const {
  for (size_t s = 1; s < segments_.size(); ++s)
    if (segments_[s].first_view == view) return true;
  return false;
}

bool Tracker::SegmentInMain(int segment) const {
  return segment == 0 || (segment > 0 && segment < static_cast<int>(segments_.size()) && segments_[static_cast<size_t>(segment)].joined);
}

bool Tracker::KeyframeInActiveSegment(int k) const {
  const int seg = keyframes_[static_cast<size_t>(k)].segment;
  return seg == active_segment_ || (SegmentInMain(seg) && SegmentInMain(active_segment_));
}

Rigid3d Tracker::MainFromSegmentFrame(int segment) const {
  Rigid3d t = Rigid3d::Identity();
  if (!SegmentInMain(segment)) t.translation().x() = -kSegmentSpacingMm * segment;
  return t;
}

int Tracker::segments_joined() const {
  int n = 0;
  for (const Segment& seg : segments_) n += seg.joined;
  return n;
}

int Tracker::ViewSegment(int64_t view) const {
  if (view < 0 || view >= views() || anchor_[static_cast<size_t>(view)] < 0) return -1;
  return keyframes_[static_cast<size_t>(anchor_[static_cast<size_t>(view)])].segment;
}

SurfacePoints Tracker::MainSamples() const {
  SurfacePoints main;
  for (size_t i = 0; i < map_.size(); ++i) {
    if (!SegmentInMain(SegmentOfPoint(map_.points()[i]))) continue;
    main.points.push_back(map_.points()[i]);
    main.normals.push_back(map_.normals()[i]);
  }
  return main;
}

void Tracker::StartSegment(Rigid3d* pose, TrackResult* out) {
  const int s = static_cast<int>(segments_.size());
  // The last pose in the main frame's coordinates (the track may be in another segment apart).
  const Rigid3d last_at_origin = MainFromSegmentFrame(active_segment_) * motion_.last_pose();
  // The main model rests while the new segment grows: its join features are made once, now.
  const auto t0 = std::chrono::steady_clock::now();
  join_target_ = MakeSegmentJoinTarget(MainSamples(), o_.segment_join);
  const double ms_target = Ms(t0);
  segments_.push_back(Segment{index_, false, keyframes_.size()});
  active_segment_ = s;
  *pose = MainFromSegmentFrame(s).inverse() * last_at_origin;
  out->state = TrackingState::kTracking;
  out->new_segment = true;
  char what[160];
  std::snprintf(what, sizeof what, "; new segment %d after %d views that could not be placed (join features of the model: %.0f ms)", s,
                lost_with_points_, ms_target);
  out->reason += what;
  // The new segment starts its own chain: no keyframe to anchor to, no motion to predict from, no
  // candidate re-entry; undo does not reach back before it.
  current_kf_ = -1;
  current_since_ = -1;
  current_occupancy_.reset();
  candidate_ = ReentryCandidate{};
  motion_.ForgetVelocity();
  ForgetResiduals();
  lost_with_points_ = 0;
  undo_barrier_view_ = index_ + 1;
}

bool Tracker::TryJoinSegment(int s, std::string* why, Rigid3d* main_from_segment) {
  const auto t0 = std::chrono::steady_clock::now();
  Rigid3d t;
  const bool joined = JoinSegmentNow(s, why, &t);
  if (joined && main_from_segment != nullptr) *main_from_segment = t;
  char ms[32];
  std::snprintf(ms, sizeof ms, " (%.0f ms)", Ms(t0));
  *why += ms;
  return joined;
}

bool Tracker::JoinSegmentNow(int s, std::string* why, Rigid3d* main_from_segment) {
  // The segment's model samples (they lie around its offset) and its newest keyframe.
  SurfacePoints seg;
  for (size_t i = 0; i < map_.size(); ++i) {
    if (SegmentOfPoint(map_.points()[i]) != s) continue;
    seg.points.push_back(map_.points()[i]);
    seg.normals.push_back(map_.normals()[i]);
  }
  int newest = -1;
  for (int k = static_cast<int>(keyframes_.size()) - 1; k >= 0 && newest < 0; --k)
    if (keyframes_[static_cast<size_t>(k)].segment == s) newest = k;
  if (seg.empty() || newest < 0) {
    *why = "the segment is empty";
    return false;
  }
  // Thinned and described once for both ways of joining.
  const SegmentJoinTarget source = MakeSegmentJoinTarget(seg, o_.segment_join);
  SegmentJoinResult r = JoinSegment(source, join_target_, o_.segment_join);
  std::string how = "fpfh";
  if (!r.ok) {
    *why = r.reason;
    if (o_.relocalise && o_.segment_join_feature_keyframes > 0) {
      std::string features_why;
      SegmentJoinResult f = JoinSegmentByFeatures(s, newest, source, &features_why);
      if (f.ok) {
        r = std::move(f);
        how = "features (" + features_why + ")";
      } else {
        *why += "; features: " + features_why;
      }
    }
  }
  if (!r.ok) return false;
  const Rigid3d& T = r.main_from_segment;
  *main_from_segment = T;
  // Verified like a re-entry: the newest keyframe at its joined pose does not contradict what the
  // main keyframes near it saw.
  const Keyframe& kn = keyframes_[static_cast<size_t>(newest)];
  const ReentryEvidence evidence = CheckReentry(kn.samples, T * graph_.pose(kn.node));
  if (!evidence.ok) {
    *why = "join: " + evidence.reason;
    return false;
  }
  // Merge: the segment's keyframes, model samples and motion state into the main frame.
  for (Keyframe& kf : keyframes_)
    if (kf.segment == s) graph_.set_pose(kf.node, T * graph_.pose(kf.node));
  for (int64_t v = 0; v < views(); ++v)
    if (ViewSegment(v) == s) view_log_[static_cast<size_t>(v)].pose = T * view_log_[static_cast<size_t>(v)].pose;
  PointMap merged(o_.map);
  SurfacePoints all;
  const Eigen::Matrix3f R = T.linear().cast<float>();
  const Eigen::Vector3f t = T.translation().cast<float>();
  for (size_t i = 0; i < map_.size(); ++i) {
    const Eigen::Vector3f& p = map_.points()[i];
    const Eigen::Vector3f& n = map_.normals()[i];
    const bool moves = SegmentOfPoint(p) == s;
    all.points.push_back(moves ? Eigen::Vector3f(R * p + t) : p);
    all.normals.push_back(moves ? Eigen::Vector3f(R * n) : n);
  }
  merged.Insert(all, Rigid3d::Identity());
  map_ = std::move(merged);
  if (active_segment_ == s) {
    motion_.MoveFrame(T);
    candidate_ = ReentryCandidate{};
  }
  segments_[static_cast<size_t>(s)].joined = true;
  // A loop edge between the newest keyframe and the nearest main keyframes that overlap it.
  const Eigen::Vector3d c = graph_.pose(kn.node) * kn.centre_in_cam;
  std::vector<std::pair<double, int>> near;
  for (int j = 0; j < static_cast<int>(keyframes_.size()); ++j) {
    const Keyframe& kf = keyframes_[static_cast<size_t>(j)];
    if (kf.segment == s || !SegmentInMain(kf.segment)) continue;
    near.emplace_back((graph_.pose(kf.node) * kf.centre_in_cam - c).norm(), j);
  }
  std::sort(near.begin(), near.end());
  int edges = 0;
  for (size_t i = 0; i < near.size() && i < 6 && edges < 2; ++i) {
    PoseGraphEdge e;
    const int j = near[i].second;
    if (!KeyframeEdge(std::min(j, newest), std::max(j, newest), &e)) continue;
    e.loop = true;
    graph_.AddEdge(e);
    ++edges;
  }
  if (edges == 0 && !near.empty()) {  // the join's own pose, on the loop σs
    PoseGraphEdge e;
    e.from = keyframes_[static_cast<size_t>(near.front().second)].node;
    e.to = kn.node;
    e.from_from_to = graph_.pose(e.from).inverse() * graph_.pose(e.to);
    e.sigma_translation_mm = o_.loop_sigma_mm;
    e.sigma_rotation_rad = o_.loop_sigma_rad;
    e.loop = true;
    graph_.AddEdge(e);
  }
  // The rebuilt model has no undo journal: undo starts again from here.
  for (ViewLog& log : view_log_) log.map_inserts_before = 0;
  undo_barrier_view_ = index_ + 1;
  *why = "joined by " + how + ": " + std::to_string(r.icp.correspondences) + " samples, rmse " + std::to_string(r.icp.rmse_mm * 1000) + " um";
  return true;
}

void Tracker::EnsureKeyframeFeatures(Keyframe* kf) {
  if (!kf->features_pending()) return;  // kOnDemand: the first relocalisation or join that needs them
  std::vector<cv::Mat> points, texture;
  // Packed by this tracker: unpacking fails only on damaged memory, and then no features are
  // better than wrong ones (the keyframe is simply not matched).
  if (UnpackFrames(kf->packed_feature_points, &points).ok() &&
      (kf->packed_feature_texture.empty() || UnpackFrames(kf->packed_feature_texture, &texture).ok()))
    kf->features = ExtractViewFeatures(points[0], texture.empty() ? cv::Mat() : texture[0], o_.features);
  std::string().swap(kf->packed_feature_points);
  std::string().swap(kf->packed_feature_texture);
}

SegmentJoinResult Tracker::JoinSegmentByFeatures(int s, int newest, const SegmentJoinTarget& seg, std::string* why) {
  SegmentJoinResult none;
  std::vector<int> main;
  for (int k = 0; k < static_cast<int>(keyframes_.size()); ++k)
    if (keyframes_[static_cast<size_t>(k)].segment != s && SegmentInMain(keyframes_[static_cast<size_t>(k)].segment)) main.push_back(k);
  if (main.empty()) {
    *why = "no main keyframe";
    return none;
  }
  CollectKeyframeFeatures();
  Keyframe& kn = keyframes_[static_cast<size_t>(newest)];
  EnsureKeyframeFeatures(&kn);
  Segment& g = segments_[static_cast<size_t>(s)];
  const size_t tries = std::min(main.size(), static_cast<size_t>(o_.segment_join_feature_keyframes));
  *why = "no feature match";
  for (size_t i = 0; i < tries; ++i) {
    const int j = main[(g.feature_cursor + i) % main.size()];
    Keyframe& kf = keyframes_[static_cast<size_t>(j)];
    EnsureKeyframeFeatures(&kf);
    const FeatureAlignResult a = AlignByFeatures(kn.features, kf.features, o_.features);
    if (!a.ok) continue;
    const Rigid3d guess = graph_.pose(kf.node) * a.target_from_source * graph_.pose(kn.node).inverse();
    SegmentJoinResult r = RefineSegmentJoin(seg, join_target_, guess, o_.segment_join);
    if (r.ok) {
      g.feature_cursor += i + 1;
      *why = "keyframe " + std::to_string(j) + ", " + std::to_string(a.inliers) + " feature inliers";
      return r;
    }
    *why = "keyframe " + std::to_string(j) + ": " + r.reason;
  }
  g.feature_cursor += tries;
  return none;
}

bool Tracker::RelocaliseLocally(const SurfacePoints& samples, TrackResult* out, bool* from_prediction) {
  *from_prediction = false;
  const Eigen::Vector3d here = motion_.last_pose() * samples.Centroid();
  std::vector<std::pair<double, int>> order;
  for (int k = 0; k < static_cast<int>(keyframes_.size()); ++k) {
    if (!KeyframeInActiveSegment(k)) continue;
    const Keyframe& kf = keyframes_[static_cast<size_t>(k)];
    order.emplace_back((graph_.pose(kf.node) * kf.centre_in_cam - here).norm(), k);
  }
  std::sort(order.begin(), order.end());
  std::vector<Rigid3d> starts = {motion_.Predict(), motion_.last_pose()};
  for (int i = 0; i < std::min<int>(o_.local_candidates, static_cast<int>(order.size())); ++i)
    starts.push_back(graph_.pose(keyframes_[static_cast<size_t>(order[static_cast<size_t>(i)].second)].node));
  const IcpOptions icp = LocalSearchIcp();
  // The search is local: its result must also be a consistent motion from the last accepted pose
  // (over the views elapsed); a far return is left to the feature relocalisation.
  std::string last_reason, failures;  // failures: why each start failed, for the events
  const auto start_name = [&](size_t i) {
    return i == 0 ? std::string("from the prediction") : i == 1 ? std::string("from the last pose")
                                                               : "from keyframe " + std::to_string(order[i - 2].second);
  };
  // After a gap every start is tried: a second fit that passes too, elsewhere, makes the return
  // ambiguous (TrackerOptions::reentry_ambiguity_mm).
  const bool all_starts = AfterGap() && o_.reentry_ambiguity_mm > 0;
  const Eigen::Vector3d centre_in_cam = samples.Centroid();
  int found = -1;
  for (size_t i = 0; i < starts.size(); ++i) {
    const IcpResult r = RunIcp(samples, starts[i], icp);
    ReentryEvidence evidence;
    if (!r.ok) last_reason = r.reason;
    if (!r.ok || !motion_.Consistent(r.target_from_source, &last_reason) || !VerifyReentry(samples, r, &evidence, &last_reason)) {
      failures += (failures.empty() ? "" : ", ") + start_name(i) + ": " + last_reason;
      continue;
    }
    if (found >= 0) {
      const double apart_mm = (r.target_from_source * centre_in_cam - out->world_from_cam * centre_in_cam).norm();
      const double apart_deg = RotationAngleRad(r.target_from_source, out->world_from_cam) * 180 / M_PI;
      if (apart_mm > o_.reentry_ambiguity_mm || apart_deg > 2.0) {
        char why[160];
        std::snprintf(why, sizeof why, "ambiguous re-entry: two fits %.2f mm, %.1f deg apart", apart_mm, apart_deg);
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

bool Tracker::Relocalise(const SurfacePoints& samples, const cv::Mat& points, const cv::Mat& texture, TrackResult* out) {
  const ViewFeatures f = ExtractViewFeatures(points, texture, o_.features);
  CollectKeyframeFeatures();
  // Local border search: keyframes nearest the last accepted view first.
  const Eigen::Vector3d here = motion_.last_pose() * samples.Centroid();
  std::vector<std::pair<double, int>> order;
  for (int k = 0; k < static_cast<int>(keyframes_.size()); ++k) {
    if (!KeyframeInActiveSegment(k)) continue;
    const Keyframe& kf = keyframes_[static_cast<size_t>(k)];
    const Eigen::Vector3d c = graph_.pose(kf.node) * kf.centre_in_cam;
    order.emplace_back((c - here).norm(), k);
  }
  std::sort(order.begin(), order.end());
  IcpOptions icp = o_.icp;
  icp.max_rmse_mm = o_.relocalise_max_rmse_mm;
  icp.min_overlap = o_.relocalise_min_overlap;
  std::string last_reason = "no keyframe";
  for (int i = 0; i < std::min<int>(o_.relocalise_candidates, static_cast<int>(order.size())); ++i) {
    Keyframe& kf = keyframes_[static_cast<size_t>(order[static_cast<size_t>(i)].second)];
    EnsureKeyframeFeatures(&kf);
    const FeatureAlignResult a = AlignByFeatures(f, kf.features, o_.features);
    if (!a.ok) {
      last_reason = a.reason;
      continue;
    }
    const Rigid3d guess = graph_.pose(kf.node) * a.target_from_source;
    const IcpResult r = RunIcp(samples, guess, icp);
    if (!r.ok) {
      last_reason = "icp after features: " + r.reason;
      continue;
    }
    if (!VerifyReentry(samples, r, &out->reentry, &last_reason)) {
      last_reason = "after features: " + last_reason;
      continue;
    }
    out->icp = r;
    out->world_from_cam = r.target_from_source;
    out->reason = "keyframe " + std::to_string(order[static_cast<size_t>(i)].second) + ", " + std::to_string(a.inliers) +
                  " feature inliers";
    return true;
  }
  out->reason = last_reason;
  return false;
}

void Tracker::MaybeKeyframe(const SurfacePoints& /*samples*/, const cv::Mat& points, const cv::Mat& normals,
                            const cv::Mat& texture, const Rigid3d& pose, TrackResult* out) {
  SurfacePoints kfs = SampleOrganised(points, normals, cv::Mat(), o_.keyframe_stride);
  const bool jumped = (o_.keyframe_jump_mm > 0 && out->prediction_offset_mm > o_.keyframe_jump_mm) ||
                      (o_.keyframe_jump_deg > 0 && out->prediction_offset_deg > o_.keyframe_jump_deg);
  if (current_kf_ >= 0 && !jumped) {
    const Keyframe& current = keyframes_[static_cast<size_t>(current_kf_)];
    const Rigid3d current_from_cam = graph_.pose(current.node).inverse() * pose;
    const bool turned = o_.keyframe_max_rotation_deg > 0 &&
                        RotationAngleRad(graph_.pose(current.node), pose) * 180.0 / M_PI > o_.keyframe_max_rotation_deg;
    const bool aged = o_.keyframe_max_views > 0 && index_ - current_since_ >= o_.keyframe_max_views;
    if (!turned && !aged && current_occupancy_->Overlap(kfs, current_from_cam) >= o_.keyframe_overlap) return;
    if (o_.keyframe_reuse_radius_mm > 0 && ReuseKeyframe(kfs, pose)) {
      out->keyframe_reused = true;
      return;
    }
  }
  Keyframe kf;
  kf.view = index_;
  kf.node = graph_.AddNode(pose);
  kf.centre_in_cam = kfs.Centroid();
  kf.parent = current_kf_;
  kf.segment = active_segment_;
  kf.samples = std::move(kfs);
  kf.samples.points.shrink_to_fit();  // kept for the scan: not the lattice's growth capacity
  kf.samples.normals.shrink_to_fit();
  current_occupancy_ = OccupancyMap(kf.samples, kOverlapVoxelMm);
  if (o_.relocalise) {
    switch (o_.keyframe_feature_timing) {
      case TrackerOptions::FeatureTiming::kInTrack: kf.features = ExtractViewFeatures(points, texture, o_.features); break;
      case TrackerOptions::FeatureTiming::kWorker: feature_worker_->Submit(keyframes_.size(), points, texture); break;
      case TrackerOptions::FeatureTiming::kOnDemand:
        // zstd fails only on exhausted memory: the features are then extracted now (kInTrack).
        if (!packer_.Pack({points}, &kf.packed_feature_points).ok() ||
            (!texture.empty() && !packer_.Pack({texture}, &kf.packed_feature_texture).ok())) {
          kf.packed_feature_points.clear();
          kf.packed_feature_texture.clear();
          kf.features = ExtractViewFeatures(points, texture, o_.features);
        }
        kf.packed_feature_points.shrink_to_fit();  // Pack sized it for the worst case
        kf.packed_feature_texture.shrink_to_fit();
        break;
    }
  }
  keyframes_.push_back(std::move(kf));
  out->new_keyframe = true;
  const int k = static_cast<int>(keyframes_.size()) - 1;
  current_kf_ = k;
  current_since_ = index_;
  if (o_.defer_keyframe_edges) deferred_edges_.push_back({-1, k});
  else out->loops_added = AddKeyframeEdges(k);
}

bool Tracker::ReuseKeyframe(const SurfacePoints& kfs, const Rigid3d& pose) {
  if (kfs.empty()) return false;
  const Eigen::Vector3d centre = pose * kfs.Centroid();
  const double max_turn_rad = o_.keyframe_max_rotation_deg > 0 ? 0.5 * o_.keyframe_max_rotation_deg * M_PI / 180.0 : M_PI;
  std::vector<std::pair<double, int>> near;
  for (int j = 0; j < static_cast<int>(keyframes_.size()); ++j) {
    if (j == current_kf_) continue;
    const Keyframe& kf = keyframes_[static_cast<size_t>(j)];
    const Rigid3d& world_from_kf = graph_.pose(kf.node);
    const double d = (world_from_kf * kf.centre_in_cam - centre).norm();
    if (d <= o_.keyframe_reuse_radius_mm && RotationAngleRad(world_from_kf, pose) <= max_turn_rad) near.emplace_back(d, j);
  }
  const size_t n = std::min(near.size(), static_cast<size_t>(o_.keyframe_reuse_candidates));
  std::partial_sort(near.begin(), near.begin() + static_cast<std::ptrdiff_t>(n), near.end());
  for (size_t i = 0; i < n; ++i) {
    const int j = near[i].second;
    const Keyframe& kf = keyframes_[static_cast<size_t>(j)];
    std::unique_ptr<PointMap> occupancy = OccupancyMap(kf.samples, kOverlapVoxelMm);
    if (occupancy->Overlap(kfs, graph_.pose(kf.node).inverse() * pose) < o_.keyframe_overlap) continue;
    // The view overlaps both the keyframe it leaves and the one it returns to: those two are a loop
    // closed (e.g. a probe back at a tooth it circled before), the edge DetectLoops would have
    // measured had the view become a keyframe.
    const int left = current_kf_;
    current_kf_ = j;
    current_since_ = index_;
    current_occupancy_ = std::move(occupancy);
    ++keyframes_reused_;
    if (left >= 0) {
      const DeferredEdge d{std::min(left, j), std::max(left, j)};
      if (o_.defer_keyframe_edges) deferred_edges_.push_back(d);
      else AddReuseEdge(d.from, d.to);
    }
    return true;
  }
  return false;
}

void Tracker::AddReuseEdge(int from, int to) {
  // Checked here rather than when the reuse happened: deferred, the keyframes' own edges (odometry,
  // DetectLoops) are added just before, in Track()'s order, and one pair may be reused many times.
  if (graph_.HasEdge(keyframes_[static_cast<size_t>(from)].node, keyframes_[static_cast<size_t>(to)].node)) return;
  PoseGraphEdge e;
  if (!KeyframeEdge(from, to, &e)) return;
  e.loop = true;
  if (to - from < o_.loop_min_separation) ScaleInformation(o_.near_loop_information_factor, &e);
  graph_.AddEdge(e);
}

int64_t Keyframe::bytes() const {
  const auto mat = [](const cv::Mat& m) { return static_cast<int64_t>(m.total() * m.elemSize()); };
  const auto points = [](const std::vector<Eigen::Vector3f>& v) { return static_cast<int64_t>(v.capacity() * sizeof(Eigen::Vector3f)); };
  return points(samples.points) + points(samples.normals) +
         static_cast<int64_t>(samples.weights.capacity() * sizeof(float)) + points(features.texture_points) + points(features.range_points) +
         points(features.shaded_points) + mat(features.texture_descriptors) + mat(features.range_descriptors) +
         mat(features.shaded_descriptors) + static_cast<int64_t>(packed_feature_points.capacity() + packed_feature_texture.capacity());
}

int64_t Tracker::keyframe_bytes() const {
  int64_t bytes = 0;
  for (const Keyframe& kf : keyframes_) bytes += kf.bytes();
  return bytes;
}

int Tracker::AddKeyframeEdges(int k) {
  if (const int parent = keyframes_[static_cast<size_t>(k)].parent; parent >= 0) {
    PoseGraphEdge e;
    const bool measured = o_.keyframe_icp_edges && KeyframeEdge(parent, k, &e);
    if (!measured) {
      e = PoseGraphEdge{};
      e.from = keyframes_[static_cast<size_t>(parent)].node;
      e.to = keyframes_[static_cast<size_t>(k)].node;
      e.from_from_to = graph_.pose(e.from).inverse() * graph_.pose(e.to);
      e.sigma_translation_mm = o_.odometry_sigma_mm;
      e.sigma_rotation_rad = o_.odometry_sigma_rad;
    }
    e.loop = false;
    graph_.AddEdge(e);
    if (measured && o_.tracked_edge_information_factor > 0) {
      // The tracked relative pose: the graph's poses are still the tracked ones (nothing but
      // Optimize moves them, and deferred edges are added before it does).
      e.from_from_to = graph_.pose(e.from).inverse() * graph_.pose(e.to);
      ScaleInformation(o_.tracked_edge_information_factor, &e);
      graph_.AddEdge(e);
    }
  }
  return o_.detect_loops ? DetectLoops(k) : 0;
}

IcpOptions KeyframeIcp(const IcpOptions& base) {
  IcpOptions icp = base;
  icp.levels = {{4, 10, 0.5, 0.8}, {1, 10, 0.2, 1.0}, {1, 8, 0.1, 1.0}};
  // Pose-graph edges keep IcpOptions' strict termination (a few per keyframe, not per burst).
  const IcpOptions strict;
  icp.min_delta_translation_mm = strict.min_delta_translation_mm;
  icp.min_delta_rotation_rad = strict.min_delta_rotation_rad;
  icp.min_relative_error_change = strict.min_relative_error_change;
  return icp;
}

bool MeasureKeyframeEdge(const SurfacePoints& from_samples, const SurfacePoints& to_samples, const Rigid3d& guess,
                         const IcpOptions& icp, double information_scale, PoseGraphEdge* e, IcpResult* result) {
  D3D_CHECK_MSG(information_scale > 0, "MeasureKeyframeEdge: information_scale must be > 0");
  const KdTreeTarget target(from_samples);
  const IcpResult r = RegisterIcp(to_samples, target, guess, icp);
  if (result) *result = r;
  if (!r.ok) return false;
  e->from_from_to = r.target_from_source;
  e->information = EdgeInformationFromIcp(r.information, r.target_from_source, information_scale);
  return true;
}

bool Tracker::KeyframeEdge(int from, int to, PoseGraphEdge* e) const {
  const Keyframe& b = keyframes_[static_cast<size_t>(from)];
  const Keyframe& a = keyframes_[static_cast<size_t>(to)];
  const Rigid3d b_from_a = graph_.pose(b.node).inverse() * graph_.pose(a.node);
  PoseGraphEdge m;
  m.from = b.node;
  m.to = a.node;
  m.sigma_translation_mm = o_.loop_sigma_mm;
  m.sigma_rotation_rad = o_.loop_sigma_rad;
  if (!MeasureKeyframeEdge(b.samples, a.samples, b_from_a, KeyframeIcp(o_.icp), o_.edge_information_scale, &m)) return false;
  if (!o_.keyframe_icp_edges) m.information.setZero();  // the σs
  *e = m;
  return true;
}

int Tracker::DetectLoops(int k) {
  const Keyframe& a = keyframes_[static_cast<size_t>(k)];
  const Rigid3d wa = graph_.pose(a.node);
  const Eigen::Vector3d ca = wa * a.centre_in_cam;
  std::vector<std::pair<double, int>> far, near;
  for (int j = 0; j + 2 <= k; ++j) {
    if (j == a.parent) continue;  // joined by the odometry edge (a reused keyframe: older than k − 1)
    const Keyframe& b = keyframes_[static_cast<size_t>(j)];
    const double d = (graph_.pose(b.node) * b.centre_in_cam - ca).norm();
    if (d >= o_.loop_radius_mm) continue;
    (j + o_.loop_min_separation <= k ? far : near).emplace_back(d, j);
  }
  std::sort(far.begin(), far.end());
  std::sort(near.begin(), near.end());
  int added = 0;
  for (const auto& [cand, budget] : {std::pair{&far, o_.max_loop_candidates}, std::pair{&near, o_.near_loop_candidates}}) {
    int here = 0;
    for (size_t i = 0; i < cand->size() && here < budget; ++i) {
      const Keyframe& b = keyframes_[static_cast<size_t>((*cand)[i].second)];
      const Rigid3d b_from_a = graph_.pose(b.node).inverse() * wa;
      if (OverlapIndex(a.samples, b.samples, b_from_a, kOverlapVoxelMm) < o_.loop_min_overlap) continue;
      PoseGraphEdge e;
      if (!KeyframeEdge((*cand)[i].second, k, &e)) continue;
      e.loop = true;
      if (cand == &near) ScaleInformation(o_.near_loop_information_factor, &e);
      graph_.AddEdge(e);
      ++here;
    }
    added += here;
  }
  return added;
}

int Tracker::loop_edges() const {
  int n = 0;
  for (const auto& e : graph_.edges()) n += e.loop;
  return n;
}

int Tracker::JoinApartSegments() {
  CommitView();
  int joined = 0;
  for (int seg = 1; seg < static_cast<int>(segments_.size()); ++seg) {
    if (segments_[static_cast<size_t>(seg)].joined) continue;
    join_target_ = MakeSegmentJoinTarget(MainSamples(), o_.segment_join);  // the main model as it is now
    std::string why;
    joined += TryJoinSegment(seg, &why);
  }
  return joined;
}

Status Tracker::Optimize(const PoseGraphOptions& options, PoseGraphSummary* summary) {
  // Deferred edges first, in keyframe order: the graph's poses have not moved since the keyframes
  // were made (nothing but Optimize moves them), so these are the edges Track() would have added.
  for (const DeferredEdge& d : deferred_edges_) {
    if (d.from < 0) AddKeyframeEdges(d.to);
    else AddReuseEdge(d.from, d.to);
  }
  deferred_edges_.clear();
  return graph_.Optimize(options, summary);
}


void Tracker::PushRecentRmse(double rmse_mm) {
  if (recent_rmse_mm_.size() < kRecentResiduals) recent_rmse_mm_.push_back(rmse_mm);
  else recent_rmse_mm_[recent_rmse_next_++ % kRecentResiduals] = rmse_mm;
}

int64_t Tracker::first_undoable_view() const {
  // Views' Insert counts do not decrease: the first view whose model state the journal still has.
  const int64_t oldest = map_.oldest_undoable_insert();
  const auto it = std::lower_bound(view_log_.begin(), view_log_.end(), oldest,
                                   [](const ViewLog& v, int64_t n) { return v.map_inserts_before < n; });
  return std::max(undo_barrier_view_, static_cast<int64_t>(it - view_log_.begin()));
}

Tracker::UndoResult Tracker::UndoFrom(int64_t first_view) {
  CommitView();
  UndoResult r;
  if (first_view > views() || first_view < first_undoable_view()) {
    r.reason = "view " + std::to_string(first_view) + " is outside what can be undone (views " + std::to_string(first_undoable_view()) +
               " to " + std::to_string(views()) + ")";
    return r;
  }
  CollectKeyframeFeatures();  // no job of the feature worker may name a keyframe that goes
  const size_t f = static_cast<size_t>(first_view);
  if (f < view_log_.size()) {
    const bool rolled_back = map_.RollBackTo(view_log_[f].map_inserts_before);
    D3D_CHECK_MSG(rolled_back, "Tracker::UndoFrom: the model's journal does not reach view " << first_view);
  }
  for (size_t v = f; v < anchor_.size(); ++v) {
    r.views_undone += anchor_[v] >= 0;
    anchor_[v] = -1;
  }
  size_t keep = 0;
  while (keep < keyframes_.size() && keyframes_[keep].view < first_view) ++keep;
  r.keyframes_undone = static_cast<int>(keyframes_.size() - keep);
  keyframes_.resize(keep);
  D3D_CHECK_MSG(keep == 0 || keyframes_.back().node == static_cast<int>(keep) - 1, "Tracker::UndoFrom: keyframe nodes out of order");
  // Edges (and deferred ones) are appended in Track()'s order until Optimize: those added from view
  // first_view on go, including reuse edges between two kept keyframes.
  if (f < view_log_.size()) {
    graph_.Truncate(static_cast<int>(keep), view_log_[f].edges_before);
    deferred_edges_.resize(std::min(deferred_edges_.size(), view_log_[f].deferred_edges_before));
  }
  // The current keyframe as the last kept accepted view left it (the one it anchored to).
  current_kf_ = -1;
  current_since_ = -1;
  for (size_t v = f; v-- > 0;)
    if (anchor_[v] >= 0) {
      current_kf_ = anchor_[v];
      current_since_ = view_log_[v].current_since;
      break;
    }
  D3D_CHECK_MSG(current_kf_ < static_cast<int>(keep), "Tracker::UndoFrom: a kept view's keyframe went");
  current_occupancy_ = current_kf_ >= 0 ? OccupancyMap(keyframes_[static_cast<size_t>(current_kf_)].samples, kOverlapVoxelMm) : nullptr;
  // The motion state, residual history and map gate as the kept views left them (replayed in order).
  ForgetResiduals();
  motion_.Reset();
  coast_run_ = 0;
  for (size_t v = 0; v < f; ++v) {
    const ViewLog& log = view_log_[v];
    if (log.coasted) {
      motion_.AdvanceAt(static_cast<int64_t>(v), log.pose, log.capture_ns, false);
      ++coast_run_;
      continue;
    }
    if (anchor_[v] < 0) continue;
    if (SegmentStartsAt(static_cast<int64_t>(v))) ForgetResiduals();
    coast_run_ = 0;
    if (log.rmse_pushed_mm >= 0) PushRecentRmse(log.rmse_pushed_mm);
    gated_run_ = log.in_model ? 0 : gated_run_ + 1;
    motion_.AdvanceAt(static_cast<int64_t>(v), log.pose, log.capture_ns, log.motion_restart);
  }
  candidate_ = ReentryCandidate{};
  // The views refused in a row before first_view count toward a new segment; the undone ones do not.
  lost_with_points_ = f < view_log_.size() ? view_log_[f].lost_with_points_before : lost_with_points_;
  state_ = motion_.last_view() < 0 ? TrackingState::kInitialising : TrackingState::kLost;
  if (motion_.last_view() < 0) D3D_CHECK_MSG(map_.empty(), "Tracker::UndoFrom: no view left but the model is not empty");
  r.ok = true;
  return r;
}

bool Tracker::ViewPose(int64_t view, Rigid3d* world_from_cam) const {
  if (view < 0 || view >= views() || anchor_[static_cast<size_t>(view)] < 0) return false;
  const Keyframe& kf = keyframes_[static_cast<size_t>(anchor_[static_cast<size_t>(view)])];
  *world_from_cam = graph_.pose(kf.node) * kf_from_cam_[static_cast<size_t>(view)];
  return true;
}

}  // namespace d3d
