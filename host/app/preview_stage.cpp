#include "host/app/preview_stage.h"

#include <cmath>

namespace d3d {
namespace {

PreviewCue CueOf(TrackingState s) {
  switch (s) {
    case TrackingState::kTracking:
      return PreviewCue::kTracking;
    case TrackingState::kLost:
      return PreviewCue::kLost;
    case TrackingState::kRelocalised:
      return PreviewCue::kRelocalised;
    case TrackingState::kInitialising:
      return PreviewCue::kWaiting;
  }
  return PreviewCue::kWaiting;
}

}  // namespace

PreviewStage::PreviewStage(const ProbeCalibration& view_calibration,
                           const PreviewModelOptions& model, int view_stride_px,
                           const UndoLog* undo)
    : calibration_(view_calibration), view_stride_px_(view_stride_px), undo_(undo), model_(model) {
  recent_latency_ms_.reserve(64);
}

bool PreviewStage::Run(ScanItem& item) {
  if (item.epoch != epoch_) {
    model_.Reset();
    pace_.Reset();
    epoch_ = item.epoch;
  }
  if (item.undo_gen > undo_gen_) {
    model_.Undo(undo_->Cut(undo_gen_, item.undo_gen));
    undo_gen_ = item.undo_gen;
  }
  if (!item.control)
    model_.AddView(item.view_index, item.track, item.view.points_in_cam, item.view.normals);
  mem_preview_points_.store(model_.model_points(), std::memory_order_relaxed);
  // A view of a segment not joined yet is drawn beside the model (display_from_cam), in its colour.
  const bool apart = !item.control && item.track.accepted && !item.track.in_main;
  const Eigen::Matrix4f model_from_cam =
      (apart ? item.track.display_from_cam : item.track.world_from_cam).matrix().cast<float>();
  const Eigen::Matrix3f r = model_from_cam.topLeftCorner<3, 3>();
  const Eigen::Vector3f t = model_from_cam.topRightCorner<3, 1>();
  const cv::Mat& pts = item.view.points_in_cam;
  PreviewSnapshot& s = snapshots_.Back();
  model_.CopyTo(&s);
  s.view_points.clear();
  for (int y = view_stride_px_ / 2; !item.control && y < pts.rows; y += view_stride_px_) {
    const auto* p = pts.ptr<cv::Vec3f>(y);
    for (int x = view_stride_px_ / 2; x < pts.cols; x += view_stride_px_)
      if (std::isfinite(p[x][2]))
        s.view_points.push_back(r * Eigen::Vector3f(p[x][0], p[x][1], p[x][2]) + t);
  }
  s.view_accepted = item.track.accepted;
  // A control item (undo) has no view: no probe pose until the next burst.
  s.have_pose =
      !item.control && (item.track.state != TrackingState::kInitialising || item.track.accepted);
  s.model_from_cam = model_from_cam;
  const PinholeBrownConrady& cam = calibration_.camera;
  s.tan_half_x = static_cast<float>(0.5 * cam.width / cam.fx);
  s.tan_half_y = static_cast<float>(0.5 * cam.height / cam.fy);
  s.near_mm = static_cast<float>(calibration_.depth_min_mm);
  s.far_mm = static_cast<float>(calibration_.depth_max_mm);
  // The host keeping too few bursts for how fast the probe moves, or so few that the track fails,
  // says so (pace_monitor.h): while tracking, and while lost, where slowing down is how the track
  // comes back.
  const bool tracked = !item.control && item.track.accepted &&
                       item.track.state == TrackingState::kTracking && !apart;
  const bool lost = !item.control && !item.track.accepted &&
                    item.track.state == TrackingState::kLost && !item.track.too_few_points;
  const bool slow_down =
      !item.control && pace_.Add(item.burst.burst_seq, item.burst.capture_ns,
                                 tracked ? &item.track.world_from_cam : nullptr, lost);
  if (!item.control) pace_advices_.store(pace_.advices(), std::memory_order_relaxed);
  PreviewCue cue = apart ? PreviewCue::kNewSegment : CueOf(item.track.state);
  if (slow_down && cue == PreviewCue::kTracking) cue = PreviewCue::kSlowDown;
  if (slow_down && cue == PreviewCue::kLost) cue = PreviewCue::kLostSlowDown;
  s.cue = cue;
  s.bursts_in_model = model_.views_in_model();
  if (!item.control) last_burst_seq_ = item.burst.burst_seq;
  s.last_burst_seq = last_burst_seq_;
  s.model_area_mm2 = model_.model_area_mm2();
  snapshots_.Publish();
  return true;
}

void PreviewStage::AddLatency(double lat) {
  // Status line: percentiles of the latest 64 latencies (the graph's, of the bursts before this
  // one).
  if (recent_latency_ms_.size() < 64)
    recent_latency_ms_.push_back(lat);
  else
    recent_latency_ms_[recent_next_++ % 64] = lat;
  recent_p50_.store(PercentileOf(recent_latency_ms_, 50), std::memory_order_relaxed);
  recent_p95_.store(PercentileOf(recent_latency_ms_, 95), std::memory_order_relaxed);
}

void PreviewStage::Memory(ScanMemory* m) const {
  m->preview_points = mem_preview_points_.load(std::memory_order_relaxed);
}

}  // namespace d3d
