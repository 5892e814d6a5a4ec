// The scan chain of one hand-held scan, as reusable pieces: per burst reconstruct → register
// (frame-to-model tracking) → fuse (TSDF), and at the end the pose graph, the mesh, the evaluation
// against a known scene and report.json. Used by d3d-scan (on the host's stage graph, one piece per
// thread) and meant for d3d-fuse (all pieces on one thread).
//
//   ScanReconstructor  reconstruct thread: burst frames → ReconstructedView (pipeline/recon)
//   ScanRegistrar      register thread:    view → TrackResult (pipeline/register Tracker), with the
//                      per-view records, tracking counters and events of report.json
//   ScanFuser          fuse thread:        accepted view + pose → TSDF (pipeline/fuse)
//   FinishScan         one thread, after the others stopped (it reads the registrar and the fuser):
//                      Tracker::Optimize (loop closures), optionally the accepted views fused again
//                      at the optimised poses (that volume then replaces the fuser's, so no other
//                      thread may read the fuser meanwhile; a helper thread of its own calls the
//                      provider and the registrar's anchorer for the next views meanwhile), mesh
//                      extraction, evaluation against the scene (pipeline/eval) when one is given,
//                      and the report (the fields of issue 5).
//   WriteScanOutputs   DIR/scan.ply, DIR/scan.stl (binary, mm), DIR/poses.txt (TUM, mm),
//                      DIR/report.json, DIR/heatmap.png (with an evaluation).
//
// Threads: each piece is owned by one thread at a time (none is thread-safe); hand-over between
// threads must be synchronised by the caller (the stage graph's edges, or joining the threads).
// The model frame is the first accepted view's camera frame (Tracker).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "calib/model/probe_calibration.h"
#include "common/core/rigid.h"
#include "common/core/status.h"
#include "common/mesh/mesh.h"
#include "common/mesh/mesh_clean.h"
#include "pipeline/chain/model_anchor.h"
#include "pipeline/chain/view_archive.h"
#include "pipeline/eval/evaluate_scan.h"
#include "pipeline/fuse/free_space.h"
#include "pipeline/fuse/tsdf.h"
#include "pipeline/recon/reconstruct.h"
#include "pipeline/register/tracker.h"

namespace d3d {

// Reconstruction of a hand-held scan: ReconstructOptions' defaults with the phase's in-burst motion
// compensation on (PhaseOptions::motion_compensation, pipeline/phase/phase.h). The hand moves while
// the burst's four frames are taken (7.5 ms from first to last); the drift of the phase this leaves
// is structured (at Φ and 2Φ, with the sign of the motion), so consecutive views are distorted
// alike and frame-to-model ICP drifts on it. Typodont full arch, seed 3, --every 2: rendered with
// no in-burst motion the first 200 views fuse to 6.3 µm RMS (6.1 at the true poses), with it to
// 35.2 µm. Whole arch, RMS / p95 µm, ATE mm, without → with compensation: typodont s3 14.1 / 26.6 /
// 0.090 → 10.1 / 18.3 / 0.061, s1 8.5 / 16.5 / 0.067 → 9.0 / 17.6 / 0.051; real arch s1 8.8 / 16.4
// / 0.057 → 7.3 / 14.4 / 0.057, s3 13.1 / 29.0 / 0.079 → 14.9 / 21.0 / 0.075 (a tail of border
// points). Cost: ~8 ms more per burst in reconstruction.
ReconstructOptions HandHeldReconstructOptions();

// The live volume a scan fuses every view into as it goes when its views are kept and fused again
// at the end at the scan's voxel (FinishScan's refusion): the final model does not depend on it (a
// host saves it mid-scan), so it is coarser and its per-pixel work thinner; its band (truncation)
// is at least 2 voxels. At 0.1 mm the band held 1/8 of the voxels of 0.05 mm: the fuse stage's CPU
// per burst fell 17.9 -> 7.9 ms (lossless replay of 200 typodont bursts at bin 2), lossless
// throughput rose 22.9 -> 26.9 bursts/s, a 0.1 mm model of the same views as true (9.4 vs 10.9 um
// RMS) with 0.8 pp less coverage. At 0.2 mm (issue 51; 450-burst replay, two interleaved pairs) the
// fuse stage's CPU is 8.06 / 7.34 -> 4.07 / 4.23 ms (the rest is the per-pixel passes, the
// occlusion and free-space tests and the packing of the kept frames); a save 13 s into that
// replay: 14.4 -> 15.7 um RMS, coverage 44.4 -> 42.1 % of the typodont. The strides: the occlusion
// test on every occlusion_stride-th pixel (TsdfOptions::occlusion_stride; the scan's is 2), the
// leaves allocated from every pixel_stride-th pixel (TsdfOptions::pixel_stride; a binned pixel is
// ~0.06 mm on the teeth, the band +-0.3 mm around it); on a 0.1 mm volume of the virtual probe's
// 1492-burst full arch at bin 2: fuse 5.68 -> 3.86 ms per burst, trueness 7.58 -> 7.60 um RMS,
// coverage 94.25 -> 94.24 %.
struct LiveVolumeOptions {
  double voxel_mm = 0.2;  // 0 = the scan's voxel (the live volume is then fused as the scan's)
  int occlusion_stride = 4;
  int pixel_stride = 2;
  // `scan` at voxel_mm with these strides; `scan` itself when voxel_mm is 0.
  TsdfOptions Of(const TsdfOptions& scan) const;
  void Check() const;  // throws std::invalid_argument (negative voxel, strides < 1)
};

struct ScanOptions {
  // Camera pixels averaged over bin × bin blocks before reconstruction (BinFrame, pipeline/recon):
  // views, tracking and fusion then work on (H/bin) × (W/bin) maps with BinnedCalibration, about
  // bin² less work per burst. Set it with ScanOptionsForBin, which also scales the pixel lattices
  // of the tracker and the fusion. 1 = full resolution.
  int bin = 1;
  ReconstructOptions recon = HandHeldReconstructOptions();
  // tracker.keyframes.detect_loops: keyframe loop closures and the pose graph at the end; a scan
  // corrects loops as they close (tracker.loop_correction on: its views are fused again at the end
  // when it did, FinishScan).
  TrackerOptions tracker = [] {
    TrackerOptions t;
    t.loop_correction.enabled = true;
    return t;
  }();
  ModelAnchorOptions anchor;  // model-guided anchoring in the register stage (model_anchor.h)
  TsdfOptions tsdf;
  FreeSpaceOptions
      free_space;  // ScanFuser: points in space earlier views saw through are not fused
  // Fuse the accepted views again at the optimised poses when the pose graph moved a view by more
  // than this (mm) and FinishScan is given a view provider; < 0 never (unless views were undone, or
  // the live volume's voxel is not tsdf.voxel_mm: then always).
  double refuse_min_correction_mm = 0.01;
  // The model's mesh cleaned for the lab: bow-tie vertices split, specks removed (mesh_clean.h).
  MeshCleanOptions mesh_clean;
  EvaluateOptions eval;
  void Check() const;  // throws std::invalid_argument
};

// The live host's scan profile, one definition for d3d-scan and d3d-fuse (whose default it is), on
// top of `options`:
// - keyframe work off the register stage's critical path: a keyframe's SIFT features only when a
//   relocalisation needs them (KeyframeGraphOptions::FeatureTiming::kOnDemand), the pose graph's
//   edges (keyframe and loop-closure ICPs) at the end of the scan (defer_keyframe_edges); the same
//   poses;
// - keyframe_reuse_radius_mm 2: a probe that stays over one tooth returns to keyframes it made
//   rather than making new ones (60 s circling one molar made 151 keyframes, 105 MiB, without; a
//   full-arch sweep reuses none);
// - at most 1.6k / 4k / 8k ICP samples on the tracker's levels 0 / 1 / 2, whatever the view's size:
//   a view full of surface cost the register stage 3x a small one (typodont, 90 bursts at 30 Hz:
//   register 89 -> 76 ms per burst, trueness 7.37 -> 7.37 um, ATE 0.026 -> 0.029 mm).
// Apply it before ScanOptionsForBin (the caps are per view, whatever its pixel size).
ScanOptions LiveScanProfile(ScanOptions options);

// Tracker options for bursts `every` apart (d3d-fuse --every; a live host that drops bursts sees
// larger steps): the first ICP level's association gate min(3, 0.8·√every) mm, and the motion
// check's motion.max_step_mm / max_step_deg (per view) times `every`.
TrackerOptions TrackerOptionsForStep(TrackerOptions options, double every);

// `options` for views binned bin × bin (ScanOptions::bin): the tracker's pixel lattices (ICP
// samples, model samples, keyframe samples) divided by bin, at least 1, with min_view_samples
// scaled to the same share of the view, its keyframe features on larger images (image_scale × bin,
// at most 1: OpenCV's SIFT then still searches down to the binned pixel) and the projective model
// image at the same size in full-resolution pixels. The TSDF's occlusion lattice stays in binned
// pixels (at bin 2, one ray per 4 × 4 camera pixels): divided by bin it tested every binned pixel,
// 6 % of a lossless host's CPU; on the 450-burst typodont replay (refused at the pose graph's
// poses) every second one gives trueness 11.534 → 11.538 µm RMS, points occluded 107 → 104, and
// the test takes 2.7 % of the CPU.
// bin = 1 returns `options`. Throws std::invalid_argument for bin < 1.
ScanOptions ScanOptionsForBin(ScanOptions options, int bin);

class ScanReconstructor {
 public:
  // `calibration` is the probe's (full resolution); with bin > 1 each frame is averaged over bin ×
  // bin blocks (BinFrame) and reconstructed with BinnedCalibration(calibration, bin). Throws
  // std::invalid_argument for an invalid calibration or options, bin < 1 or a camera size not
  // divisible by bin.
  ScanReconstructor(const ProbeCalibration& calibration, const ReconstructOptions& options,
                    int bin = 1);
  // frames: the burst's frames (at least calibration.pattern.steps; extra ones, e.g. a texture
  // frame, are ignored), H×W CV_8U/CV_16U of the probe's camera size. INVALID_ARGUMENT for too few
  // or mis-sized frames.
  [[nodiscard]] Status Reconstruct(const std::vector<cv::Mat>& frames, ReconstructedView* out);
  // The calibration of the reconstructed views (binned when bin > 1).
  const ProbeCalibration& calibration() const { return recon_.calibration(); }
  // The frames the last Reconstruct ran on: binned (this object's buffers, rewritten by the next
  // call) when bin > 1, else headers of the caller's frames. A ScanReconstructor built with
  // calibration() and bin 1 reconstructs them into the same view bit for bit (ViewArchive).
  const std::vector<cv::Mat>& frames_used() const { return phase_frames_; }
  int bin() const { return bin_; }

 private:
  int bin_;
  Reconstructor recon_;
  std::vector<cv::Mat> phase_frames_;
  std::vector<cv::Mat> binned_frames_;  // bin > 1: the binned frames, reused
};

// One Track() call.
struct ScanViewRecord {
  uint64_t burst_seq = 0;    // the probe's burst sequence number
  int64_t reference_ns = 0;  // capture time of the burst (mid-burst, ns)
  bool accepted = false;
  TrackingState state = TrackingState::kInitialising;
  // Registered only to bridge a gap before another view (host/app/gap_bridge.h): it helped the
  // track but is not one of the scan's views (not fused, no pose in the result).
  bool bridge = false;
};

class ScanRegistrar {
 public:
  // Tracking only: the views are registered as reconstructed.
  ScanRegistrar(const PinholeBrownConrady& camera, const TrackerOptions& options);
  // Tracking with model-guided anchoring (model_anchor.h): after a view's pose is found, the parts
  // its burst could not anchor are anchored against the model, added to the view and registered
  // with it. normal_max_gap_mm: ReconstructOptions::normal_max_gap_mm. Throws std::invalid_argument
  // for invalid options or calibration.
  ScanRegistrar(const ProbeCalibration& calibration, const TrackerOptions& options,
                const ModelAnchorOptions& anchor, double normal_max_gap_mm);
  // Registers one reconstructed view (view index = the number of earlier calls). With model
  // anchoring, `view` gains the anchored points (its unwrap, points and normals are rewritten in
  // place); fuse it after this call. The points the edge fill gave the view (pipeline/unwrap/
  // edge_fill.h: those in the albedo-edge cut) are not registered and do not enter the tracking
  // model or the pose graph's keyframes: their error (tens of µm, from the camera's blur across
  // the border) would bias the pose, which every other point of the view then inherits; they are
  // there for the fusion's coverage. Typodont seed 2 with them registered: ATE 0.048 → 0.067 mm,
  // trueness 7.9 → 12.1 µm RMS.
  // bridge: the view is registered only to bridge a gap before another one
  // (ScanViewRecord::bridge): left out of the result and of the counts of views accepted and
  // refused; its events say "bridge".
  TrackResult Register(ReconstructedView& view, uint64_t burst_seq, int64_t reference_ns,
                       bool bridge = false);
  // With OdometryOptions::defer_model_insert: the last Register's model insert, which Register left
  // pending (Tracker::CommitView); call it once the view has been passed on. The next Register or
  // UndoLastSeconds runs a pending one first.
  void Commit();
  // Model anchoring of a view reconstructed again (FinishScan's refusion), against the whole model
  // (the tracker's, built at the tracked poses: give the view's tracked pose); returns the pixels
  // anchored (0 without model anchoring).
  int64_t AnchorAtPose(const Rigid3d& world_from_cam, ReconstructedView* view);
  // Records a view as accepted at a pose known from elsewhere, without registering it (d3d-fuse
  // --truth-poses: the fusion-only error floor). A scan uses either this or Register, not both.
  void RegisterAtPose(uint64_t burst_seq, int64_t reference_ns, const Rigid3d& world_from_cam);
  // The current pose of view `index` (0-based, in call order): the given one (RegisterAtPose) or
  // the tracker's (after Optimize, the optimised one); false for a refused or undone view.
  bool ViewPose(int64_t index, Rigid3d* world_from_cam) const;
  // The group of frames view `index` was placed in: 0 for the main one (always with RegisterAtPose;
  // with Register, the first segment and those joined to it: Tracker::SegmentInMain), else its
  // scan segment's number; −1 for a refused or undone view, or a bridge (Register's `bridge`).
  int ViewGroup(int64_t index) const;
  // "Undo last seconds" (Register's views only, before FinishScan): the accepted views captured
  // within `seconds` of the newest accepted one (reference_ns; without capture times, the newest
  // accepted view only), back to the oldest the tracker can still undo
  // (OdometryOptions::map.undo_inserts), are taken back (Tracker::UndoFrom): they stay in views()
  // as not accepted, count in views_undone() and an "undo" event, and leave the pose graph and the
  // refusion. A fuser that fused them still holds them: FinishScan then fuses the kept views again.
  struct UndoResult {
    bool ok = false;
    std::string reason;         // why nothing was undone
    int64_t first_view = -1;    // views first_view … views().size() − 1 were taken back
    int64_t views_undone = 0;   // of them accepted ones
    bool clamped = false;       // the journal did not reach back `seconds`
    double seconds_undone = 0;  // capture time from the first undone view to the newest one
  };
  UndoResult UndoLastSeconds(double seconds);
  // Tracker::RetractLoss for the last view; the loss it counted (lost_events) is taken back too.
  bool RetractLoss();
  // Tracker::ReinstateLoss, and the loss counted again.
  bool ReinstateLoss();
  int64_t views_undone() const { return views_undone_; }

  Tracker& tracker() { return tracker_; }
  const Tracker& tracker() const { return tracker_; }
  const std::vector<ScanViewRecord>& views() const { return views_; }
  int64_t accepted() const { return accepted_; }
  int64_t rejected() const { return rejected_; }
  int64_t lost_events() const { return lost_events_; }  // transitions into kLost
  int64_t relocalised() const { return relocalised_; }
  const nlohmann::json& events() const {
    return events_;
  }                                           // non-tracking states and refusals, with reasons
  double ms_register() const { return ms_; }  // total wall time in Register
  int64_t pixels_model_anchored() const {
    return pixels_anchored_;
  }                                                                 // model anchoring, in Register
  int64_t views_model_anchored() const { return views_anchored_; }  // views that gained points
  double ms_model_anchor() const { return ms_anchor_; }  // of ms_register(): in the anchorer

 private:
  Tracker tracker_;
  std::unique_ptr<ModelAnchorer> anchorer_;  // null: no model anchoring
  int64_t pixels_anchored_ = 0, views_anchored_ = 0;
  double ms_anchor_ = 0;
  std::vector<ScanViewRecord> views_;
  std::vector<Rigid3d> given_poses_;  // RegisterAtPose, one per view
  // The view's points and normals without the edge-filled ones, what Register gives the tracker
  // (reused buffers; the register thread's).
  cv::Mat track_points_, track_normals_;
  void CopyWithoutEdgeFill(const ReconstructedView& view);
  int64_t accepted_ = 0, rejected_ = 0, lost_events_ = 0, relocalised_ = 0, views_undone_ = 0;
  TrackingState prev_state_ = TrackingState::kInitialising;
  TrackingState state_before_last_ =
      TrackingState::kInitialising;  // prev_state_ before the last Register
  bool retracted_counted_ = false;   // the retracted loss had counted in lost_events_
  nlohmann::json events_ = nlohmann::json::array();
  double ms_ = 0;
};

class ScanFuser {
 public:
  ScanFuser(const PinholeBrownConrady& camera, const TsdfOptions& options,
            const FreeSpaceOptions& free_space = {});
  // Fuses the view's points except those the free-space test rejects (pipeline/fuse/free_space.h);
  // the edge fill's points (quality reason kModulationEdge) as the volume's secondary points when
  // its options fade them (TsdfOptions::secondary_fade_weight).
  [[nodiscard]] Status Fuse(const ReconstructedView& view, const Rigid3d& world_from_cam);
  const FreeSpaceOptions& free_space_options() const { return free_space_.options(); }
  int64_t free_space_rejected() const { return free_space_rejected_; }  // points, over all views
  TsdfVolume& volume() { return *tsdf_; }
  const TsdfVolume& volume() const { return *tsdf_; }
  const PinholeBrownConrady& camera() const { return camera_; }
  int64_t fused() const { return fused_; }
  double ms_fuse() const { return ms_; }
  // Replaces this fuser's volume by `other`'s (FinishScan, once a refusion is complete) and frees
  // the old one before the mesh is extracted, so that the two volumes and the mesh are never held
  // at once; fused() and ms_fuse() keep counting the views fused here, free_space_rejected() takes
  // `other`'s (the points its volume left out). `other` is left empty.
  void AdoptVolume(ScanFuser&& other);

 private:
  PinholeBrownConrady camera_;
  std::unique_ptr<TsdfVolume> tsdf_;
  FreeSpaceTest free_space_;
  cv::Mat rejected_,
      masked_;         // per view, reused: the free-space test's mask, the points without them
  cv::Mat secondary_;  // per view, reused: CV_8U, 255 = an edge-filled point
  int64_t free_space_rejected_ = 0;
  int64_t fused_ = 0;
  double ms_ = 0;
};

// The scene the scan is evaluated against (optional).
struct ScanTruth {
  const TriangleMesh* reference = nullptr;  // world frame, mm (face labels: coverage of teeth only)
  // True world_from_cam of a burst, when the scan path is known (the virtual probe); else empty:
  // the best fit then starts from GlobalAlign (principal axes + ICP).
  std::function<bool(const ScanViewRecord& view, Rigid3d* world_from_cam)> true_pose;
};

// Reconstructs view `view_index` (burst `record.burst_seq`) again for the refusion pass; a non-OK
// status aborts FinishScan, NOT_FOUND skips the view. Called by FinishScan's helper thread, one
// view at a time in view order (so it must not touch what the calling thread uses meanwhile).
using ScanViewProvider =
    std::function<Status(int64_t view_index, const ScanViewRecord& record, ReconstructedView* out)>;

// The provider of a scan's kept views (ViewArchive, pipeline/chain/view_archive.h): the frames kept
// for record.burst_seq, reconstructed again by a ScanReconstructor of `view_calibration` at bin 1
// (the calibration of the views, binned when they were: the kept frames are binned already), so
// each view comes back bit for bit as it was first reconstructed. The reconstructor is made at the
// first call. `archive` must outlive the provider and not change while it is used; the provider is
// one thread's at a time (it holds the reconstructor and a frame buffer). NOT_FOUND, IO_ERROR and
// CORRUPT as ViewArchive::Get.
ScanViewProvider KeptViewProvider(const ViewArchive& archive,
                                  const ProbeCalibration& view_calibration,
                                  const ReconstructOptions& options);

struct ScanTimes {
  int64_t bursts = 0;  // bursts the chain ran on (the denominators of ms_per_burst)
  double ms_recon = 0, ms_register = 0, ms_fuse = 0;
};

// A scan segment that never joined the main model (SegmentOptions::after_views), fused on
// its own in its own frame.
struct ScanSegmentMesh {
  int segment = 0;
  int64_t views = 0;
  TriangleMesh mesh;
};

struct ScanResult {
  TriangleMesh mesh;                   // model frame, mm, with vertex normals
  std::vector<int64_t> pose_t_ns;      // accepted views: capture time ...
  std::vector<Rigid3d> poses;          // ... and model_from_cam after the pose graph
  std::vector<int64_t> pose_views;     // ... and the view (registrar's index) of each
  nlohmann::json report;               // report.json
  cv::Mat heatmap;                     // deviation heat map (empty without evaluation)
  std::vector<ScanSegmentMesh> apart;  // segments that never joined (written as segment_N.ply)
};

// After the stages stopped: see the file comment. When the registrar undid views
// (ScanRegistrar::UndoLastSeconds) the fuser's volume still holds them, so the kept views are
// always fused again (INVALID_ARGUMENT without a provider); so are they when the fuser's volume has
// another voxel than options.tsdf (a coarse live volume, LiveVolumeOptions): the refusion is always
// at options.tsdf. The report holds bursts, fused, rejected, views_undone, tracking_lost,
// relocalised, unrecovered, final_state, keyframes, loop_edges, pose_graph_max_correction_mm,
// ms_per_burst (+ per stage), ms_mesh, tsdf_* , mesh_*, events and, with a reference:
// trueness_rms_um, trueness_mean_um, trueness_mean_abs_um, trueness_p95_um, coverage_pct,
// best_fit_rmse_um, and ate_mm / ate_deg and rpe_mm / rpe_deg / rpe_max_mm / rpe_max_pose (relative
// pose error between consecutive views; NaN-free: only when true poses are known), wrong_fusions
// (views whose footprint, ViewFootprint at eval.footprint_depth_mm, is off by > 0.2 mm, or turned >
// 1°), wrong_fusions_by_camera_centre (the same rule at the camera centre), footprint_max_mm and
// wrong_fusion_views (the first 50: pose index, footprint mm, centre_mm, deg). INTERNAL when the
// model is empty (no view accepted).
[[nodiscard]] Status FinishScan(const ScanOptions& options, const ScanTimes& times,
                                ScanRegistrar* registrar, ScanFuser* fuser,
                                const ScanViewProvider& provider, const ScanTruth& truth,
                                ScanResult* out);

// The evaluation part of FinishScan, for tools that run their own chain (d3d-fuse): best fit of
// `mesh` (model frame, mm) to `scene` (world frame) — started from the trajectory alignment when
// `true_poses` (world_from_cam, one per entry of `poses`, model_from_cam) are given, else from
// GlobalAlign — then trueness, coverage and, with true poses, ATE and the wrong fusions judged at
// `footprint_in_cam` (ViewFootprint; empty: the camera centre), added to `report` under the keys
// listed at FinishScan; the deviation heat map (50 µm full scale) into `heatmap` if not null.
// Source: pipeline/eval (EvaluateTrueness, AbsoluteTrajectoryError).
void EvaluateScanAgainstScene(const TriangleMesh& mesh, const TriangleMesh& scene,
                              const std::vector<Rigid3d>& poses,
                              const std::vector<Rigid3d>& true_poses,
                              const std::vector<Eigen::Vector3d>& footprint_in_cam,
                              const EvaluateOptions& options, nlohmann::json* report,
                              cv::Mat* heatmap);

// Writes scan.ply, scan.stl, poses.txt, report.json (and heatmap.png) into `dir` (created).
[[nodiscard]] Status WriteScanOutputs(const std::string& dir, const ScanResult& result);
[[nodiscard]] Status WriteTumPoses(const std::string& path, const std::vector<int64_t>& t_ns,
                                   const std::vector<Rigid3d>& poses);

}  // namespace d3d
