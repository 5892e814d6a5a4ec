#include "pipeline/chain/scan_flags.h"

#include <stdexcept>

namespace d3d {

void DeclareScanFlags(OptionRegistry* r, ScanFlags* flags, ScanOptions* o) {
  TrackerOptions& t = o->tracker;
  TsdfOptions& tsdf = o->tsdf;
  flags->max_rmse_um = t.odometry.icp.max_rmse_mm * 1000;
  r->Add("--profile", &flags->profile,
         "scan profile: live (LiveScanProfile, pipeline/chain/scan_chain.h: keyframe work off the "
         "critical path, keyframe\n"
         "reuse, ICP sample caps per level) | full (every ICP sample, keyframe features and edges "
         "as they come)")
      .OneOf({"live", "full"});
  r->Add("--bin", &flags->bin,
         "average the camera's pixels over NxN blocks before reconstruction (1 = full resolution; "
         "2: views of a quarter "
         "the pixels, ~4x less reconstruction work)")
      .Range(1, 8);
  r->Add("--association", &flags->association,
         "the tracker's ICP data association: grid (nearest model sample, on a decimated model at "
         "the coarse level) | "
         "kdtree (exact nearest at every level, by nanoflann) | projective")
      .OneOf({"grid", "kdtree", "projective"});
  r->Add("--max-rmse-um", &flags->max_rmse_um,
         "tracking: a view whose ICP residual (RMS, um) is above this is refused")
      .NonNegative();
  r->Add("--keyframe-max-rotation", &t.keyframes.max_rotation_deg,
         "tracking: a view that turned more than this (deg) since the last keyframe is one too (0 "
         "= off)");
  r->Add("--keyframe-max-views", &t.keyframes.max_views,
         "tracking: a view this many views after the last keyframe is one too (0 = off)");
  r->Add("--reentry-max-violation", &t.relocaliser.check.max_violation_fraction,
         "tracking: a re-entry pose is refused when more than this share of the points it compares "
         "with the keyframes\n"
         "near it lie in space one side saw through (1 = no check; "
         "ReentryCheckOptions::max_violation_fraction)")
      .Range(0.0, 1.0);
  r->Flag("--loops,!--no-loops", &t.keyframes.detect_loops,
          "loop-closure detection and the pose graph (--no-loops: none)");
  r->Flag("--loop-correction,!--no-loop-correction", &t.loop_correction.enabled,
          "tracking: optimise the pose graph when a new keyframe closes a loop and move the "
          "tracking model with it\n"
          "(LoopCorrectionOptions, pipeline/register/tracker.h); the views are fused again at the "
          "end");
  r->Add("--tracked-edge-factor", &t.keyframes.tracked_edge_information_factor,
         "pose graph: each keyframe also gets the tracked relative pose to its parent as an edge, "
         "with the keyframe ICP "
         "edge's information times this (0 = none; "
         "KeyframeGraphOptions::tracked_edge_information_factor)")
      .Range(0.0, 10.0);
  r->Flag("--model-anchor,!--no-model-anchor", &o->anchor.enabled,
          "model-guided anchoring (--no-model-anchor: the parts of a view its burst could not "
          "anchor stay out)");
  r->Add("--edge-fill-passes", &o->recon.edge_fill.passes,
         "reconstruction: pixel layers of the albedo-edge cut given the phase of the anchored "
         "pixels beside them (0 = off)")
      .Range(0, 64);
  r->Add("--edge-fill-quality", &o->recon.edge_fill.quality_factor,
         "reconstruction: a pixel filled in the albedo-edge cut weighs this times the anchored "
         "pixel it came from")
      .Range(0.001, 1.0);
  r->Add("--voxel", &tsdf.voxel_mm, "TSDF voxel (mm) of the model");
  r->Add("--truncation", &tsdf.truncation_mm, "TSDF truncation (mm)");
  r->Add("--min-mesh-weight", &tsdf.min_mesh_weight,
         "mesh only where the fused weight (sum of point qualities) is at least this");
  r->Add("--max-cell-sdf-span", &tsdf.max_cell_sdf_span,
         "mesh: drop a vertex whose 8 voxels' signed distances span more than this many cell "
         "diagonals (0 = off)");
  r->Add("--occlusion-margin", &tsdf.occlusion_margin_mm,
         "fusion: a point more than this (mm) behind a surface the model knows is not fused (0 = "
         "no test)");
  r->Add("--edge-fill-fade", &tsdf.secondary_fade_weight,
         "fusion: edge-filled points shape the surface only until the other points' fused weight "
         "reaches this (0 = they "
         "count like the rest)")
      .NonNegative();
  r->Flag("--free-space,!--no-free-space", &o->free_space.enabled,
          "fusion: a point in space that earlier views saw through is not fused (--no-free-space: "
          "no such test)");
  r->Flag("--refuse,!--no-refuse", &flags->refuse,
          "keep the fused views' frames (zstd, ~0.15 MB each at --bin 2) and fuse them again at "
          "the pose graph's poses "
          "at the end when it moved a view by more than 10 um (the mesh then does not depend on "
          "how the tracker drifted)");
  r->Add("--live-voxel", &flags->live_voxel_mm,
         "voxel (mm) of the live volume each view is fused into as the scan goes (a save mid-scan "
         "writes it; its band at "
         "least 2 voxels); with --refuse the model is the kept views fused again at --voxel at the "
         "end (0 = live at "
         "--voxel)")
      .Range(0.0, 1.0);
}

Status ApplyScanFlags(const ScanFlags& flags, double step, ScanOptions* options) {
  Association association = Association::kGrid;
  if (!ParseAssociation(flags.association, &association))
    return InvalidArgument("--association must be grid, kdtree or projective, not '" +
                           flags.association + "'");
  if (flags.profile != "live" && flags.profile != "full")
    return InvalidArgument("--profile must be live or full, not '" + flags.profile + "'");
  if (flags.bin < 1) return InvalidArgument("--bin must be >= 1");
  if (!(step >= 1)) return InvalidArgument("the step between views must be >= 1 burst");
  ScanOptions o = flags.profile == "live" ? LiveScanProfile(*options) : *options;
  o.tracker = TrackerOptionsForStep(o.tracker, step);
  o.tracker.odometry.association = association;
  o.tracker.odometry.icp.max_rmse_mm = flags.max_rmse_um / 1000.0;
  o.refuse_min_correction_mm = flags.refuse ? 0.01 : -1;
  o = ScanOptionsForBin(o, flags.bin);
  try {
    o.Check();
  } catch (const std::invalid_argument& e) {
    return InvalidArgument(std::string("scan options: ") + e.what());
  }
  *options = o;
  return Status::Ok();
}

}  // namespace d3d
