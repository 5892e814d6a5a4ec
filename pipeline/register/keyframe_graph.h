// The tracker's keyframes and their pose graph: which views become keyframes (overlap with the
// current one, turn, age, a jump from the prediction), the reuse of an older keyframe that already
// covers a view, the edges between keyframes (ICP between their own samples) and the loop closures
// of each new keyframe, deferred to Optimize() on request, and the keyframes' relocalisation
// features (extracted in Track(), on a worker thread, or on demand).
//
// Owns: the keyframes (samples, features, packed feature inputs), the pose graph, the current
// keyframe and its occupancy map, the deferred edges, and the feature worker. Everything is touched
// by Track()'s thread (the Tracker that composes it), except that the feature worker thread
// (FeatureTiming::kWorker) reads its own copies of a keyframe's points and texture and writes its
// features into its own results queue, which Track()'s thread collects (CollectFeatures).
#pragma once

#include <cstdint>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <type_traits>
#include <vector>

#include "common/core/status.h"
#include "common/pack/frame_pack.h"
#include "pipeline/register/features.h"
#include "pipeline/register/icp.h"
#include "pipeline/register/odometry.h"
#include "pipeline/register/point_map.h"
#include "pipeline/register/pose_graph.h"
#include "pipeline/register/track_result.h"

namespace d3d {

// FeatureOptions with image_scale 0.5 (the keyframes' features: as many view pairs aligned as at
// full size, several times faster; docs/decisions/0008).
FeatureOptions HalfScaleFeatures();

struct KeyframeGraphOptions {
  // A view whose overlap index with the current keyframe (fraction of its samples in the
  // keyframe's occupied voxels) falls below this becomes a keyframe.
  double overlap = 0.7;
  // ... or whose camera turned by more than max_rotation_deg since the current keyframe, or after
  // max_views views on it (0 = off): a probe rolling round a distal molar or lingering keeps its
  // overlap, and the views hanging on one keyframe get no loop (docs/decisions/0008).
  double max_rotation_deg = 8.0;
  int max_views = 45;
  // ... or whose pose jumped from the motion prediction by more than these (0 = off): it becomes a
  // keyframe of its own (never an older one reused), so its pose comes from the pose graph's edges
  // rather than carrying the jump (docs/decisions/0003).
  double jump_mm = 0.7;
  double jump_deg = 1.2;
  // Reuse: a view that would become a keyframe makes an older one current again instead when that
  // one's centre lies within reuse_radius_mm of the view's, turned at most max_rotation_deg / 2,
  // and it overlaps the view by `overlap` (of the reuse_candidates nearest, the first that passes).
  // Why: a probe circling one tooth kept making keyframes, each holding memory
  // (docs/decisions/0008). 0 = never reuse; d3d-scan: 2 mm.
  double reuse_radius_mm = 0;
  int reuse_candidates = 3;
  int stride = 4;                                 // px lattice of a keyframe's samples
  FeatureOptions features = HalfScaleFeatures();  // keyframe and relocalisation features
  // When a keyframe's features (SIFT on three images) are extracted; the same features in every
  // mode.
  //  kInTrack:  in Track(), when the keyframe is made.
  //  kWorker:   on a worker thread (Track() pays a copy of the points and texture); a
  //             relocalisation first waits for every keyframe's features.
  //  kOnDemand: when a relocalisation or join first matches against the keyframe; until then it
  //             keeps its points and texture packed (less than the features), freed once extracted.
  enum class FeatureTiming { kInTrack, kWorker, kOnDemand };
  FeatureTiming feature_timing = FeatureTiming::kInTrack;
  // A new keyframe's edges (odometry ICP and loop search, up to 10 ICPs) are measured in Optimize()
  // instead of in Track(): the same edges (the graph's poses do not move before, but for a loop
  // correction: OptimizeNow), only TrackResult::loops_added stays 0. For a live host, whose Track()
  // is on the critical path.
  bool defer_edges = false;
  bool detect_loops = true;       // search loop closures for each new keyframe
  double loop_radius_mm = 10.0;   // keyframe centres closer than this are loop candidates
  int loop_min_separation = 10;   // keyframes
  double loop_min_overlap = 0.3;  // overlap index of a loop candidate with the new keyframe
  int max_loop_candidates = 6;    // per new keyframe, older than loop_min_separation, nearest first
  // Per new keyframe, edges to recent keyframes too (2 .. loop_min_separation − 1 back), nearest
  // first: several overlapping neighbours constrain a keyframe whose own registration was weak.
  int near_loop_candidates = 3;
  // The information of those near loops times this (0 < f ≤ 1): their errors are correlated with
  // the odometry edge beside them, which the graph would otherwise count twice
  // (docs/decisions/0008).
  double near_loop_information_factor = 0.25;
  // Odometry edges measured by ICP between the keyframes' own samples with ICP's information
  // (× edge_information_scale); loop edges use that information too. false: the tracked relative
  // pose on the σs below (also the edge of a keyframe whose ICP to its parent failed).
  bool icp_edges = true;
  // > 0 (with icp_edges): a second odometry edge per keyframe, the tracked relative pose with the
  // ICP edge's information × this factor. Off by default: it steadies a single pass but carries the
  // tracker's drift into the loop-closing full arch (docs/decisions/0008). d3d-fuse / d3d-scan
  // --tracked-edge-factor.
  double tracked_edge_information_factor = 0.0;
  double edge_information_scale = 1e-3;  // ICP information × this on ICP edges (icp_edges)
  double odometry_sigma_mm = 0.005, odometry_sigma_rad = 1e-4;  // edge σ (without ICP information)
  double loop_sigma_mm = 0.005, loop_sigma_rad = 1e-4;  // loop edge σ (without ICP information)
  void Check() const;                                   // throws std::invalid_argument
};

// ICP levels of keyframe-to-keyframe registration (gates 0.5 → 0.1 mm), acceptance from `base`.
IcpOptions KeyframeIcp(const IcpOptions& base = DefaultTrackerIcp());

// A pose-graph edge measured by ICP between two keyframes' own samples (their camera frames,
// normals required): `to_samples` registered onto a k-d tree of `from_samples` starting from
// `guess` (from_from_to). On success *edge gets from_from_to and ICP's information matrix times
// information_scale (pose_graph.h EdgeInformationFromIcp); its nodes and `loop` are left to the
// caller. Returns false (edge untouched) when the ICP is not ok; *result (optional) gets the ICP.
bool MeasureKeyframeEdge(const SurfacePoints& from_samples, const SurfacePoints& to_samples,
                         const Rigid3d& guess, const IcpOptions& icp, double information_scale,
                         PoseGraphEdge* edge, IcpResult* result = nullptr);

struct Keyframe {
  int64_t view = 0;       // index of the view (Track call) it was made from
  int node = 0;           // pose graph node
  SurfacePoints samples;  // camera frame
  ViewFeatures features;  // camera frame (kWorker: once collected; kOnDemand: once extracted)
  // kOnDemand: the inputs of its features (points H×W CV_32FC3, texture H×W CV_8U or empty), packed
  // losslessly (common/pack/frame_pack.h; texture: empty when there is none) until a relocalisation
  // extracts them (both released then; sizes: docs/decisions/0008). A keyframe's points are never
  // empty.
  std::string packed_feature_points, packed_feature_texture;
  int segment = 0;  // the scan segment it was made in (segments.h)
  bool features_pending() const { return !packed_feature_points.empty(); }
  // Bytes the keyframe holds: samples, features and packed feature inputs.
  int64_t bytes() const;
  Eigen::Vector3d centre_in_cam = Eigen::Vector3d::Zero();
  // The keyframe the views were anchored to when this one was made (its odometry edge starts
  // there): the previous keyframe, or an older one reused since; −1 for the first.
  int parent = -1;
};
// Its members move without throwing (ViewFeatures declares so for its cv::Mats), so
// std::vector<Keyframe> moves keyframes when it grows rather than copying them (see ViewFeatures).
static_assert(std::is_nothrow_move_constructible_v<Keyframe>,
              "std::vector<Keyframe> must move keyframes when it grows, not copy them");

class KeyframeGraph {
 public:
  // tracking_icp: the frame-to-model ICP, whose acceptance KeyframeIcp keeps; with_features: the
  // keyframes carry relocalisation features. Throws for invalid options.
  KeyframeGraph(const KeyframeGraphOptions& options, const IcpOptions& tracking_icp,
                bool with_features);
  ~KeyframeGraph();
  const KeyframeGraphOptions& options() const { return o_; }

  // With feature_timing kWorker or kOnDemand, a keyframe's features may still be pending (empty).
  const std::vector<Keyframe>& keyframes() const { return keyframes_; }
  bool empty() const { return keyframes_.empty(); }
  int size() const { return static_cast<int>(keyframes_.size()); }
  const PoseGraph& graph() const { return graph_; }
  const Rigid3d& world_from_keyframe(int k) const {
    return graph_.pose(keyframes_[static_cast<size_t>(k)].node);
  }
  Eigen::Vector3d CentreInWorld(
      int k) const {  // keyframe k's surface centre at its graph pose (mm)
    const Keyframe& kf = keyframes_[static_cast<size_t>(k)];
    return graph_.pose(kf.node) * kf.centre_in_cam;
  }
  int current() const { return current_kf_; }  // the keyframe views anchor to now (−1: none yet)
  int64_t current_since() const { return current_since_; }  // the view that made it current
  int reused() const { return keyframes_reused_; }  // times an older keyframe became current again
  int64_t bytes() const;                            // the keyframes' Keyframe::bytes(), summed
  int loop_edges() const;

  // The keyframe step of an accepted view `view` (points, normals H×W CV_32FC3 camera frame,
  // texture H×W CV_8U or empty) at `pose` (world_from_cam) in segment `segment`: it becomes a
  // keyframe, reuses an older one, or anchors to the current one. Reads out->prediction_offset_mm /
  // _deg; sets out->new_keyframe, keyframe_reused, loops_added.
  void Update(const cv::Mat& points, const cv::Mat& normals, const cv::Mat& texture,
              const Rigid3d& pose, int64_t view, int segment, TrackResult* out);

  // How far the drift since an older keyframe has put keyframe k: of k's loop candidates (at least
  // loop_min_separation before it, centre within loop_radius_mm: DetectLoops' candidates), the
  // nearest candidates + 2 are tested, and up to `candidates` that overlap k by loop_min_overlap at
  // the graph's poses get k's samples registered onto theirs (keyframe ICP from the graph's
  // relative pose); returns the largest distance (mm) by which that moves k's surface centre. −1
  // when no candidate overlaps or every ICP failed; detect_loops off: −1. The edges measured go to
  // *loops (loop edges, on the loop σs), not into the graph; *tested gets the candidates tested.
  double LoopDiscrepancyMm(int k, int candidates, std::vector<PoseGraphEdge>* loops,
                           int* tested) const;
  // Optimises the pose graph now, from what is measured: without defer_edges, Optimize. With it,
  // the deferred edges stay deferred (Optimize measures them later, from the poses this leaves): a
  // copy of the graph gets, for each keyframe whose edges wait, its tracked relative pose to its
  // parent (the odometry σs), and `loops`; the copy is solved and its poses taken. Why: measuring
  // every deferred edge at the first loop closure stalled Track() for seconds
  // (docs/decisions/0020).
  [[nodiscard]] Status OptimizeNow(const PoseGraphOptions& options,
                                   const std::vector<PoseGraphEdge>& loops,
                                   PoseGraphSummary* summary);

  // Keyframe k's features, extracted first when kOnDemand left them pending.
  const ViewFeatures& Features(int k);
  // Waits for the feature worker's pending keyframes and moves their features into the keyframes.
  void CollectFeatures();

  // The ICP edge of keyframe `to`'s samples onto keyframe `from`'s from their current relative
  // pose, on the loop σs (false when the ICP fails).
  bool MeasureEdge(int from, int to, PoseGraphEdge* edge) const;
  void AddEdge(const PoseGraphEdge& edge) { graph_.AddEdge(edge); }
  // Sets keyframe k's graph pose (world_from_keyframe).
  void SetPose(int k, const Rigid3d& world_from_keyframe) {
    graph_.set_pose(keyframes_[static_cast<size_t>(k)].node, world_from_keyframe);
  }
  // Moves the graph poses of segment s's keyframes by T (a join: main_from_segment).
  void MoveSegment(int s, const Rigid3d& T);
  // A segment starts: no keyframe is current.
  void ForgetCurrent();

  // Adds the deferred edges (in Track()'s order), then optimises the pose graph.
  [[nodiscard]] Status Optimize(const PoseGraphOptions& options, PoseGraphSummary* summary);

  // Undo: the edge counts to truncate back to (graph, deferred), and dropping the keyframes made
  // from view first_view on, with (truncate_edges) the edges added since the counts were taken.
  // Returns how many keyframes went.
  size_t edges() const { return graph_.edges().size(); }
  size_t deferred_edges() const { return deferred_edges_.size(); }
  int DropFrom(int64_t first_view, bool truncate_edges, size_t edges_before,
               size_t deferred_before);
  // Makes keyframe k (< size(); −1: none) current since view `since`.
  void SetCurrent(int k, int64_t since);

 private:
  // Reuse (reuse_radius_mm): makes an older keyframe covering the view (samples kfs, camera frame,
  // at `pose`) the current one; false when none does. On success, the keyframe left and the one
  // reused get a loop edge (AddReuseEdge).
  bool Reuse(const SurfacePoints& kfs, const Rigid3d& pose, int64_t view);
  // A loop edge measured by ICP between keyframes from < to (near_loop_information_factor when
  // fewer than loop_min_separation apart); none when an edge joins them already or the ICP fails.
  void AddReuseEdge(int from, int to);
  // The pose-graph edges of keyframe k (to its parent, and loop closures): returns the loops added.
  int AddKeyframeEdges(int k);
  int DetectLoops(int k);
  // Keyframe k's loop candidates, nearest first as (distance mm, keyframe): older keyframes but its
  // parent whose centres lie within loop_radius_mm of k's at the graph's poses; *far those at least
  // loop_min_separation before k, *near (optional) the others from k − 2 back.
  void LoopCandidates(int k, std::vector<std::pair<double, int>>* far,
                      std::vector<std::pair<double, int>>* near) const;
  // The edge parent → k on the odometry σs, at the graph's relative pose (the tracked one).
  PoseGraphEdge TrackedOdometryEdge(int parent, int k) const;

  class FeatureWorker;  // feature_timing kWorker (keyframe_graph.cpp)

  KeyframeGraphOptions o_;
  IcpOptions keyframe_icp_;  // KeyframeIcp of the tracking ICP
  bool with_features_;
  std::unique_ptr<FeatureWorker> feature_worker_;  // null unless feature_timing is kWorker
  FramePacker packer_;  // kOnDemand: packs a new keyframe's feature inputs
  PoseGraph graph_;
  std::vector<Keyframe> keyframes_;
  // Edges that wait for Optimize (defer_edges), in the order Track() would have added them:
  // from < 0, keyframe `to`'s edges (AddKeyframeEdges); else a reuse edge (AddReuseEdge).
  struct DeferredEdge {
    int from = -1, to = -1;
  };
  std::vector<DeferredEdge> deferred_edges_;
  // The current keyframe (views anchor to it: the newest, or an older one reused since), the view
  // that made it current, and its samples as an occupancy map (its camera frame), built when it
  // became current: every later view's keyframe test measures its overlap with it. −1 / null until
  // the first keyframe.
  int current_kf_ = -1;
  int64_t current_since_ = -1;
  std::unique_ptr<PointMap> current_occupancy_;
  mutable SurfacePoints check_samples_;  // LoopDiscrepancyMm: every 4th of the keyframe's samples
  int keyframes_reused_ = 0;
};

}  // namespace d3d
