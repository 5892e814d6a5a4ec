// What the live preview shows, as plain data (no GL): the fused model as decimated points with
// normals (append-only between resets), the current view, the probe pose and frustum, and the
// status line. The host's preview stage fills PreviewSnapshots in a TripleBuffer
// (host/graph/edges.h); the render thread reads the newest one without ever waiting.
//
// Frames and units: model frame (the first accepted view's camera frame), mm.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

namespace d3d {

// The colour cue of the preview (tracking states of pipeline/register plus the host's own).
// kNewSegment: the scan goes on in a segment of its own (the model could not be found there), to be
// joined to the model once they overlap (SegmentOptions::after_views).
enum class PreviewCue : uint8_t {
  kWaiting,
  kTracking,
  kLost,
  kRelocalised,
  kProbeLost,
  kPaused,
  kNewSegment,
  kSlowDown,
  kLostSlowDown
};
// "WAITING FOR PROBE", "TRACKING", "LOST", "RELOCALISED", "PROBE LOST", "PAUSED", "NEW SEGMENT",
// "SLOW DOWN" (tracking, but the host keeps too few bursts for the probe's speed:
// host/app/pace_monitor.h), "LOST - SLOW DOWN" (lost, and the host keeps too few bursts to track at
// the probe's pace)
const char* PreviewCueText(PreviewCue c);

struct PreviewSnapshot {
  uint64_t generation = 0;  // bumps on a model reset or an undo: points are copied anew
  std::vector<Eigen::Vector3f>
      points;  // model, decimated (one per preview cell), append-only within a generation
  std::vector<Eigen::Vector3f> normals;  // unit, per point
  // The scan segment being built apart from the model (SegmentOptions::after_views; cue
  // kNewSegment), decimated, drawn in the segment colour where the model was lost: placed, not
  // registered (TrackResult::display_from_cam). Append-only within a segment_generation.
  uint64_t segment_generation = 0;
  std::vector<Eigen::Vector3f> segment_points, segment_normals;
  std::vector<Eigen::Vector3f>
      view_points;             // the latest view (decimated), model frame (apart: beside it)
  bool view_accepted = false;  // the latest view was fused (else refused: drawn red)
  bool have_pose = false;
  Eigen::Matrix4f model_from_cam = Eigen::Matrix4f::Identity();  // the latest view's probe pose
  float tan_half_x = 0.16f, tan_half_y = 0.12f;  // camera field (frustum), tan of the half angles
  float near_mm = 42, far_mm = 58;               // measurement volume along the optical axis
  PreviewCue cue = PreviewCue::kWaiting;
  uint64_t bursts_in_model = 0;  // views in the model (accepted, not undone)
  uint64_t last_burst_seq = 0;
  double model_area_mm2 = 0;  // preview cells × cell area: the scan's coverage so far
};

// When the preview's status panel is drawn again. Its counters change with every burst, and its
// anti-aliased text was the render thread's largest cost on a software renderer (d3d-bench-preview:
// ~60 % of the thread's CPU when redrawn every frame), so a change of the text alone is shown at
// most every period_ns; a change of cue or message (tracking lost, "saved …") at once.
// Thread: the render thread's.
class PanelRefresh {
 public:
  explicit PanelRefresh(int64_t period_ns = 250'000'000) : period_ns_(period_ns) {}
  // True when the panel must be drawn again at now_ns (any monotonic clock, ns), and then counts
  // it as drawn: the first call, `force`, a new cue or message, or a new text with period_ns
  // passed since the last draw.
  bool Due(PreviewCue cue, const std::string& message, const std::string& text, int64_t now_ns,
           bool force);

 private:
  int64_t period_ns_;
  bool drawn_ = false;
  PreviewCue cue_ = PreviewCue::kWaiting;
  std::string message_, text_;
  int64_t drawn_ns_ = 0;
};

// Counters the render thread reads each frame (atomics behind it; see host/app/scan_app.h).
struct PreviewStatus {
  PreviewCue cue_override =
      PreviewCue::kTracking;  // kProbeLost / kPaused / kWaiting override the snapshot's cue
  bool override_cue = false;
  uint64_t bursts_received = 0, bursts_processed = 0, bursts_fused = 0, bursts_dropped = 0,
           bursts_rejected = 0;
  double bursts_per_s = 0, latency_ms_p50 = 0, latency_ms_p95 = 0;
  std::string message;  // transient line (e.g. "saved scan.ply")
};

}  // namespace d3d
