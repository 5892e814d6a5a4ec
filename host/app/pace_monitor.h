// Whether the dentist should slow down: the host keeps too few of the probe's bursts for how fast
// the probe moves (issue 51: when the machine cannot keep up, the host degrades gracefully and says
// so).
//
// Why: a host that cannot process every burst (a slow machine, another load) keeps a subset of
// them; the tracker then registers views further apart. At 30 Hz with every burst kept the probe
// moves ~0.3 mm between views at 10 mm/s; keeping 1 burst in 5, 1.7 mm, near the tracker's coarse
// ICP gate (TrackerOptionsForStep: 0.8·√step mm), beyond which the track is lost and the scan goes
// on in segments. Slowing the hand is what the dentist can do about it.
//
// Rule, over the processed views of the last window_s of capture time: the host kept less than
// max_kept_share of the bursts the probe sent (from the bursts' sequence numbers), and either the
// median translation between consecutive tracked views exceeds min_step_mm, or the track already
// fails at this pace: at least min_lost_views of the window's views, and more than half, had points
// the tracker could not place (a host that falls far behind keeps views too far apart to track, and
// then has no steps to measure: 1 burst in 15 on a slow machine, docs/decisions/0006). The advice
// then holds until the rule has not held for hold_s (no flicker).
//
// Threads: one thread's (the preview stage's).
#pragma once

#include <cstdint>
#include <deque>
#include <vector>

#include "common/core/rigid.h"

namespace d3d {

struct PaceOptions {
  double window_s = 1.0;        // capture time the rule looks back over
  double max_kept_share = 0.6;  // the host kept fewer of the probe's bursts than this ...
  // ... and the median step between tracked views exceeds this: half the live tracker's coarse ICP
  // gate (TrackerOptionsForStep at d3d-scan's live step 6: 0.8·√6 = 1.96 mm).
  double min_step_mm = 1.0;
  double hold_s = 1.0;  // an advice stays this long after the rule last held
  int min_views = 4;    // views in the window before an advice by the step
  int min_lost_views =
      2;               // views the tracker could not place, in the window, before an advice by them
  void Check() const;  // throws std::invalid_argument
};

class PaceMonitor {
 public:
  explicit PaceMonitor(const PaceOptions& options = {});
  // One processed view, in order: the burst's sequence number and capture time (ns), and its pose
  // when it was tracked (accepted while tracking; else nullptr: the view only counts as kept);
  // lost: the view had points the tracker could not place (refused while lost, not for too few
  // points). Returns whether the dentist should slow down now.
  bool Add(uint64_t burst_seq, int64_t capture_ns, const Rigid3d* world_from_cam,
           bool lost = false);
  int64_t advices() const { return advices_; }       // times the advice came on
  double kept_share() const { return kept_share_; }  // over the window, at the last Add
  double step_mm() const {
    return step_mm_;
  }  // median step over the window, at the last Add (0: too few)
  int lost_views() const {
    return lost_views_;
  }              // views of the window the tracker could not place, at the last Add
  void Reset();  // a new scan (a reset graph): no history

 private:
  struct View {
    uint64_t burst_seq;
    int64_t capture_ns;
    bool tracked;
    bool lost;
    Rigid3d pose;
  };
  PaceOptions o_;
  std::deque<View> window_;
  std::vector<double> steps_;  // Add's buffer (reused)
  bool advising_ = false;
  int64_t advised_since_ns_ = 0;
  int64_t advices_ = 0;
  double kept_share_ = 1.0, step_mm_ = 0.0;
  int lost_views_ = 0;
};

}  // namespace d3d
