// Scan segments: when views cannot be placed on the model, the scan does not stop and does not
// guess. After SegmentOptions::after_views views in a row refused while lost (each with enough
// points), the next such view starts a segment in a frame of its own (the main frame moved by
// s · kSegmentSpacingMm along x, odometry.h: the segments never meet in the model, the keyframe
// searches or the pose graph), and the track goes on there. Every join_every new keyframes of a
// segment not joined yet, it is registered onto the main model (segment_join.h: FPFH + RANSAC +
// ICP; when FPFH finds nothing, keyframe features against join_feature_keyframes main keyframes per
// attempt, in turn; at the end of the scan also FPFH on finer keypoints, join_fine_at_end, and
// from the segment's first keyframes put at every main keyframe's camera, join_starts_at_end); the
// Tracker verifies the join like a re-entry (relocaliser.h), and then the segment's keyframes and
// model samples move into the main frame and a loop edge joins it to the main keyframes (Merge).
// Undo (Tracker::UndoFrom) does not reach back past a segment's start or join.
//
// Owns: the segment list (first view, joined, join-attempt bookkeeping), the active segment, the
// count of views refused in a row, the undo barrier and the main model's join features (made when a
// segment starts: the main model rests meanwhile). It reads and, on a join, rewrites the tracking
// model (odometry.h) and the keyframes' poses and edges (keyframe_graph.h). Track()'s thread only.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "pipeline/register/keyframe_graph.h"
#include "pipeline/register/odometry.h"
#include "pipeline/register/segment_join.h"
#include "pipeline/register/track_result.h"

namespace d3d {

struct SegmentOptions {
  // Views refused in a row while lost before the next starts a segment; 0 = never: the tracker
  // stays lost until a view re-enters the model.
  int after_views = 8;
  int max_segments = 16;  // the main one included
  int join_every = 1;     // new keyframes of a segment apart between join attempts
  int join_feature_keyframes =
      8;  // main keyframes the feature join tries per attempt; 0: FPFH only
  // The end of the scan's last try for a segment still apart (JoinApartSegments), when FPFH and the
  // features found nothing: the probe may have come back over ground scanned long before, far from
  // where the track was lost (a quadrant started again from the incisors the scan began on). Each
  // of the segment's first join_starts_at_end keyframes is put where each main keyframe's camera
  // was, ICP (a wide first gate, join_start_gate_mm) holds it there or not, and the segment is
  // refined from every start that held (RefineSegmentJoin); two refined joins apart (the FPFH
  // ambiguity distances) refuse. 0 = off.
  int join_starts_at_end = 3;
  double join_start_gate_mm = 3.0;
  // The end of the scan's last try, before the starts: FPFH once more on finer keypoints of both
  // models (join_fine_fpfh; the main model's are made for each segment's last try, ~0.4 s for a
  // full arch), refined and verified like every join. false = off.
  bool join_fine_at_end = true;
  FpfhOptions join_fine_fpfh = FineDentalFpfh();
  SegmentJoinOptions join;
  void Check() const;  // throws std::invalid_argument
};

class Segments {
 public:
  // by_features: a join may fall back to keyframe features (they exist). Throws for invalid
  // options.
  Segments(const SegmentOptions& options, Odometry* odometry, KeyframeGraph* keyframes,
           bool by_features);
  const SegmentOptions& options() const { return o_; }

  int size() const { return static_cast<int>(segments_.size()); }
  int active() const { return active_; }
  int joined() const;  // segments joined to the main one
  // Whether segment s lies in the main frame (the first, or joined to it).
  bool InMain(int segment) const;
  // Whether keyframe k lies in the active segment's frame (the local and feature searches' scope).
  bool KeyframeInActive(int k) const;
  // Segment s's frame moved back to the main frame's origin (a translation: not a registration);
  // identity for the main one.
  Rigid3d MainFromSegmentFrame(int segment) const;
  bool StartsAt(int64_t view) const;  // view `view` started a segment (> 0)
  int64_t undo_barrier_view() const { return undo_barrier_view_; }

  // Views refused in a row while lost (with enough points).
  int refused_in_row() const { return refused_in_row_; }
  void set_refused_in_row(int views) { refused_in_row_ = views; }
  // One more view refused while lost: true when it is to start a segment.
  bool CountRefused();
  // Whether the active segment, apart, is due a join attempt (join_every new keyframes since the
  // last); the attempt is counted.
  bool JoinDue();

  // Starts a segment with view `view` (accepted, the track's last pose `last_pose` in the active
  // segment's frame): *pose gets that pose in the new frame; out->state, new_segment and reason
  // set.
  void Start(int64_t view, const Rigid3d& last_pose, Rigid3d* pose, TrackResult* out);
  // Registers segment s onto the main model: true with the join (*join, main_from_segment), the
  // segment keyframe it rests on (*anchor: the newest, or the one the start held) and *how it was
  // found; false with *why. at_end: also the end of the scan's starts (join_starts_at_end).
  bool FindJoin(int s, bool at_end, SegmentJoinResult* join, int* anchor, std::string* how,
                std::string* why);
  // The newest keyframe made in segment s, −1 when it has none.
  int NewestKeyframe(int s) const;
  // Merges a verified join of segment s (main_from_segment T, resting on segment keyframe
  // `anchor`) before view `view`: its keyframes and model samples move into the main frame, edges
  // join the anchor to the main keyframes, and undo starts again after the view.
  void Merge(int s, const Rigid3d& T, int anchor, int64_t view);
  // The main model's join features made again from the model as it is now (JoinApartSegments).
  void RefreshJoinTarget();

 private:
  SurfacePoints MainSamples() const;  // the main model's samples (world)
  // The join's second way: keyframe features of the segment's newest keyframe against main
  // keyframes in turn, refined by RefineSegmentJoin on `seg`.
  SegmentJoinResult JoinByFeatures(int s, int newest, const SegmentJoinTarget& seg,
                                   std::string* why);
  // The join's third way, at the end of the scan (SegmentOptions::join_starts_at_end).
  SegmentJoinResult JoinFromKeyframeStarts(int s, const SegmentJoinTarget& seg, int* anchor,
                                           std::string* why);

  SegmentOptions o_;
  Odometry& odometry_;
  KeyframeGraph& keyframes_;
  bool by_features_;
  // [0] the first; a segment's first view, whether it was joined to the main model, the keyframe
  // count at its last join attempt, and the next main keyframe the feature join tries.
  struct Segment {
    int64_t first_view = 0;
    bool joined = false;
    size_t keyframes_at_attempt = 0;
    size_t feature_cursor = 0;
  };
  std::vector<Segment> segments_ = {Segment{}};
  int active_ = 0;
  int refused_in_row_ = 0;
  int64_t undo_barrier_view_ = 0;  // UndoFrom does not reach before this view
  SegmentJoinTarget join_target_;  // the main model's join features
};

}  // namespace d3d
