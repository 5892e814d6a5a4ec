// Truncated signed distance fusion in a sparse OpenVDB grid, and its surface as a triangle mesh.
//
// Method: Curless & Levoy 1996 ("A volumetric method for building complex models from range
// images", §3: cumulative weighted signed distance), on a sparse VDB tree as in VDBFusion (Vizzo
// et al. 2022, Sensors 22(3) 1296): only leaves (8³ voxels) within the truncation band of a view's
// points are allocated. The signed distance of a voxel centre x is taken projectively: x is moved
// into the camera, projected with the calibrated camera (distortion included), and its distance
// to the tangent plane of the measured point at that pixel, d = n·(x − p) (n toward the camera;
// positive in front of the surface, negative behind), is clamped to ±truncation; voxels more than
// one truncation behind the surface are left alone. Each view adds d with weight w = its point's
// quality (pipeline/unwrap's quality map, 0..1):
//   D ← (W·D + w·d) / (W + w),  W ← min(W + w, max_weight).
// With unit weights and no cap, D is the mean of the n measurements: noise falls as 1/√n.
// Mesh: marching cubes on the zero level (OpenVDB tools::volumeToMesh, adaptivity 0; Lorensen &
// Cline 1987 / dual-contouring topology of OpenVDB), keeping polygons whose voxel cell corners all
// carry at least min_mesh_weight (which drops the spurious crossings at the band's back and rim),
// with hysteresis (as Canny's edge linking, 1986 §III): of those polygons, only the connected
// pieces that hold at least one vertex whose corners all reach mesh_seed_weight are kept. A patch
// one view alone measured wrongly (a fringe-order error shifts a patch by a fringe's depth) never
// reaches the seed weight and goes; thin low-weight borders of the well-seen surface stay.
// Span test: a sign change is a surface only where the field behaves as a distance. Across one
// cell a distance field changes by at most the cell diagonal (√3·voxel); where two bands that
// disagree meet (the back of the band behind a surface, at −truncation, next to voxels written
// positive by views whose points lay deeper, within the occlusion margin), the sign flips in one
// step by up to two truncations, and marching cubes puts a surface there, facing into the object. A
// vertex whose 8 voxels span more than max_cell_sdf_span diagonals is dropped. Real arch, seed 3,
// full arch: such a layer 0.23–0.29 mm inside the teeth took the trueness RMS to 14.9 µm; at 3
// diagonals (0.26 mm) it is gone: 11.6 µm, coverage 95.6 → 95.4 % (at 2.5: 11.4 µm, 95.1 %; at
// 2: 11.4 µm, 94.7 %: sharp edges, where views' tangent planes disagree, also span more than one
// diagonal). Occlusion test (free-space consistency; the visibility reasoning of Merrell et al.
// 2007, "Real- time visibility-based fusion of depth maps", ICCV, §4.2 "occlusion" conflicts): a
// camera cannot see a point that lies behind a surface the model already knows well. Before a view
// is fused, the model is sampled along each point's ray toward the camera, from occlusion_margin_mm
// to occlusion_reach_mm in steps shorter than the band's back half (so the back of any surface the
// ray crosses there is hit): a sample behind a surface (D < −0.1·truncation, weight ≥
// occlusion_min_weight) marks the point occluded, and it is not fused. Such points are measurement
// errors: a patch unwrapped one fringe order off across a hidden depth step lands 1–2 mm behind the
// surface, where no other view's band reaches to correct it, and several consecutive views repeat
// it (real arch, seed 2, without the test: 0.1 % of the mesh lay 0.2–0.8 mm inside the teeth, RMS
// 26 µm instead of 9). Secondary points (a two-channel field): a view may mark some points as
// secondary, measured but less trusted (the edge fill's, pipeline/unwrap/edge_fill.h: 3–4× the
// phase error of the anchored points beside them). They should make surface where nothing better
// was seen and not pull the surface where primary points were. With the primary and secondary
// points' own running averages D_p, W_p and D_s, W_s, a voxel holds
//   D' = (W_p·D_p + λ·W_s·D_s) / (W_p + λ·W_s),  W = W_p + W_s,  λ = max(0, 1 − W_p /
//   secondary_fade_weight),
// so secondary points count fully where no primary point was fused, fade out as primary weight
// builds up, and count nothing beyond secondary_fade_weight; D' is continuous in W_p, so no seam
// forms where the two meet. D' is what is meshed and what the occlusion test reads. The volume
// stores D', W, and D_s, W_s in secondary grids; D_p follows from them, so each measurement updates
// its channel and D' is blended again. Once λ reaches 0 a voxel keeps D' = D_p, W = W_p and drops
// its secondary share (λ only falls: later secondary points there are not fused), and a secondary
// leaf without bookkeeping left is freed at the end of the view, so the secondary grids hold only
// the surface that primary points saw weakly or not at all. (With max_weight reached, W_p is
// approximate; the default cap is never reached.) Measured with secondary_fade_weight 2, full
// typodont arch: trueness RMS at true poses, seed 1, 9.23 → 8.74 µm; tracked, seeds 2 / 3,
// 9.23 → 8.83 / 12.29 → 12.20 µm; coverage unchanged (±0.02 pp). But the secondary grids kept
// 37,745 leaves (seed 3): a leaf stays while any of its voxels has W_p < 2, and the far side of
// the band, which few views reach, has such voxels almost everywhere. With two volumes held at
// the refusion, the peak RSS rose 1872 → 2312 MiB, over the 2 GiB budget, so it is off by
// default until the bookkeeping is limited to the voxels near the zero level.
// Cost: the per-pixel tests are taken once per pixel, and the voxel loop projects rows of 8 voxels
// at once in single precision (SIMD): 19–23 ms per 640×480 view on this 2-core machine, Open3D's
// ScalableTSDFVolume 37–46 ms on the same views (d3d-bench-register; 47 ms before, in double
// precision voxel by voxel). The fused field agrees with the double-precision loop's to 3 nm at
// the 99th percentile (a voxel on a pixel border may round to the neighbouring pixel).
// Thread model: one owner thread calls Integrate/ExtractMesh; Integrate uses TBB internally.
#pragma once

#include <cstdint>
#include <memory>
#include <opencv2/core.hpp>

#include "calib/model/camera_model.h"
#include "common/core/rigid.h"
#include "common/core/status.h"
#include "common/mesh/mesh.h"

namespace d3d {

struct TsdfOptions {
  double voxel_mm = 0.05;          // voxel edge (≤ 0.05 mm for the arch)
  double truncation_mm = 0.2;      // band half-width
  float max_weight = 1e6f;         // cap of the accumulated weight (moving average beyond)
  float min_point_weight = 0.05f;  // points of lower quality are not fused
  double max_incidence_deg = 80;   // points seen more grazing than this are not fused
  int pixel_stride = 1;           // leaf allocation samples every k-th pixel (integration uses all)
  float min_mesh_weight = 0.5f;   // see ExtractMesh
  float mesh_seed_weight = 2.0f;  // see ExtractMesh; <= min_mesh_weight: no hysteresis
  // A mesh vertex is dropped when the signed distances of the 8 voxels around it span more than
  // this many cell diagonals (√3·voxel_mm); a distance field spans at most one (see the file
  // comment). 0 = no test, else ≥ 1.
  double max_cell_sdf_span = 3.0;
  // Occlusion test (see the file comment): ray samples from margin to reach (mm) in front of each
  // point, every occlusion_stride-th pixel (its block shares the result). margin 0 = off.
  double occlusion_margin_mm = 0.6;
  double occlusion_reach_mm = 2.5;  // one fringe order is 1.4–1.9 mm of depth on the probe
  float occlusion_min_weight = 2.0f;
  int occlusion_stride = 2;
  // Secondary points (Integrate's `secondary` mask: edge-filled ones) enter the surface with their
  // weight times λ = max(0, 1 − W_p / secondary_fade_weight), W_p the voxel's weight from primary
  // points (file comment). 0 (default) = secondary points count like the rest; 2 is the value
  // measured.
  float secondary_fade_weight = 0.0f;
  void Check() const;  // throws std::invalid_argument
};

class TsdfVolume {
 public:
  explicit TsdfVolume(const TsdfOptions& options = {});
  ~TsdfVolume();
  TsdfVolume(const TsdfVolume&) = delete;
  TsdfVolume& operator=(const TsdfVolume&) = delete;

  const TsdfOptions& options() const { return o_; }

  // Fuses one organised view. points_in_cam, normals_in_cam: H×W CV_32FC3 (mm, NaN = none);
  // quality: H×W CV_32F in [0, 1] or empty (weight 1); camera: the intrinsics the view was
  // measured with (H×W = its size); world_from_cam: the view's registered pose; secondary: H×W
  // CV_8U, nonzero = a secondary point (less trusted: see secondary_fade_weight), or empty (none).
  // INVALID_ARGUMENT for mismatched sizes or types.
  [[nodiscard]] Status Integrate(const cv::Mat& points_in_cam, const cv::Mat& normals_in_cam,
                                 const cv::Mat& quality, const PinholeBrownConrady& camera,
                                 const Rigid3d& world_from_cam,
                                 const cv::Mat& secondary = cv::Mat());

  // Fuses an unorganised set of points with normals (world frame) by splatting each point's
  // tangent-plane distance into the voxels within truncation of it (used by tests and for clouds
  // without a camera): same averaging, weight per point.
  void IntegratePoints(const std::vector<Eigen::Vector3f>& points,
                       const std::vector<Eigen::Vector3f>& normals,
                       const std::vector<float>& weights);

  // The zero level as a mesh (world frame, mm, faces counter-clockwise seen from the front /
  // camera side), with polygons whose cell corners all have weight ≥ min_weight (< 0: the option)
  // in the connected pieces that reach options().mesh_seed_weight somewhere (see the file comment).
  TriangleMesh ExtractMesh(float min_weight = -1.0f) const;

  // Signed distance (mm) and weight of all fused points (primary and secondary alike) at a world
  // point (trilinear; weight 0 where unobserved).
  float SignedDistance(const Eigen::Vector3d& p_in_world) const;
  float Weight(const Eigen::Vector3d& p_in_world) const;

  int64_t ActiveVoxels() const;
  int64_t MemoryBytes() const;  // all grids, as OpenVDB counts them
  // Leaves (8³ voxels) of the secondary grids: where secondary points still shape the surface.
  int64_t SecondaryLeaves() const;
  int64_t views() const { return views_; }
  int64_t last_occluded_points() const { return last_occluded_; }  // of the last Integrate
  int64_t occluded_points() const { return occluded_; }            // over all views

 private:
  struct Impl;
  TsdfOptions o_;
  std::unique_ptr<Impl> impl_;
  int64_t views_ = 0;
  int64_t last_occluded_ = 0, occluded_ = 0;
  cv::Mat occluded_mask_;  // scratch of Integrate: CV_8U per pixel, 1 = occluded
  // Scratch of Integrate, per pixel (row-major, H×W): what a voxel projecting there adds. Owned by
  // Integrate's caller, written before and read by the TBB tasks it waits for; kept across calls
  // so that the hot path does not allocate.
  struct FusePixel {
    Eigen::Vector3f point;   // p_in_cam, mm
    Eigen::Vector3f normal;  // unit, toward the camera; NaN: none (the range difference is used)
    float range = 0;         // |p_in_cam|, mm
    float weight = 0;        // the point's quality; 0 = not fused
    bool secondary = false;  // from Integrate's secondary mask
  };
  std::vector<FusePixel> fuse_pixels_;

  // Integrate's steps, in order (tsdf.cpp).
  struct ViewLeaf;   // a leaf near the view's points, in each grid
  struct VoxelPass;  // the view as FuseLeaf needs it
  void TestOcclusion(const cv::Mat& points_in_cam, const Rigid3d& world_from_cam);
  void PreparePixels(const cv::Mat& points_in_cam, const cv::Mat& normals_in_cam,
                     const cv::Mat& quality, const cv::Mat& secondary, bool test_occlusion);
  std::vector<ViewLeaf> AllocateLeaves(const cv::Mat& points_in_cam, const Rigid3d& world_from_cam,
                                       bool test_occlusion);
  std::vector<uint8_t> FuseVoxels(const std::vector<ViewLeaf>& leaves,
                                  const PinholeBrownConrady& camera, const Rigid3d& world_from_cam,
                                  int cols, int rows);
  static bool FuseLeaf(const ViewLeaf& leaf, const VoxelPass& view);
  void FreeSecondaryLeaves(const std::vector<ViewLeaf>& leaves,
                           const std::vector<uint8_t>& secondary_left);
};

}  // namespace d3d
