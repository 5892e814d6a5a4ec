#include "pipeline/chain/scan_chain.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <mutex>
#include <opencv2/imgcodecs.hpp>
#include <stdexcept>
#include <thread>

#include "common/mesh/mesh_io.h"
#include "pipeline/eval/report_json.h"

namespace d3d {
namespace {
using Clock = std::chrono::steady_clock;
double MsSince(Clock::time_point t) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t).count();
}
}  // namespace

ReconstructOptions HandHeldReconstructOptions() {
  ReconstructOptions o;
  o.phase.motion_compensation = true;
  return o;
}

void ScanOptions::Check() const {
  recon.Check();
  tracker.Check();
  anchor.Check();
  tsdf.Check();
  mesh_clean.Check();
  eval.Check();
}

TrackerOptions TrackerOptionsForStep(TrackerOptions options, double every) {
  if (!(every >= 1)) throw std::invalid_argument("TrackerOptionsForStep: every must be >= 1");
  if (!options.odometry.icp.levels.empty())
    options.odometry.icp.levels[0].max_distance_mm = std::min(3.0, 0.8 * std::sqrt(every));
  options.motion.max_step_mm *= every;
  options.motion.max_step_deg *= every;
  return options;
}

TsdfOptions LiveVolumeOptions::Of(const TsdfOptions& scan) const {
  TsdfOptions t = scan;
  if (voxel_mm > 0) {
    t.voxel_mm = voxel_mm;
    t.truncation_mm = std::max(scan.truncation_mm, 2.0 * voxel_mm);
    t.occlusion_stride = occlusion_stride;
    t.pixel_stride = pixel_stride;
  }
  return t;
}

void LiveVolumeOptions::Check() const {
  if (!(voxel_mm >= 0))
    throw std::invalid_argument("LiveVolumeOptions: voxel_mm >= 0 (0 = the scan's voxel)");
  if (occlusion_stride < 1 || pixel_stride < 1)
    throw std::invalid_argument("LiveVolumeOptions: occlusion_stride and pixel_stride >= 1");
}

ScanOptions LiveScanProfile(ScanOptions options) {
  TrackerOptions& t = options.tracker;
  t.keyframes.feature_timing = KeyframeGraphOptions::FeatureTiming::kOnDemand;
  t.keyframes.defer_edges = true;
  t.keyframes.reuse_radius_mm = 2.0;
  for (auto [level, cap] : {std::pair{0, 1600}, std::pair{1, 4000}, std::pair{2, 8000}})
    if (level < static_cast<int>(t.odometry.icp.levels.size()))
      t.odometry.icp.levels[static_cast<size_t>(level)].max_samples = cap;
  return options;
}

ScanOptions ScanOptionsForBin(ScanOptions options, int bin) {
  if (bin < 1) throw std::invalid_argument("ScanOptionsForBin: bin must be >= 1");
  options.bin = bin;
  if (bin == 1) return options;
  TrackerOptions& t = options.tracker;
  const int old_stride = t.odometry.sample_stride;
  const auto lattice = [bin](int stride) {
    return std::max(1, static_cast<int>(std::lround(static_cast<double>(stride) / bin)));
  };
  t.odometry.sample_stride = lattice(t.odometry.sample_stride);
  t.odometry.map_stride = lattice(t.odometry.map_stride);
  t.keyframes.stride = lattice(t.keyframes.stride);
  // A view of the same share of the image gives (old_stride / (bin · stride))² times the samples.
  const double share = static_cast<double>(old_stride) / (bin * t.odometry.sample_stride);
  t.odometry.min_view_samples =
      std::max(1, static_cast<int>(std::lround(t.odometry.min_view_samples * share * share)));
  t.keyframes.features.image_scale = std::min(1.0, t.keyframes.features.image_scale * bin);
  t.odometry.target_scale = std::min(2.0, t.odometry.target_scale * bin);
  // The occlusion test keeps its lattice in binned pixels (blocks of 2k × 2k camera pixels at bin
  // 2).
  return options;
}

ScanReconstructor::ScanReconstructor(const ProbeCalibration& calibration,
                                     const ReconstructOptions& options, int bin)
    : bin_(bin), recon_(bin > 1 ? BinnedCalibration(calibration, bin) : calibration, options) {
  if (bin < 1) throw std::invalid_argument("ScanReconstructor: bin must be >= 1");
}

Status ScanReconstructor::Reconstruct(const std::vector<cv::Mat>& frames, ReconstructedView* out) {
  const size_t steps = static_cast<size_t>(recon_.calibration().pattern.steps);
  if (frames.size() < steps)
    return InvalidArgument("burst has " + std::to_string(frames.size()) +
                           " frames, the pattern needs " + std::to_string(steps));
  phase_frames_.resize(steps);
  if (bin_ == 1) {
    for (size_t i = 0; i < steps; ++i) phase_frames_[i] = frames[i];  // headers only
  } else {
    binned_frames_.resize(steps);
    const PinholeBrownConrady& cam = recon_.calibration().camera;
    for (size_t i = 0; i < steps; ++i) {
      if (frames[i].cols != cam.width * bin_ || frames[i].rows != cam.height * bin_)
        return InvalidArgument(
            "reconstruct: a frame is " + std::to_string(frames[i].cols) + "x" +
            std::to_string(frames[i].rows) + " but the calibration's camera is " +
            std::to_string(cam.width * bin_) + "x" + std::to_string(cam.height * bin_));
      D3D_RETURN_IF_ERROR(BinFrame(frames[i], bin_, &binned_frames_[i]));
      phase_frames_[i] = binned_frames_[i];
    }
  }
  return recon_.Reconstruct(phase_frames_, out);
}

ScanRegistrar::ScanRegistrar(const PinholeBrownConrady& camera, const TrackerOptions& options)
    : tracker_(camera, options) {}

ScanRegistrar::ScanRegistrar(const ProbeCalibration& calibration, const TrackerOptions& options,
                             const ModelAnchorOptions& anchor, double normal_max_gap_mm)
    : tracker_(calibration.camera, options) {
  if (anchor.enabled) {
    // Pixel counts are set for the 640 × 480 probe's fringe period, as the reconstruction's are.
    ModelAnchorOptions a = anchor;
    const double s = FringePeriodCamPx(calibration) / kReferenceFringePeriodCamPx;
    a.min_pixels = std::max(1, static_cast<int>(std::lround(a.min_pixels * s * s)));
    anchorer_ = std::make_unique<ModelAnchorer>(calibration, a, normal_max_gap_mm);
  }
}

TrackResult ScanRegistrar::Register(ReconstructedView& view, uint64_t burst_seq,
                                    int64_t reference_ns, bool bridge) {
  D3D_CHECK_MSG(given_poses_.empty(), "ScanRegistrar: Register after RegisterAtPose");
  const auto t0 = Clock::now();
  const int64_t index = static_cast<int64_t>(views_.size());
  // The tracker reads the view's own buffers, or copies without the edge-filled points; the
  // augmenter writes into the view, and then into the copies again.
  const bool copy = view.pixels_edge_filled > 0;
  if (copy) CopyWithoutEdgeFill(view);
  Tracker::ViewAugmenter augment;
  if (anchorer_) {
    augment = [&](const Rigid3d& world_from_cam, const PointMap& model) {
      ModelAnchorStats st;
      const int64_t n = anchorer_->Anchor(model, world_from_cam, &view, &st);
      ms_anchor_ += st.ms;
      pixels_anchored_ += n;
      views_anchored_ += n > 0;
      if (n > 0 && copy) CopyWithoutEdgeFill(view);
      return n > 0;
    };
  }
  TrackResult r = tracker_.Track(copy ? track_points_ : view.points_in_cam,
                                 copy ? track_normals_ : view.normals, view.quality, view.texture,
                                 augment, reference_ns);
  ms_ += MsSince(t0);  // with OdometryOptions::defer_model_insert, Commit() adds the insert's
  if (!bridge) ++(r.accepted ? accepted_ : rejected_);  // a bridge is not one of the scan's views
  if (r.state == TrackingState::kLost && prev_state_ != TrackingState::kLost) ++lost_events_;
  if (r.state == TrackingState::kRelocalised) ++relocalised_;
  auto event = [&](const std::string& reason) {
    nlohmann::json e = {{"view", index},
                        {"burst", burst_seq},
                        {"state", TrackingStateName(r.state)},
                        {"fused", r.accepted && r.in_main && !bridge},
                        {"reason", reason}};
    if (bridge) e["bridge"] = true;
    events_.push_back(std::move(e));
  };
  if (r.state != TrackingState::kTracking || !r.accepted || r.new_segment) event(r.reason);
  if (!r.join_attempt.empty()) event("segment join: " + r.join_attempt);  // joined, or why not
  state_before_last_ = prev_state_;
  prev_state_ = r.state;
  views_.push_back({burst_seq, reference_ns, r.accepted, r.state, bridge});
  return r;
}

bool ScanRegistrar::RetractLoss() {
  if (!tracker_.RetractLoss()) return false;
  retracted_counted_ =
      prev_state_ == TrackingState::kLost && state_before_last_ != TrackingState::kLost;
  if (retracted_counted_) --lost_events_;
  prev_state_ = tracker_.state();
  return true;
}

bool ScanRegistrar::ReinstateLoss() {
  const TrackingState was = tracker_.state();
  if (!tracker_.ReinstateLoss()) return false;
  if (was != TrackingState::kLost && tracker_.state() == TrackingState::kLost && retracted_counted_)
    ++lost_events_;
  prev_state_ = tracker_.state();
  return true;
}

void ScanRegistrar::Commit() { ms_ += tracker_.CommitView(); }

void ScanRegistrar::CopyWithoutEdgeFill(const ReconstructedView& view) {
  // copyTo into a buffer of the same size and type keeps its data, so the headers the tracker
  // holds during Track see the new values.
  view.points_in_cam.copyTo(track_points_);
  view.normals.copyTo(track_normals_);
  const uint8_t edge = static_cast<uint8_t>(QualityReason::kModulationEdge);
  const cv::Vec3f nan = cv::Vec3f::all(std::numeric_limits<float>::quiet_NaN());
  for (int r = 0; r < track_points_.rows; ++r) {
    const uint8_t* reason = view.quality_reason.ptr<uint8_t>(r);
    cv::Vec3f* p = track_points_.ptr<cv::Vec3f>(r);
    cv::Vec3f* n = track_normals_.ptr<cv::Vec3f>(r);
    for (int c = 0; c < track_points_.cols; ++c)
      if (reason[c] == edge) p[c] = n[c] = nan;
  }
}

int64_t ScanRegistrar::AnchorAtPose(const Rigid3d& world_from_cam, ReconstructedView* view) {
  return anchorer_ ? anchorer_->Anchor(tracker_.model(), world_from_cam, view) : 0;
}

void ScanRegistrar::RegisterAtPose(uint64_t burst_seq, int64_t reference_ns,
                                   const Rigid3d& world_from_cam) {
  D3D_CHECK_MSG(given_poses_.size() == views_.size(),
                "ScanRegistrar: RegisterAtPose after Register");
  given_poses_.push_back(world_from_cam);
  views_.push_back({burst_seq, reference_ns, true, TrackingState::kTracking});
  ++accepted_;
}

ScanRegistrar::UndoResult ScanRegistrar::UndoLastSeconds(double seconds) {
  UndoResult r;
  if (!given_poses_.empty()) {
    r.reason = "views given at known poses cannot be undone";
    return r;
  }
  int64_t last = static_cast<int64_t>(views_.size()) - 1;
  while (last >= 0 && !views_[static_cast<size_t>(last)].accepted) --last;
  if (last < 0) {
    r.reason = "no view to undo";
    return r;
  }
  // The first view captured within `seconds` of the newest accepted one.
  const int64_t end_ns = views_[static_cast<size_t>(last)].reference_ns;
  int64_t first = last;
  if (end_ns > 0) {
    const int64_t from_ns =
        end_ns - static_cast<int64_t>(std::llround(std::max(0.0, seconds) * 1e9));
    while (first > 0 && views_[static_cast<size_t>(first - 1)].reference_ns >= from_ns) --first;
  }
  Commit();  // a pending insert counts in what the journal reaches
  const int64_t reachable = tracker_.first_undoable_view();
  if (first < reachable) {
    first = reachable;
    r.clamped = true;
  }
  if (first > last) {
    r.reason = "the undo journal reaches no accepted view (OdometryOptions::map.undo_inserts)";
    return r;
  }
  const Tracker::UndoResult t = tracker_.UndoFrom(first);
  if (!t.ok) {
    r.reason = t.reason;
    return r;
  }
  for (size_t k = static_cast<size_t>(first); k < views_.size(); ++k) views_[k].accepted = false;
  r.ok = true;
  r.first_view = first;
  r.views_undone = t.views_undone;
  r.seconds_undone =
      static_cast<double>(end_ns - views_[static_cast<size_t>(first)].reference_ns) * 1e-9;
  accepted_ -= t.views_undone;
  views_undone_ += t.views_undone;
  prev_state_ = tracker_.state();  // the search that follows is not a tracking loss
  events_.push_back({{"view", first},
                     {"burst", views_[static_cast<size_t>(first)].burst_seq},
                     {"state", "undo"},
                     {"views_undone", t.views_undone},
                     {"keyframes_undone", t.keyframes_undone},
                     {"to_burst", views_[static_cast<size_t>(last)].burst_seq},
                     {"reason", r.clamped ? "undo (as far back as the journal reaches)" : "undo"}});
  return r;
}

int ScanRegistrar::ViewGroup(int64_t index) const {
  if (index < 0 || index >= static_cast<int64_t>(views_.size()) ||
      !views_[static_cast<size_t>(index)].accepted || views_[static_cast<size_t>(index)].bridge)
    return -1;
  if (!given_poses_.empty()) return 0;
  const int s = tracker_.ViewSegment(index);
  return s < 0 ? -1 : tracker_.SegmentInMain(s) ? 0 : s;
}

bool ScanRegistrar::ViewPose(int64_t index, Rigid3d* world_from_cam) const {
  if (index < 0 || index >= static_cast<int64_t>(views_.size())) return false;
  if (!given_poses_.empty()) {
    *world_from_cam = given_poses_[static_cast<size_t>(index)];
    return true;
  }
  return tracker_.ViewPose(index, world_from_cam);
}

ScanFuser::ScanFuser(const PinholeBrownConrady& camera, const TsdfOptions& options,
                     const FreeSpaceOptions& free_space)
    : camera_(camera),
      tsdf_(std::make_unique<TsdfVolume>(options)),
      free_space_(camera, free_space) {}

Status ScanFuser::Fuse(const ReconstructedView& view, const Rigid3d& world_from_cam) {
  const auto t0 = Clock::now();
  const cv::Mat* points = &view.points_in_cam;
  if (view.points_in_cam.type() == CV_32FC3 && view.points_in_cam.rows == camera_.height &&
      view.points_in_cam.cols == camera_.width) {
    const int64_t n = free_space_.TestAndRemember(view.points_in_cam, world_from_cam, &rejected_);
    if (n > 0) {
      view.points_in_cam.copyTo(masked_);
      masked_.setTo(cv::Scalar::all(std::numeric_limits<double>::quiet_NaN()), rejected_);
      points = &masked_;
      free_space_rejected_ += n;
    }
  }  // else Integrate reports the mismatch
  // The edge fill's points (pipeline/unwrap/edge_fill.h) are the volume's secondary points.
  const bool has_reason = tsdf_->options().secondary_fade_weight > 0 &&
                          view.quality_reason.type() == CV_8U &&
                          view.quality_reason.size() == view.points_in_cam.size();
  if (has_reason)
    cv::compare(view.quality_reason, static_cast<double>(QualityReason::kModulationEdge),
                secondary_, cv::CMP_EQ);
  const Status s = tsdf_->Integrate(*points, view.normals, view.quality, camera_, world_from_cam,
                                    has_reason ? secondary_ : cv::Mat());
  ms_ += MsSince(t0);
  if (s.ok()) ++fused_;
  return s;
}

void ScanFuser::AdoptVolume(ScanFuser&& other) {
  D3D_CHECK_MSG(other.tsdf_ != nullptr, "ScanFuser::AdoptVolume: the other fuser has no volume");
  tsdf_ = std::move(other.tsdf_);
  free_space_rejected_ = other.free_space_rejected_;  // the count of the volume's own views
}

ScanViewProvider KeptViewProvider(const ViewArchive& archive,
                                  const ProbeCalibration& view_calibration,
                                  const ReconstructOptions& options) {
  struct State {
    std::unique_ptr<ScanReconstructor> recon;
    std::vector<cv::Mat> frames;
  };
  auto state = std::make_shared<State>();
  return [&archive, view_calibration, options, state](int64_t, const ScanViewRecord& record,
                                                      ReconstructedView* out) -> Status {
    D3D_RETURN_IF_ERROR(archive.Get(record.burst_seq, &state->frames));
    if (!state->recon)
      state->recon = std::make_unique<ScanReconstructor>(view_calibration, options, 1);
    return state->recon->Reconstruct(state->frames, out);
  };
}

namespace {
// Fuses views `todo` (indices into the registrar's views) again into *into at poses[k]: each view
// got again from the provider and model-anchored at its tracked pose.
Status FuseViewsAgain(const ScanViewProvider& provider, ScanRegistrar* registrar,
                      const std::vector<Rigid3d>& tracked, const std::vector<int64_t>& todo,
                      const std::vector<Rigid3d>& poses, ScanFuser* into) {
  const std::vector<ScanViewRecord>& views = registrar->views();
  // Two threads: a helper gets each view again (provider) and anchors it while this thread fuses
  // the one before, in the same order as one thread would (the same volume bit for bit); two
  // view buffers between them. The helper alone calls the provider and the anchorer (the
  // registrar's model is only read meanwhile); this thread alone touches *into.
  struct Slot {
    ReconstructedView view;
    int64_t k = -1;
    Status status;
  };
  std::array<Slot, 2> slots;
  std::mutex mu;
  std::condition_variable cv;
  size_t produced = 0, consumed = 0;
  bool abort = false;
  std::thread helper([&] {
    for (const int64_t k : todo) {
      {
        std::unique_lock<std::mutex> lock(mu);
        cv.wait(lock, [&] { return produced - consumed < slots.size() || abort; });
        if (abort) return;
      }
      Slot& slot = slots[produced % slots.size()];
      slot.k = k;
      slot.status = provider(k, views[static_cast<size_t>(k)], &slot.view);
      // The model-anchored parts again, against the whole model and at the pose the model's
      // samples were inserted with (the tracked one): the order K does not depend on the pose.
      if (slot.status.ok()) registrar->AnchorAtPose(tracked[static_cast<size_t>(k)], &slot.view);
      const bool stop = !slot.status.ok() && slot.status.code() != StatusCode::kNotFound;
      {
        std::lock_guard<std::mutex> lock(mu);
        ++produced;
      }
      cv.notify_all();
      if (stop) return;
    }
  });
  Status failed = Status::Ok();
  for (size_t i = 0; i < todo.size() && failed.ok(); ++i) {
    {
      std::unique_lock<std::mutex> lock(mu);
      cv.wait(lock, [&] { return consumed < produced; });
    }
    Slot& slot = slots[consumed % slots.size()];
    if (slot.status.code() != StatusCode::kNotFound) {
      failed = slot.status.ok() ? into->Fuse(slot.view, poses[static_cast<size_t>(slot.k)])
                                : slot.status;
    }
    {
      std::lock_guard<std::mutex> lock(mu);
      ++consumed;
      abort = !failed.ok();
    }
    cv.notify_all();
  }
  helper.join();
  return failed;
}
}  // namespace

Status FinishScan(const ScanOptions& options, const ScanTimes& times, ScanRegistrar* registrar,
                  ScanFuser* fuser, const ScanViewProvider& provider, const ScanTruth& truth,
                  ScanResult* out) {
  *out = ScanResult{};
  Tracker& tracker = registrar->tracker();
  const std::vector<ScanViewRecord>& views = registrar->views();
  const int64_t n_views = static_cast<int64_t>(views.size());
  nlohmann::json& j = out->report;
  // Pose graph (loop closures): the correction it finds is reported; a large one means a step.
  PoseGraphSummary pg;
  double max_correction_mm = 0;
  // Segments still apart get a last join attempt first (Tracker::JoinApartSegments). The model is
  // then the largest group of views in one frame: the main segment with those joined to it, or a
  // segment apart with more views (the scan lost the model early and went on there; it needs its
  // views again: a provider). The other groups are saved on their own, never fused at a guess.
  int joined_at_end = 0;
  std::vector<std::string> join_attempts_at_end;
  if (tracker.segments() > 1) joined_at_end = tracker.JoinApartSegments(&join_attempts_at_end);
  std::map<int, int64_t> group_views;
  for (int64_t k = 0; k < n_views; ++k)
    if (const int g = registrar->ViewGroup(k); g >= 0) ++group_views[g];
  int model_group = 0;
  for (const auto& [g, count] : group_views)
    if (provider && count > group_views[model_group]) model_group = g;
  const Rigid3d model_from_group = tracker.MainFromSegmentFrame(model_group);
  auto in_main = [&](int64_t k) { return registrar->ViewGroup(k) == model_group; };
  std::vector<Rigid3d> tracked(views.size(), Rigid3d::Identity());
  for (int64_t k = 0; k < n_views; ++k) registrar->ViewPose(k, &tracked[static_cast<size_t>(k)]);
  const bool loops = options.tracker.keyframes.detect_loops && tracker.graph().num_nodes() > 1;
  if (loops) {
    D3D_RETURN_IF_ERROR(tracker.Optimize({}, &pg));
    for (int64_t k = 0; k < n_views; ++k) {
      Rigid3d p;
      if (in_main(k) && registrar->ViewPose(k, &p))
        max_correction_mm =
            std::max(max_correction_mm, TranslationDistanceMm(p, tracked[static_cast<size_t>(k)]));
    }
  }
  // Refusion at the optimised poses, when the views can be had again.
  std::unique_ptr<ScanFuser> refused;
  double ms_refuse = 0;
  // Undone views are still in the fuser's volume: only the kept views fused again leave them out.
  const bool undone = registrar->views_undone() > 0;
  if (undone && !provider)
    return Status(StatusCode::kInvalidArgument,
                  "views were undone but there is no view provider to fuse the kept ones again");
  // A live volume of another voxel than the scan's (a host's coarse live model) is never the
  // result.
  const bool other_voxel = fuser->volume().options().voxel_mm != options.tsdf.voxel_mm;
  if (other_voxel && !provider)
    return Status(StatusCode::kInvalidArgument,
                  "the live volume's voxel (" + std::to_string(fuser->volume().options().voxel_mm) +
                      " mm) is not the scan's (" + std::to_string(options.tsdf.voxel_mm) +
                      " mm) and there is no view provider to fuse the views again");
  // A segment's views are fused live only once it is joined (TrackResult::in_main): a joined one
  // makes the live volume incomplete.
  const bool joined = tracker.segments_joined() > 0;
  if (joined && !provider)
    return Status(StatusCode::kInvalidArgument,
                  "segments were joined but there is no view provider to fuse their views");
  // A loop corrected during the scan moved the views after it into another frame than the ones
  // fused before it: fused again when they can be had (without a provider the live volume stays
  // the model, its views up to loop_correction_max_shift_mm apart; fused_again_at_optimised_poses
  // says which).
  const bool corrected = tracker.loop_corrections() > 0;
  const bool must_refuse = undone || other_voxel || joined || corrected || model_group != 0;
  if (provider && (must_refuse || (loops && options.refuse_min_correction_mm >= 0 &&
                                   max_correction_mm > options.refuse_min_correction_mm))) {
    const auto t0 = Clock::now();
    refused =
        std::make_unique<ScanFuser>(fuser->camera(), options.tsdf, fuser->free_space_options());
    std::vector<Rigid3d> poses(views.size(), Rigid3d::Identity());
    std::vector<int64_t> todo;
    for (int64_t k = 0; k < n_views; ++k)
      if (in_main(k) && registrar->ViewPose(k, &poses[static_cast<size_t>(k)])) {
        poses[static_cast<size_t>(k)] = model_from_group * poses[static_cast<size_t>(k)];
        todo.push_back(k);
      }
    D3D_RETURN_IF_ERROR(FuseViewsAgain(provider, registrar, tracked, todo, poses, refused.get()));
    ms_refuse = MsSince(t0);
  }
  // Both volumes are held only until the refusion is complete; on an error above, the live model
  // is untouched. The refused volume then becomes the model and the live one is freed.
  const double tsdf_memory_mib =
      static_cast<double>(fuser->volume().MemoryBytes() +
                          (refused ? refused->volume().MemoryBytes() : 0)) /
      (1024.0 * 1024.0);
  const bool refused_at_optimised_poses = refused != nullptr;
  if (refused) {
    fuser->AdoptVolume(std::move(*refused));
    refused.reset();
  }
  std::vector<Rigid3d> final_poses(views.size(), Rigid3d::Identity());
  for (int64_t k = 0; k < n_views; ++k)
    if (registrar->ViewPose(k, &final_poses[static_cast<size_t>(k)]) && in_main(k))
      final_poses[static_cast<size_t>(k)] = model_from_group * final_poses[static_cast<size_t>(k)];
  const TsdfVolume& model = fuser->volume();
  const auto tm0 = Clock::now();
  out->mesh = model.ExtractMesh();
  if (out->mesh.faces.empty())
    return Status(StatusCode::kInternal, "the fused model is empty (no view was accepted)");
  const MeshCleanReport cleaned = CleanMesh(options.mesh_clean, &out->mesh);
  const double ms_mesh = MsSince(tm0);
  if (out->mesh.faces.empty())
    return Status(StatusCode::kInternal,
                  "the fused model is empty after its specks were removed (no piece of " +
                      std::to_string(options.mesh_clean.min_piece_area_mm2) + " mm2)");
  out->mesh.ComputeVertexNormals();
  std::vector<Rigid3d> acc_truth;
  bool have_truth_poses = static_cast<bool>(truth.true_pose);
  for (int64_t k = 0; k < n_views; ++k) {
    const ScanViewRecord& v = views[static_cast<size_t>(k)];
    if (!v.accepted || !in_main(k)) continue;
    out->pose_t_ns.push_back(v.reference_ns);
    out->poses.push_back(final_poses[static_cast<size_t>(k)]);
    out->pose_views.push_back(k);
    if (have_truth_poses) {
      Rigid3d t;
      if (truth.true_pose(v, &t))
        acc_truth.push_back(t);
      else
        have_truth_poses = false;
    }
  }
  // The other groups (segments that never joined, or the main one when a segment apart became the
  // model): each fused on its own in its own frame, when the views can be had again.
  int64_t views_apart = 0;
  for (const auto& [s, count] : group_views) {
    if (s == model_group) continue;
    std::vector<int64_t> todo;
    for (int64_t k = 0; k < n_views; ++k)
      if (registrar->ViewGroup(k) == s) todo.push_back(k);
    views_apart += static_cast<int64_t>(todo.size());
    if (!provider || todo.empty()) continue;
    ScanFuser apart(fuser->camera(), options.tsdf, fuser->free_space_options());
    D3D_RETURN_IF_ERROR(FuseViewsAgain(provider, registrar, tracked, todo, final_poses, &apart));
    ScanSegmentMesh m;
    m.segment = s;
    m.views = static_cast<int64_t>(todo.size());
    m.mesh = apart.volume().ExtractMesh();
    if (!m.mesh.faces.empty()) CleanMesh(options.mesh_clean, &m.mesh);
    m.mesh.ComputeVertexNormals();
    out->apart.push_back(std::move(m));
  }
  const double n = static_cast<double>(std::max<int64_t>(times.bursts, 1));
  j["bursts"] =
      std::count_if(views.begin(), views.end(), [](const ScanViewRecord& v) { return !v.bridge; });
  j["segments_started"] =
      tracker.segments() - 1;  // segments after the first (SegmentOptions::after_views)
  j["segments_joined"] = tracker.segments_joined();
  j["segments_joined_at_end"] = joined_at_end;
  j["segment_joins_at_end"] = join_attempts_at_end;  // what each last attempt found
  j["segments_apart"] = static_cast<int64_t>(group_views.size()) -
                        (group_views.empty() ? 0 : 1);  // saved as segment_N.ply
  j["views_apart"] = views_apart;
  j["model_segment"] = model_group;  // 0: the first segment (with those joined to it) is the model
  j["views_in_model"] = static_cast<int64_t>(out->poses.size());
  j["fused"] = fuser->fused();
  j["rejected"] = registrar->rejected();
  j["views_undone"] = registrar->views_undone();
  j["undo_journal_mib"] = static_cast<double>(tracker.model().journal_bytes()) /
                          (1024.0 * 1024.0);  // OdometryOptions::map.undo_inserts
  j["keyframes_mib"] = static_cast<double>(tracker.keyframe_bytes()) /
                       (1024.0 * 1024.0);  // samples, features, packed feature inputs
  j["model_samples"] =
      tracker.model().size();  // the tracking model's samples (one per 0.08 mm voxel)
  j["tracking_lost"] = registrar->lost_events();
  j["relocalised"] = registrar->relocalised();
  j["views_model_anchored"] = registrar->views_model_anchored();
  j["pixels_model_anchored"] = registrar->pixels_model_anchored();
  j["ms_model_anchor_per_burst"] =
      registrar->ms_model_anchor() / std::max<double>(1.0, static_cast<double>(n_views));
  j["unrecovered"] = tracker.state() == TrackingState::kLost ? 1 : 0;
  j["final_state"] = TrackingStateName(tracker.state());
  j["keyframes"] = tracker.keyframes().size();
  j["keyframes_reused"] =
      tracker.keyframes_reused();  // times an older keyframe became current again
  j["loop_edges"] = tracker.loop_edges();
  j["loop_corrections"] = tracker.loop_corrections();
  j["loop_correction_max_shift_mm"] = tracker.max_loop_shift_mm();
  j["loop_correction_solves"] = tracker.loop_optimisations();
  j["ms_loop_correction_total"] = tracker.ms_loop_correction();
  j["pose_graph_max_correction_mm"] = max_correction_mm;
  j["pose_graph_disagreeing_edges"] = pg.disagreeing_edges.size();
  j["ms_per_burst"] = (times.ms_recon + times.ms_register + times.ms_fuse) / n;
  j["ms_recon_per_burst"] = times.ms_recon / n;
  j["ms_register_per_burst"] = times.ms_register / n;
  j["ms_fuse_per_burst"] = times.ms_fuse / n;
  j["ms_mesh"] = ms_mesh;
  j["voxel_mm"] = model.options().voxel_mm;
  j["fused_again_at_optimised_poses"] = refused_at_optimised_poses;
  j["ms_fuse_again_total"] = ms_refuse;
  j["tsdf_active_voxels"] = model.ActiveVoxels();
  j["tsdf_secondary_leaves"] =
      model.SecondaryLeaves();  // where edge-filled points still shape the surface (tsdf.h)
  j["points_occluded"] = model.occluded_points();  // not fused: behind a known surface (tsdf.h)
  j["points_free_space_rejected"] =
      fuser->free_space_rejected();        // not fused: in seen-through space (free_space.h)
  j["tsdf_memory_mib"] = tsdf_memory_mib;  // both volumes at the end of a refusion
  j["mesh_vertices"] = out->mesh.vertices.size();
  j["mesh_faces"] = out->mesh.faces.size();
  // What the lab's cleaning did (MeshCleanOptions): specks removed, bow-tie vertices split.
  j["mesh_pieces"] = cleaned.pieces_kept;
  j["mesh_specks_removed"] = cleaned.pieces_removed;
  j["mesh_speck_faces_removed"] = cleaned.faces_removed;
  j["mesh_vertices_split"] = cleaned.vertices_split;
  j["events"] = registrar->events();
  if (truth.reference != nullptr && !truth.reference->faces.empty() && !out->poses.empty())
    EvaluateScanAgainstScene(out->mesh, *truth.reference, out->poses,
                             have_truth_poses ? acc_truth : std::vector<Rigid3d>{},
                             ViewFootprint(fuser->camera(), options.eval.footprint_depth_mm),
                             options.eval, &j, &out->heatmap);
  return Status::Ok();
}

void EvaluateScanAgainstScene(const TriangleMesh& mesh, const TriangleMesh& scene,
                              const std::vector<Rigid3d>& poses,
                              const std::vector<Rigid3d>& true_poses,
                              const std::vector<Eigen::Vector3d>& footprint_in_cam,
                              const EvaluateOptions& options, nlohmann::json* report,
                              cv::Mat* heatmap) {
  nlohmann::json& j = *report;
  const bool have_truth_poses = !true_poses.empty() && true_poses.size() == poses.size();
  const MeshClosestPoint ref(scene);
  Rigid3d world_from_model = Rigid3d::Identity();
  AteReport ate_traj;
  if (have_truth_poses)
    ate_traj = AbsoluteTrajectoryError(poses, true_poses, &world_from_model);
  else
    world_from_model = GlobalAlign(mesh, ref);
  const TruenessReport t = EvaluateTrueness(mesh, ref, world_from_model, options);
  j["best_fit_start"] = have_truth_poses ? "trajectory" : "global_align";
  if (have_truth_poses) {
    // ATE in the frame of the surface best fit (the trajectory-only alignment is ill-posed for
    // short, nearly straight paths); the trajectory-aligned figure is kept too.
    // Wrong fusions (kWrongFusionMm, kWrongFusionDeg) judge the view's footprint (ViewFootprint);
    // the camera centre's count is kept beside them for comparison with earlier reports.
    double s2 = 0, sr = 0, smax = 0, rmax = 0, fmax = 0;
    int64_t wrong = 0, wrong_by_centre = 0;
    nlohmann::json wrong_views = nlohmann::json::array();  // the first 50: where to look
    for (size_t k = 0; k < poses.size(); ++k) {
      const Rigid3d e = t.reference_from_scan * poses[k];
      const double d = TranslationDistanceMm(e, true_poses[k]);
      const double f = FootprintDistanceMm(e, true_poses[k], footprint_in_cam);
      const double r = RotationAngleRad(e, true_poses[k]) * 180 / M_PI;
      s2 += d * d;
      smax = std::max(smax, d);
      fmax = std::max(fmax, f);
      rmax = std::max(rmax, r);
      sr += r;
      wrong_by_centre += d > kWrongFusionMm || r > kWrongFusionDeg;
      if (f > kWrongFusionMm || r > kWrongFusionDeg) {
        ++wrong;
        if (wrong_views.size() < 50)
          wrong_views.push_back({{"pose", k}, {"mm", f}, {"centre_mm", d}, {"deg", r}});
      }
    }
    j["ate_mm"] = std::sqrt(s2 / static_cast<double>(poses.size()));
    j["ate_deg"] = sr / static_cast<double>(poses.size());
    j["ate_max_mm"] = smax;
    j["ate_max_deg"] = rmax;
    j["footprint_max_mm"] = fmax;  // the largest footprint error of any fused view
    j["wrong_fusions"] =
        wrong;  // fused views whose footprint is off by > 0.2 mm, or turned > 1 deg
    j["wrong_fusions_by_camera_centre"] = wrong_by_centre;  // the same rule at the camera centre
    j["wrong_fusion_views"] =
        wrong_views;  // pose: line of poses.txt (0-based, after the header); mm: footprint
    j["ate_trajectory_aligned_mm"] = ate_traj.rmse_mm;
    j["ate_trajectory_aligned_deg"] = ate_traj.mean_deg;
    // Where the trajectory jumped (views in poses.txt order, 0-based): see RelativePoseError.
    const RpeReport rpe = RelativePoseError(poses, true_poses);
    j["rpe_mm"] = rpe.rmse_mm;
    j["rpe_deg"] = rpe.mean_deg;
    j["rpe_max_mm"] = rpe.max_mm;
    j["rpe_max_pose"] = rpe.max_pose;
  }
  AddTruenessFields(t, &j);
  j["trueness_points"] = t.points;
  j["trueness_outlier_pct"] = t.outlier_pct;
  if (heatmap != nullptr) {
    TriangleMesh in_ref = mesh;
    for (auto& v : in_ref.vertices) v = t.reference_from_scan * v;
    *heatmap = DeviationHeatMap(in_ref, t.signed_um, 50);
  }
}

Status WriteTumPoses(const std::string& path, const std::vector<int64_t>& t_ns,
                     const std::vector<Rigid3d>& poses) {
  std::ofstream f(path);
  if (!f) return IoError("cannot write '" + path + "'");
  f << "# timestamp_s tx ty tz qx qy qz qw (translation in mm; model_from_probe, model = first "
       "view's camera)\n";
  char stamp[48];
  for (size_t i = 0; i < poses.size() && i < t_ns.size(); ++i) {
    std::snprintf(stamp, sizeof stamp, "%lld.%09lld", static_cast<long long>(t_ns[i] / 1000000000),
                  static_cast<long long>(t_ns[i] % 1000000000));
    f << stamp << ' ' << TumPoseFields(poses[i]) << '\n';
  }
  return f ? Status::Ok() : IoError("write failed: '" + path + "'");
}

Status WriteScanOutputs(const std::string& dir, const ScanResult& result) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return IoError("cannot create '" + dir + "'");
  D3D_RETURN_IF_ERROR(SavePlyBinary((fs::path(dir) / "scan.ply").string(), result.mesh));
  D3D_RETURN_IF_ERROR(SaveStlBinary((fs::path(dir) / "scan.stl").string(), result.mesh));
  D3D_RETURN_IF_ERROR(
      WriteTumPoses((fs::path(dir) / "poses.txt").string(), result.pose_t_ns, result.poses));
  for (const ScanSegmentMesh& m : result.apart)
    if (!m.mesh.faces.empty())
      D3D_RETURN_IF_ERROR(SavePlyBinary(
          (fs::path(dir) / ("segment_" + std::to_string(m.segment) + ".ply")).string(), m.mesh));
  if (!result.heatmap.empty() &&
      !cv::imwrite((fs::path(dir) / "heatmap.png").string(), result.heatmap))
    return IoError("cannot write heatmap.png in '" + dir + "'");
  std::ofstream f(fs::path(dir) / "report.json");
  f << result.report.dump(2) << "\n";
  return f ? Status::Ok() : IoError("cannot write report.json in '" + dir + "'");
}

}  // namespace d3d
