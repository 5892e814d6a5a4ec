// Frame-to-model tracking of a hand-held scan, with tracking-loss detection, relocalisation,
// keyframes and a loop-closing pose graph. One Tracker per scan, driven by one thread.
//
// Per view (an organised cloud in the camera frame):
//  1. Prediction: constant velocity from the last two accepted poses, over skipped views too
//     (motion_model.h).
//  2. Frame-to-model ICP (icp.h) against the PointMap of every accepted view, by projective
//     association in the model rendered from the prediction, or the exact nearest model sample
//     near it, found on uniform grids (grid_target.h) or by a k-d tree (options.association).
//     A view with too few points (probe lifted, out of range) is skipped without a state change.
//  3. Checks: ICP ok (overlap, residual, degeneracy) and consistent motion (the step from the last
//     accepted pose, per elapsed burst, below motion.max_step_mm / max_step_deg). A view failing them is
//     refused (not fused, not added to the model) and the state becomes kLost; optionally one that
//     fits but is degenerate is coasted instead (max_coast_views, off): not fused, the track kept.
//  4. Relocalisation (when ICP fails, and for every view while lost): first a local search, ICP
//     from the predicted pose, the last accepted pose and the keyframes nearest to it (the probe usually comes
//     back where it left), whose result must pass the motion check of step 3 over the views elapsed
//     since the last accepted one; then SIFT features of the view
//     (features.h) are matched to keyframes, chosen by a local border search: keyframes nearest
//     the last accepted view first (where the probe left the model), up to relocalise_candidates;
//     RANSAC → ICP against the model; the first that passes is accepted (state kRelocalised).
//     A return after a gap must also be well constrained, unambiguous and consistent with what the
//     keyframes near it saw (reentry_check.h); see reentry_min_eigen_ratio.
//  4b. Segments: views that still cannot be placed start a segment of their own frame, joined to
//     the main model once they overlap it (segment_join.h); see segment_after_views.
//  5. Keyframes: a view whose overlap index with the current keyframe (fraction of its samples in
//     the keyframe's occupied voxels) falls below keyframe_overlap (or, optionally, that turned or
//     waited too long since it, or whose pose jumped from the prediction) becomes a keyframe,
//     unless an older keyframe near it already covers
//     it (that one becomes current again: keyframe_reuse_radius_mm): samples, features and pose
//     kept; an odometry edge joins it to the keyframe that was current, measured by ICP between
//     the two keyframes' samples (keyframe_icp_edges) with ICP's information matrix.
//  6. Loop closure: a new keyframe is registered by ICP to other keyframes (up to
//     max_loop_candidates at least loop_min_separation keyframes back, and near_loop_candidates
//     more recent ones) whose samples overlap its own (overlap index ≥ loop_min_overlap at the
//     current poses): each success becomes a loop edge (robust loss, ICP information).
// Optimize() solves the pose graph (pose_graph.h) and re-expresses every accepted view through its
// anchor keyframe: world_from_cam = world_from_keyframe (optimised) · keyframe_from_cam (tracked).
// UndoFrom() takes the newest views back out (the host's "undo last seconds"): they become refused
// views, and the model, keyframes, pose graph and motion state are what they were before them
// (the model exactly, through PointMap's undo journal: TrackerOptions::map.undo_inserts).
#pragma once

#include <functional>
#include <limits>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <type_traits>
#include <vector>

#include "calib/model/camera_model.h"
#include "common/pack/frame_pack.h"
#include "pipeline/register/features.h"
#include "pipeline/register/grid_target.h"
#include "pipeline/register/icp.h"
#include "pipeline/register/motion_model.h"
#include "pipeline/register/point_map.h"
#include "pipeline/register/pose_graph.h"
#include "pipeline/register/reentry_check.h"
#include "pipeline/register/segment_join.h"

namespace d3d {

enum class TrackingState { kInitialising, kTracking, kLost, kRelocalised };
const char* TrackingStateName(TrackingState s);  // "initialising", "tracking", "lost", "relocalised"

// Frame-to-model data association: projective (the model rendered from the prediction), or the
// exact nearest model sample within the gate, by a nanoflann k-d tree or by uniform grids
// (GridTarget: the same matches, faster).
enum class Association { kProjective, kKdTree, kGrid };
const char* AssociationName(Association a);  // "projective", "kdtree", "grid"
// Parses AssociationName's names; false for any other text.
bool ParseAssociation(const std::string& name, Association* out);

// Frame-to-model ICP of the tracker: IcpOptions' levels (gates 1.0 → 0.15 mm) with the finest
// level on every 2nd sample (~15k of a full view: the pose's noise from 15k samples is ~0.2 µm,
// below what the levels' termination leaves), and termination at pose updates below 0.5 µm /
// 2e-5 rad (0.2 µm at the view's ~10 mm radius) or an error change below 0.1 %. IcpOptions'
// defaults (0.1 µm, 2e-6 rad, 0.01 %) ran every level to its iteration cap; these cost ~60 % of
// that for the same trueness (typodont, 90 bursts at 30 Hz: 7.35 vs 7.37 µm RMS, register stage
// 139 → 88 ms per burst).
// The two coarse levels are pure point-to-plane (α = 1, not IcpOptions' 0.7 / 0.9) and end at
// updates below 10 µm / 1e-3 rad and 5 µm / 5e-4 rad (IcpLevel's own termination): a level only
// has to bring the pose well inside the next one's gate (0.3, 0.15 mm). With the point-to-point
// share and the common 0.5 µm end, a live view (predicted ~0.5–1.8 mm off) converged linearly
// (update ratio ~0.7 per iteration) and the first two levels ran ~10 and ~9 of their 12 and 10
// iterations on average; the finest level, pure point-to-plane, 3–5. Measured with the views of
// 7 live runs of the 450-burst typodont recording (d3d-scan --replay-views): in one run, ICP
// iterations per level 5422 / 4457 / 2451 → 2979 / 2260 / 1961 and nearest-sample queries
// 41.6 → 27.2 million (keyframe edges, unchanged, included); register stage CPU 25.6–34.6 →
// 19.4–23.6 ms per burst (live: 28–34 → 20–25), trueness 13.06 → 13.03 µm RMS on average (per
// run −0.85 … +0.56 µm); lossless replay 11.65 → 12.15 µm. The local search's wide first level
// keeps the point-to-point share (LocalSearchIcp).
IcpOptions DefaultTrackerIcp();

// FeatureOptions with image_scale 0.5 (the tracker's keyframe features; see TrackerOptions::features).
FeatureOptions HalfScaleFeatures();

struct TrackerOptions {
  IcpOptions icp = DefaultTrackerIcp();  // frame-to-model
  PointMapOptions map;
  // Nearest neighbour (grid; the k-d tree finds the same samples) by default: on the full-arch
  // simulation, projective association into the model
  // rendered at half resolution gave 4× the trueness error (53 vs 14 µm RMS over the first 150
  // bursts at 15 Hz) for ~30 % less time.
  // The grid replaced the k-d tree as the default: identical poses and mesh on a 450-burst typodont
  // replay, register stage 72 -> 47 ms per burst (see grid_target.h); identical only with
  // grid_decimate_min_gate_mm = 0 since.
  Association association = Association::kGrid;
  int sample_stride = 2;          // px lattice of the ICP source samples
  int map_stride = 3;             // px lattice of the samples added to the model
  // true: Track() leaves the accepted view's model insert pending, and the caller runs it with
  // CommitView() once it has passed the view on (d3d-scan: after the register stage has handed the
  // burst to the preview, so the preview does not wait for it); the next Track() or UndoFrom()
  // runs a pending one first. Nothing between the insert and Track's end reads the model, so the
  // results are the same bits either way.
  bool defer_model_insert = false;
  double target_scale = 0.5;      // projective: model image size / camera size
  int target_splat = 1;           // projective: splat half-size (px of the model image)
  int target_window = 1;          // projective: search half-window (px)
  double gather_margin_mm = 1.0;  // grid, k-d tree: model samples within the view's box ± this
  // grid: ICP levels whose gate is at least this (mm) search a decimated model, one sample per
  // voxel of a quarter of the gate (GridTarget::Build); 0 = every level exact. Default: the first
  // (coarse) level only, gates 1.0 mm (2 mm live), and the local search's 4 mm; the finer levels
  // (0.3 / 0.15 mm) still find the exact nearest model sample and decide the pose. The coarse
  // level was the ICP's costliest per sample (~150 model samples per 1 mm cell read per query);
  // measured on the views of 12 live runs of the 450-burst typodont recording (d3d-scan
  // --replay-views, each with and without): register stage CPU 31.9–39.2 → 28.1–39.0 ms per
  // burst (−5.0 ms on average), trueness change median −0.01 µm, within ±0.3 µm in 11 runs and
  // +1.2 µm in one; lossless replay 11.54 → 11.74 µm RMS.
  double grid_decimate_min_gate_mm = 0.5;
  MotionModelOptions motion;  // prediction and the motion check (motion_model.h)
  double keyframe_overlap = 0.7;
  // A view also becomes a keyframe when the camera turned by more than keyframe_max_rotation_deg
  // since the last keyframe, or keyframe_max_views views passed since it (0 = off, overlap only).
  // Why: a probe rolling around a distal molar (the full-arch transitions) or lingering over one
  // spot keeps its overlap with the last keyframe, so 100–180 views hang on one keyframe through
  // their tracked poses and no loop reaches them; the tracked views there were 23–32 µm off at the
  // surface against 8–12 elsewhere. Full arch, default noise, overlap only → 8° / 45 views
  // (keyframes 110–117 → 141–158, loop edges 190–225 → 345–463), trueness RMS µm:
  //   typodont s1 9.06 → 8.52, s2 9.23 → 11.72, s3 12.29 → 9.84;
  //   real arch s1 8.41 → 10.33, s2 11.72 → 12.31, s3 11.07 → 10.29;
  // precision between seeds (RMS µm, pairs 1–2 / 1–3 / 2–3): typodont 11.6 / 11.9 / 15.6 →
  // 11.4 / 9.3 / 11.4, real arch 12.5 / 8.3 / 15.2 → 13.0 / 9.7 / 15.0. The mean trueness barely
  // moves (typodont 10.2 → 10.0, real 10.4 → 11.0 µm) but the worst pair of scans agrees better:
  // the transitions' error no longer depends on where one keyframe happened to fall.
  double keyframe_max_rotation_deg = 8.0;
  int keyframe_max_views = 45;
  // A view whose pose jumped from the motion prediction (TrackResult::prediction_offset_mm / _deg)
  // by more than these becomes a keyframe of its own (never an older one reused): a jump is where
  // ICP moved from one layer of a drifted model to another, and a view anchored to the keyframe
  // before it would carry the jump into its final pose; as a keyframe, its pose comes from the
  // pose graph's edges, measured from the keyframes' own points (docs/decisions/0003). 0 = off.
  double keyframe_jump_mm = 0.7;
  double keyframe_jump_deg = 1.2;
  // Keyframe reuse: when a view would become a keyframe (any rule above), an older keyframe that
  // already covers it becomes the current one instead (ORB-SLAM's keyframe culling, done before
  // the keyframe is made rather than after): one whose centre lies within keyframe_reuse_radius_mm
  // of the view's, turned at most half keyframe_max_rotation_deg from it (so that it lasts a few
  // views), and whose overlap index with the view is at least keyframe_overlap; of the
  // keyframe_reuse_candidates such nearest, the first that passes. Later views anchor to it and are
  // tested against it, and the next new keyframe's odometry edge starts from it. Why: a keyframe
  // holds ~0.4-0.7 MB (samples, packed feature inputs), and a probe circling one tooth made one
  // every ~0.4 s for as long as it circled (RSS +1.7 MB/s). The price: fewer keyframes and loop
  // edges where the probe lingers, so the pose graph averages fewer measurements there (test
  // AProbeCirclingOneSpotReusesItsKeyframes: worst optimised view 9 → 19 µm on a 160 × 120 view,
  // tracked 15 µm either way). 0 = never reuse (every trigger makes a keyframe); d3d-scan: 2 mm.
  double keyframe_reuse_radius_mm = 0;
  int keyframe_reuse_candidates = 3;
  int keyframe_stride = 4;        // px lattice of a keyframe's samples
  // Keyframe and relocalisation features. SIFT on half-size images (image_scale 0.5): measured on
  // 45 view pairs 3, 6 and 12 bursts apart along each arch's path (640 × 480 views), it aligns as
  // many pairs as full size (typodont 15 of 45 both; real arch 33 of 45 both) and extracts 4–10×
  // faster (real arch 469 → 90 ms per view for the three images, on the shared 2 cores).
  FeatureOptions features = HalfScaleFeatures();
  int relocalise_candidates = 6;
  int local_candidates = 4;       // local search: ICP from the last pose and this many nearest keyframes
  double local_search_gate_mm = 4.0;  // first-level association gate of the local search
  int min_view_samples = 5000;    // fewer samples (a fragment, ~6 % of the image): skipped, state unchanged
  // A view that a Track() augmenter enlarged is registered again when its samples grew by at least
  // this share.
  double reregister_min_gain = 0.25;
  // That second ICP starts from the pose just found, so it runs icp's levels from this one on
  // (the coarse levels would only re-find that pose).
  int reregister_first_level = 1;
  // A view whose ICP residual is above this multiple of the median residual of the last 16
  // accepted views is accepted (its pose stands; it is fused) but not added to the tracking model:
  // a view that straddles two layers of the model (the same surface inserted by two passes that
  // drifted apart) fits both badly and, added, would grow a third layer at a wrong pose that later
  // views lock onto (typodont seed 3: a view 1.3 mm off at 22 µm among 15 µm views, then a run of
  // views 1.7 mm off). Only a view that lies mostly on the model already (ICP overlap ≥
  // map_gate_min_overlap) and at most map_gate_max_run views in a row: the model must keep growing
  // where the probe goes (without both, a typodont scan lost the model for good at its 63rd view).
  // 0 = every accepted view enters the model.
  double map_max_rmse_ratio = 1.4;
  double map_gate_min_overlap = 0.8;
  int map_gate_max_run = 2;
  double relocalise_max_rmse_mm = 0.04;  // stricter residual for a view re-entering the model (local search or features)
  double relocalise_min_overlap = 0.5;
  // After a loss, a view that the local search or the features place on the model is a re-entry
  // candidate, not yet accepted: it is refused (state stays kLost), and the next view with points
  // must confirm it: ICP from the candidate's pose (the local search's gate, the re-entry residual)
  // ending within motion.max_step_mm / max_step_deg per view elapsed since the candidate (by time with
  // motion.view_period_ns: a live host may take a while over the candidate). That view is accepted
  // (kRelocalised) and the track resumes from it; otherwise the candidate is dropped and that view
  // is searched in its turn. One view can fit a similar part of the model (a neighbouring tooth)
  // well enough; two in a row rarely agree on it. A live typodont scan lost the model for 91
  // bursts, re-entered by the local search onto keyframe 1's tooth while the probe was behind the
  // last molar, and the next view's ICP from there ended 3.1 mm and 3.7° away; the local search
  // then took that view near the wrong pose too, and every later view followed (trueness 242 µm
  // RMS). The cost: the first view of every re-entry after a loss is not fused. A view refused
  // while tracking is still recovered at once by the local search (its motion check then spans
  // one or two views). false: a re-entry is accepted at once.
  bool confirm_reentry = true;
  // ... except a re-entry that ICP from the motion prediction finds at most this many views
  // (by time with motion.view_period_ns) after the last accepted view: the track resumes at once
  // (kRelocalised), as after a view refused while tracking. That is one bad view (a degenerate
  // stretch) in a track that never left, not a return from elsewhere. Live typodont replay: a
  // view refused as degenerate at burst 217 left the next one (burst 219, found from the
  // prediction 1.3 views after the last accepted) a candidate; the host's next view came 9 bursts
  // later, where the probe had moved past the model's border, failed to confirm it (overlap 0.20),
  // and the scan never re-entered (130 of 450 bursts processed). 0 = always confirm.
  double reentry_direct_max_views = 2.0;
  // Coasting: a view whose ICP from the motion prediction fits (overlap, residual) but is
  // degenerate (a smooth stretch: it slides along some direction) is not fused, but while tracking
  // (at most reentry_direct_max_views views after the last placed view) it keeps the track: ICP
  // runs again from the prediction stepping only along the well-constrained directions
  // (IcpOptions::remap_min_eigen_ratio = coast_min_eigen_ratio), and that pose feeds the motion
  // model and the tracking model (not the fused one), so the next view is tracked from it rather
  // than searched for after a loss. At most this many views in a row; 0 = off, the default: on the
  // zoo it placed a view after a stretch of nearly empty views 2 mm off, and the track went on
  // from there (docs/decisions/0003).
  int max_coast_views = 0;
  // The directions a coasted view takes from its fit: eigenvalue ratio at least this (the weak
  // directions just above IcpOptions::min_eigen_ratio slide almost as freely: a smooth patch gives
  // three weak directions, 0.001–0.005, and three strong ones, > 0.1).
  double coast_min_eigen_ratio = 0.02;
  // A re-entry after a gap (state lost, or more than reentry_direct_max_views views since the last
  // accepted one: views with too few points, a lifted probe) must be well constrained: ICP's
  // eigenvalue ratio (IcpResult::eigen_ratio) at least this. Such a return after a gap also waits
  // for the next view's confirmation (confirm_reentry), as after a loss. Why: a view of a smooth
  // stretch slides along it; typodont full arch, seed 5 burst 184 (after 4 views with too few
  // points) re-entered 2.3 mm and 12.7° off at eigen ratio 0.007, seed 6 bursts 154 / 156 11.7 and
  // 15.1 mm off at 0.005 / 0.002, and the rest of each scan was built on them (107 / 121 µm RMS).
  // Tracked views there: 5th percentile 0.011–0.013, median 0.07–0.09. 0 = no such limit.
  double reentry_min_eigen_ratio = 0.02;
  // After a gap the local search tries all its starts; when two fits pass every check yet put the
  // view's surface centre more than this apart (mm) or turned by more than 2 degrees from each
  // other, the return is ambiguous and refused. 0 = the first fit that passes is taken.
  double reentry_ambiguity_mm = 0.5;
  // A pose farther than these from the motion prediction (per view the prediction spans, at least
  // one) is a jump, not a motion of the hand, even inside a track: a tracked view whose ICP ran off
  // to another fit, or a view refused while tracking that the local search recovered from a
  // keyframe's pose, sliding along a smooth stretch. Such a pose must meet the standard of a
  // re-entry after a gap (relocalise_max_rmse_mm, relocalise_min_overlap, reentry_min_eigen_ratio,
  // the re-entry check), or the view is refused like a failed ICP. Figures: docs/decisions/0007.
  // 0 = off.
  double jump_check_mm = 1.5;
  double jump_check_deg = 3.0;
  // Every re-entry pose (local search, features, a candidate's confirmation) must also be
  // consistent with what the keyframes near it saw (reentry_check.h): a pose that fails is passed
  // over like a failed ICP, and the search goes on with the next start.
  ReentryCheckOptions reentry_check;
  // Segments. A scan that cannot place its views on the model does not stop and does not guess:
  // after segment_after_views views in a row refused while lost (each with enough points: the
  // probe is over teeth, somewhere the model cannot be found), the next such view starts a new
  // segment in a frame of its own (the main frame moved by segment s · 2 m along x, so that the
  // segments never meet in the model, the keyframe searches or the pose graph), and the track goes
  // on there. Local search and feature relocalisation look in the current segment only. Every
  // segment_join_every new keyframes of a segment not joined yet, it is registered onto the main
  // model (segment_join.h: FPFH + RANSAC + ICP; when FPFH finds nothing and relocalise is on, the
  // keyframe features of the segment's newest keyframe against segment_join_feature_keyframes main
  // keyframes per attempt, in turn, each match refined by the same ICP) and the join verified like a re-entry
  // (reentry_min_eigen_ratio, reentry_check against the main keyframes near it); once it holds,
  // the segment's keyframes, model and motion state move into the main frame, a loop edge joins it
  // to the main keyframes, and its views are the main model's from then on (TrackResult::in_main).
  // JoinApartSegments() tries every segment still apart once more. 0 = never start a segment: the tracker
  // stays lost until a view re-enters the model. Undo (UndoFrom) does not reach back past a segment's
  // start or join.
  int segment_after_views = 8;
  int max_segments = 16;
  int segment_join_every = 1;
  int segment_join_feature_keyframes = 8;  // 0: FPFH only
  SegmentJoinOptions segment_join;
  double loop_radius_mm = 10.0;   // keyframe centres closer than this are loop candidates
  int loop_min_separation = 10;   // keyframes
  double loop_min_overlap = 0.3;
  int max_loop_candidates = 6;    // per new keyframe, older than loop_min_separation, nearest first
  // Per new keyframe, edges to recent keyframes too (2 .. loop_min_separation − 1 back), nearest
  // first: several overlapping neighbours constrain a keyframe whose own registration was weak.
  int near_loop_candidates = 3;
  // The information of those near loops is multiplied by this (0 < f ≤ 1). A near loop and the
  // odometry edge beside it register the same new samples onto overlapping surfaces, so their
  // errors are correlated, yet the graph counts each as an independent measurement: the chain's
  // local bias then outweighs the far loops that close the arch. Measured on full-arch scans
  // (keyframes' aim-point error against the truth after re-solving the dumped graph, RMS, factor
  // 1 / 0.5 / 0.25 / 0.1): typodont seed 3 19.3 / 16.9 / 14.7 / 13.3 µm, real arch seed 2
  // 22.9 / 23.0 / 23.0 / 23.1 µm (insensitive). Whole runs at 0.25: typodont seed 3 trueness RMS
  // 15.1 → 11.7 µm, seeds 1 and 2 6.9 → 6.8 and 8.2 → 7.9 µm; precision between the three
  // typodont seeds 16.3 / 18.3 → 13.2 / 14.6 µm RMS. Below 0.25 the gain on seed 3 slows while
  // the chain's own local constraint weakens, so 0.25.
  double near_loop_information_factor = 0.25;
  // Odometry edges measured by ICP between the keyframes' own samples (k-d tree), independent of
  // the model the tracker registered against, with ICP's information matrix (times
  // edge_information_scale) as the edge's information; loop edges use that information too.
  // false: the odometry edge is the tracked relative pose with the σs below (also the edge of a
  // keyframe whose ICP to its parent failed).
  bool keyframe_icp_edges = true;
  // With keyframe_icp_edges and a factor > 0, each keyframe whose ICP odometry edge was measured
  // also gets a second odometry edge from its parent: the relative pose the tracker gave the two
  // (frame-to-model ICP against the whole model near them, not just the parent's samples), with the
  // ICP edge's information times this factor. Off by default: it halves the spread of a single pass
  // but costs the loop-closing scans (measured below); `d3d-fuse` / `d3d-scan
  // --tracked-edge-factor`. Why: a single pass along the arch has links that only the odometry edge
  // spans (no near loop: the keyframes around it overlap too little), and one keyframe ICP's error
  // there bends everything after it. The tracked relative pose has errors about as large (450-burst
  // typodont recording: per component 25 / 24 / 2.7 µm and 0.44 / 0.48 / 0.44 mrad, against the ICP
  // edge's 14 / 26 / 2.9 µm and 0.48 / 0.30 / 0.44 mrad) and correlated with them by 0.3–0.65, so
  // the two average. 20 lossless `d3d-scan` replays of that recording, each without its first 0–26
  // bursts or with 5 % of them dropped (trueness RMS, factor 0 / 0.5 / 1): SD 1.28 / 0.74 / 0.65
  // µm, range 10.2–15.6 / 10.5–12.8 / 10.7–12.9 µm, ATE mean 0.075 / 0.070 / 0.069 mm (a 20th run,
  // 20.2 / 21.1 / 21.8 µm, lost its keyframe ICP in a fast turn, and the σ edge that then stands for
  // it bends the chain there). But the whole full arch (`d3d-fuse --sim typodont --bin 2 --every 2`,
  // 133–143 keyframes), factor 0 / 1: seed 1 9.00 / 12.80 µm, seed 2 12.43 / 9.85, seed 3 9.64 /
  // 11.45, seed 4 (lost for good at burst 214: 172 of 746 views) 23.2 / 49.2: the tracked poses
  // carry the tracker's drift, which the loops across the arch must undo.
  // Tracked edges only where a keyframe got no loop edge did worse on the single pass (11.8–13.1 µm
  // over the first 7 of those replays).
  double tracked_edge_information_factor = 0.0;
  double edge_information_scale = 1e-3;
  double odometry_sigma_mm = 0.005, odometry_sigma_rad = 1e-4;  // pose graph edge σ (without ICP information)
  double loop_sigma_mm = 0.005, loop_sigma_rad = 1e-4;
  bool relocalise = true;
  // When a keyframe's features (SIFT on three images: ~150–300 ms at 640×480, ~75 ms at 320×240
  // here) are extracted. Only relocalisation (step 4) reads them. Results are the same in every
  // mode (the same features of the same points and texture).
  //  kInTrack:  in Track(), when the keyframe is made.
  //  kWorker:   on a worker thread of the tracker: a keyframe costs Track() a copy of its points and
  //             texture (~1 ms) rather than a stall of several bursts; a relocalisation first waits
  //             for every keyframe's features. The CPU is still spent: on a loaded 2-core host the
  //             worker took 11 % of the process's CPU (issue 6).
  //  kOnDemand: when a relocalisation first matches against the keyframe; until then it keeps a copy
  //             of its points and texture (~1 MB at 320×240: less than its features, up to 1500 × 3
  //             SIFT descriptors of 512 B), freed once extracted. A scan that never relocalises by
  //             features never spends that CPU; the first relocalisation after a loss extracts up to
  //             relocalise_candidates keyframes' features (~75 ms each at 320×240).
  enum class FeatureTiming { kInTrack, kWorker, kOnDemand };
  FeatureTiming keyframe_feature_timing = FeatureTiming::kInTrack;
  // A new keyframe's pose-graph edges (the ICP edge to the previous keyframe and the loop-closure
  // search, up to 10 ICPs) are measured in Optimize() instead of in Track(). The graph's poses do
  // not move before Optimize, so the edges are the same; only TrackResult::loops_added stays 0.
  // For a live host (Track() on the critical path; the work moves to the end of the scan).
  bool defer_keyframe_edges = false;
  bool detect_loops = true;
  void Check() const;             // throws std::invalid_argument
};

// ICP levels of keyframe-to-keyframe registration (gates 0.5 → 0.1 mm), acceptance from `base`.
IcpOptions KeyframeIcp(const IcpOptions& base = DefaultTrackerIcp());

// A pose-graph edge measured by ICP between two keyframes' own samples (their camera frames,
// normals required): `to_samples` registered onto a k-d tree of `from_samples` starting from
// `guess` (from_from_to). On success *edge gets from_from_to and ICP's information matrix times
// information_scale (pose_graph.h EdgeInformationFromIcp); its nodes and `loop` are left to the
// caller. Returns false (edge untouched) when the ICP is not ok; *result (optional) gets the ICP.
bool MeasureKeyframeEdge(const SurfacePoints& from_samples, const SurfacePoints& to_samples, const Rigid3d& guess,
                         const IcpOptions& icp, double information_scale, PoseGraphEdge* edge, IcpResult* result = nullptr);

struct Keyframe {
  int64_t view = 0;                   // index of the view (Track call) it was made from
  int node = 0;                       // pose graph node
  SurfacePoints samples;              // camera frame
  ViewFeatures features;              // camera frame (kWorker: once collected; kOnDemand: once extracted)
  // kOnDemand: the inputs of its features (points H×W CV_32FC3, texture H×W CV_8U or empty), packed
  // losslessly (common/pack/frame_pack.h; texture: empty when there is none) until a relocalisation
  // extracts them (both released then). Packed points take ~0.1-0.38 MB against 0.92 MB unpacked
  // at 320 × 240 (most pixels of a view hold no point): the keyframes are what a long scan's memory
  // keeps growing with. A keyframe's points are never empty.
  std::string packed_feature_points, packed_feature_texture;
  int segment = 0;                    // the scan segment it was made in (TrackerOptions::segment_after_views)
  bool features_pending() const { return !packed_feature_points.empty(); }
  // Bytes the keyframe holds: samples, features and packed feature inputs.
  int64_t bytes() const;
  Eigen::Vector3d centre_in_cam = Eigen::Vector3d::Zero();
  // The keyframe the views were anchored to when this one was made (its odometry edge starts
  // there): the previous keyframe, or an older one reused since (keyframe_reuse_radius_mm); −1 for
  // the first.
  int parent = -1;
};
// Its members move without throwing (ViewFeatures declares so for its cv::Mats), so
// std::vector<Keyframe> moves keyframes when it grows rather than copying them (see ViewFeatures).
static_assert(std::is_nothrow_move_constructible_v<Keyframe>, "std::vector<Keyframe> must move keyframes when it grows, not copy them");

struct TrackResult {
  TrackingState state = TrackingState::kInitialising;
  bool accepted = false;              // pose valid and view added to the model (fuse it)
  Rigid3d world_from_cam = Rigid3d::Identity();
  std::string reason;                 // why refused, or how relocalised
  IcpResult icp;
  bool new_keyframe = false;
  bool keyframe_reused = false;       // an older keyframe became the current one (keyframe_reuse_radius_mm)
  bool in_model = false;              // the view's samples entered the tracking model (map_max_rmse_ratio)
  ReentryEvidence reentry;            // the re-entry check of the pose found after a loss (keyframes 0: none ran)
  int segment = 0;                    // the segment of the view (accepted views)
  bool new_segment = false;           // the view started that segment
  bool segment_joined = false;        // the segment was joined to the main model before this view
  // Where a preview may draw a view of a segment apart (accepted, !in_main): world_from_cam with the
  // segment's frame moved back to the main frame's origin (MainFromSegmentFrame), beside where the
  // model was lost; not registered to it. In the main frame: world_from_cam.
  Rigid3d display_from_cam = Rigid3d::Identity();
  // segment_joined: carries what was drawn at that segment's display_from_cam poses into the main frame.
  Rigid3d main_from_display = Rigid3d::Identity();
  std::string join_attempt;           // what a join attempt before this view found (empty: none was made)
  // The pose is in the main frame (the first segment, or one joined to it): fuse the view into the
  // main model only then.
  bool in_main = true;
  int loops_added = 0;
  // Accepted views: how far (camera centre, mm) the pose lies from the motion model's prediction;
  // NaN when there was none (the first views, a re-entry, a new segment).
  double prediction_offset_mm = std::numeric_limits<double>::quiet_NaN();
  double prediction_offset_deg = std::numeric_limits<double>::quiet_NaN();
  double ms = 0;
};

class Tracker {
 public:
  // camera: intrinsics of the organised views (their H×W). Throws for invalid options.
  Tracker(const PinholeBrownConrady& camera, const TrackerOptions& options = {});
  ~Tracker();

  // Called once per accepted view (not the first), with its pose, before the view enters the model:
  // it may add points to the view, writing into the same buffers as the points, normals and quality
  // given to Track (e.g. surfaces the model confirms: pipeline/scan/model_anchor.h), and returns
  // true if it did. Track then runs ICP again from that pose with all the points (when they grew by
  // TrackerOptions::reregister_min_gain) and takes the new pose if that ICP is ok and a consistent
  // motion. A view with too few points for ICP, right after
  // an accepted one while tracking, is offered to it once at the motion prediction instead (then
  // not again after its ICP). "Right after": at most one view refused in between.
  using ViewAugmenter = std::function<bool(const Rigid3d& world_from_cam, const PointMap& model)>;

  // points, normals: H×W CV_32FC3 camera frame (mm, NaN = none); quality H×W CV_32F or empty;
  // texture H×W CV_8U or empty (then relocalisation uses range features only).
  // capture_ns: the view's capture time (ns, any epoch), used with TrackerOptions::motion.view_period_ns.
  TrackResult Track(const cv::Mat& points, const cv::Mat& normals, const cv::Mat& quality, const cv::Mat& texture,
                    const ViewAugmenter& augment = {}, int64_t capture_ns = 0);

  TrackingState state() const { return state_; }
  // With keyframe_feature_timing kWorker or kOnDemand, a keyframe's features may still be pending
  // (empty) here.
  const std::vector<Keyframe>& keyframes() const { return keyframes_; }
  int64_t keyframe_bytes() const;  // the keyframes' Keyframe::bytes(), summed
  int keyframes_reused() const { return keyframes_reused_; }  // times an older keyframe became current again
  int current_keyframe() const { return current_kf_; }         // the keyframe views anchor to now (−1: none yet)
  const PoseGraph& graph() const { return graph_; }
  int64_t views() const { return static_cast<int64_t>(anchor_.size()); }
  const PointMap& model() const { return map_; }  // without a pending insert (see CommitView)
  // Runs the model insert Track() left pending (TrackerOptions::defer_model_insert); nothing when
  // none is. Returns its time (ms).
  double CommitView();
  bool insert_pending() const { return insert_pending_; }

  // Optimises the pose graph (loop closures) and returns the summary.
  [[nodiscard]] Status Optimize(const PoseGraphOptions& options, PoseGraphSummary* summary);

  // The first view UndoFrom can take back: the model's undo journal (options.map.undo_inserts)
  // reaches back to it. views() when it reaches no view (no journal).
  int64_t first_undoable_view() const;
  struct UndoResult {
    bool ok = false;
    std::string reason;          // why not (ok = false)
    int64_t views_undone = 0;    // accepted views taken back
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
  int loop_edges() const;
  // Segments (TrackerOptions::segment_after_views): how many, whether segment s lies in the main
  // frame (the first, or joined to it), and the segment of view i (−1: refused).
  int segments() const { return static_cast<int>(segments_.size()); }
  int segments_joined() const;
  bool SegmentInMain(int segment) const;
  int ViewSegment(int64_t view) const;
  // Segment s's frame moved back to the main frame's origin (a translation: not a registration, the
  // two stay unrelated); identity for the main one.
  Rigid3d MainFromSegmentFrame(int segment) const;
  // A last join attempt for every segment not joined yet (at the end of a scan, before Optimize):
  // returns how many joined.
  int JoinApartSegments();

 private:
  IcpResult RunIcp(const SurfacePoints& source, const Rigid3d& initial, const IcpOptions& icp) const;
  // ICP of the local search and of a re-entry's confirmation: o_.icp with the first level's gate
  // widened to local_search_gate_mm and the residual limit relocalise_max_rmse_mm.
  IcpOptions LocalSearchIcp() const;
  // *from_prediction: the fit started from the motion prediction.
  // A return to the model after a gap or a loss (see TrackerOptions::reentry_min_eigen_ratio).
  bool AfterGap() const;
  // The checks of a re-entry pose (ICP result r of `samples`) beyond ICP's own: after a gap or a
  // jump from the prediction, well constrained (reentry_min_eigen_ratio); and the re-entry check,
  // whose evidence goes to *evidence. False with *why when one fails (*evidence untouched when the
  // first did).
  bool VerifyReentry(const SurfacePoints& samples, const IcpResult& r, ReentryEvidence* evidence, std::string* why);
  // Whether `pose` lies farther from the motion prediction than jump_check_mm / jump_check_deg.
  bool JumpsFromPrediction(const Rigid3d& pose) const;
  // A tracked view's fit (ICP result r of `samples`) that jumped: the re-entry's residual and
  // overlap limits, then VerifyReentry. False with *why.
  bool MeetsJumpStandard(const SurfacePoints& samples, const IcpResult& r, std::string* why);
  // The re-entry check (TrackerOptions::reentry_check) of `samples` at world_from_cam against the
  // keyframes nearest to it.
  ReentryEvidence CheckReentry(const SurfacePoints& samples, const Rigid3d& world_from_cam);
  // The map gate's residual history (map_max_rmse_ratio) starts again: a new segment's views are
  // compared with each other, not with the residuals of the model the track left (a young
  // segment's model fits its views worse; compared with the main model's, they stayed out of it).
  void ForgetResiduals();
  // Whether view `view` started a segment (> 0).
  bool SegmentStartsAt(int64_t view) const;
  // Starts a new segment with this view (accepted at *pose, in the segment's frame).
  void StartSegment(Rigid3d* pose, TrackResult* out);
  // Tries to join segment s to the main model; true when it did (then merged, see TrackerOptions).
  // *why: what it found, and its time.
  // *main_from_segment (optional): the join's transform, when it joined.
  bool TryJoinSegment(int s, std::string* why, Rigid3d* main_from_segment = nullptr);
  bool JoinSegmentNow(int s, std::string* why, Rigid3d* main_from_segment);  // the same, untimed
  // The join's second way: keyframe features of the segment's newest keyframe (`newest`) against
  // main keyframes in turn, refined by RefineSegmentJoin on `seg` (prepared by MakeSegmentJoinTarget).
  SegmentJoinResult JoinSegmentByFeatures(int s, int newest, const SegmentJoinTarget& seg, std::string* why);
  void EnsureKeyframeFeatures(Keyframe* kf);  // kOnDemand: extracts them at first use
  // The main model's samples (world), for the join target.
  SurfacePoints MainSamples() const;
  bool RelocaliseLocally(const SurfacePoints& samples, TrackResult* out, bool* from_prediction);
  bool Relocalise(const SurfacePoints& samples, const cv::Mat& points, const cv::Mat& texture, TrackResult* out);
  void MaybeKeyframe(const SurfacePoints& samples, const cv::Mat& points, const cv::Mat& normals,
                     const cv::Mat& texture, const Rigid3d& pose, TrackResult* out);
  // Keyframe reuse (TrackerOptions::keyframe_reuse_radius_mm): makes an older keyframe covering the
  // view (samples kfs, camera frame, at `pose`) the current one; false when none does.
  // On success, the keyframe left and the one reused get a loop edge (AddReuseEdge) unless joined.
  bool ReuseKeyframe(const SurfacePoints& kfs, const Rigid3d& pose);
  // A loop edge measured by ICP between keyframes from < to (KeyframeEdge; near_loop_information_factor
  // when fewer than loop_min_separation apart); none when an edge joins them already or the ICP fails.
  void AddReuseEdge(int from, int to);
  int DetectLoops(int new_kf);
  // The pose-graph edges of keyframe k (to its parent, and loop closures): returns the loops added.
  int AddKeyframeEdges(int k);
  // ICP of keyframe `to`'s samples onto keyframe `from`'s from their current relative pose: an
  // edge with ICP's information (false when the ICP fails).
  bool KeyframeEdge(int from, int to, PoseGraphEdge* edge) const;

  class FeatureWorker;  // keyframe_feature_timing kWorker (tracker.cpp)
  // Waits for the feature worker's pending keyframes and moves their features into keyframes_.
  void CollectKeyframeFeatures();

  PinholeBrownConrady camera_;
  PinholeIntrinsics pinhole_;
  TrackerOptions o_;
  std::unique_ptr<FeatureWorker> feature_worker_;  // null unless keyframe_feature_timing is kWorker
  ReentryCheck reentry_check_;                      // Track()'s thread
  std::vector<ReentryKeyframe> reentry_kfs_;        // CheckReentry's keyframes, reused
  FramePacker packer_;                              // kOnDemand: packs a new keyframe's feature inputs (Track()'s thread)
  // Edges that wait for Optimize (defer_keyframe_edges), in the order Track() would have added them:
  // from < 0, keyframe `to`'s edges (AddKeyframeEdges); else a reuse edge (AddReuseEdge).
  struct DeferredEdge {
    int from = -1, to = -1;
  };
  std::vector<DeferredEdge> deferred_edges_;
  PointMap map_;
  bool insert_pending_ = false;   // map_samples_ go into map_ at pending_pose_ (CommitView)
  Rigid3d pending_pose_ = Rigid3d::Identity();
  // RunIcp's model samples near the view and its association grids (kGrid), refilled for every ICP
  // with their buffers reused: Track()'s thread only.
  mutable SurfacePoints gathered_;
  // Track()'s samples of the view (for ICP; more_samples_ after augmentation) and on the map's
  // lattice (for Insert), refilled every view with their buffers reused: Track()'s thread only.
  SurfacePoints view_samples_, more_samples_, map_samples_;
  mutable GridTarget grid_;
  PoseGraph graph_;
  std::vector<Keyframe> keyframes_;
  // The current keyframe (views anchor to it: the newest, or an older one reused since), the view
  // that made it current, and its samples as an occupancy map (its camera frame), built when it
  // became current: every later view's keyframe test measures its overlap with it. Touched only by
  // Track()'s thread; −1 / null until the first keyframe.
  int current_kf_ = -1;
  int64_t current_since_ = -1;
  std::unique_ptr<PointMap> current_occupancy_;
  int keyframes_reused_ = 0;
  TrackingState state_ = TrackingState::kInitialising;
  int64_t index_ = -1;                // current view index
  MotionModel motion_;                // the last placed poses: prediction, motion check
  static constexpr size_t kRecentResiduals = 16;  // the "last 16" of map_max_rmse_ratio
  std::vector<double> recent_rmse_mm_;  // ICP residuals of the last kRecentResiduals accepted views (ring)
  size_t recent_rmse_next_ = 0;
  void PushRecentRmse(double rmse_mm);
  int gated_run_ = 0;  // views in a row kept out of the model
  int coast_run_ = 0;  // views in a row coasted (TrackerOptions::max_coast_views)
  // Coasts the view (see TrackerOptions::max_coast_views) when `icp` (from `prediction`) allows it:
  // true and *out filled (refused, the state kept), false when it does not apply.
  bool Coast(const SurfacePoints& samples, const cv::Mat& points, const cv::Mat& normals, const Rigid3d& prediction,
             TrackResult* out);
  // The view's samples (map_stride) into the tracking model at `pose`: now, or left pending for
  // CommitView (defer_model_insert).
  void InsertIntoModel(const cv::Mat& points, const cv::Mat& normals, const Rigid3d& pose);
  // confirm_reentry: the pending re-entry candidate (view index, capture time, pose, how found).
  struct ReentryCandidate {
    bool pending = false;
    int64_t view = -1, capture_ns = 0;
    Rigid3d world_from_cam = Rigid3d::Identity();
    std::string how;
  };
  ReentryCandidate candidate_;
  // ICP of this view from the candidate's pose; true (and *out filled) when it confirms it.
  bool ConfirmReentry(const SurfacePoints& samples, TrackResult* out);
  // Per view: anchor keyframe (−1 = refused) and keyframe_from_cam.
  std::vector<int> anchor_;
  std::vector<Rigid3d> kf_from_cam_;
  // Per view, what UndoFrom needs to replay the state the kept views left: the model's Insert count
  // at its start, and for an accepted view its pose, capture time, residual pushed to
  // recent_rmse_mm_ (< 0: none), whether it entered the model, whether it was a re-entry, and the
  // view that made its keyframe current (current_since_; the keyframe itself is anchor_'s), and the
  // pose graph's edges and the deferred ones at its start (a keyframe reuse adds an edge between two
  // older keyframes).
  struct ViewLog {
    int64_t map_inserts_before = 0;
    size_t edges_before = 0, deferred_edges_before = 0;
    int64_t current_since = -1;
    int64_t capture_ns = 0;
    int lost_with_points_before = 0;  // lost_with_points_ when the view came (UndoFrom restores it)
    double rmse_pushed_mm = -1;
    bool in_model = false;
    bool motion_restart = false;  // no velocity across it: a re-entry or a segment's first view
    bool coasted = false;  // refused but carried the motion model (TrackerOptions::max_coast_views)
    Rigid3d pose = Rigid3d::Identity();
  };
  std::vector<ViewLog> view_log_;
  // Segments: [0] the first; a segment's first view and keyframe, whether it was joined to the main
  // model, and the keyframe count at its last join attempt. Track()'s thread only.
  struct Segment {
    int64_t first_view = 0;
    bool joined = false;
    size_t keyframes_at_attempt = 0;
    size_t feature_cursor = 0;  // the next main keyframe the join's feature matching tries
  };
  std::vector<Segment> segments_ = {Segment{}};
  int active_segment_ = 0;
  int lost_with_points_ = 0;       // views in a row refused while lost (with enough points)
  int64_t undo_barrier_view_ = 0;  // UndoFrom does not reach before this view (a segment's start or join)
  SegmentJoinTarget join_target_;  // the main model's join features, made when a segment starts (the main model rests meanwhile)
  bool KeyframeInActiveSegment(int k) const;
};

}  // namespace d3d
