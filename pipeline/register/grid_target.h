// Exact nearest-neighbour association for ICP on uniform grids, one per association gate: the
// frame-to-model tracker's alternative to a k-d tree (KdTreeTarget) that gives the same matches.
//
// Method: the voxel-hash neighbour search of KISS-ICP (Vizzo et al. 2023, RA-L, Sec. III-C) with a
// dense array in place of the hash, which the tracker's small gathered targets (~20–40k samples
// in a ~20 mm box) afford, and two levels of cells. Per distinct gate r (IcpOptions' levels, e.g.
// 1.0 / 0.3 / 0.15 mm, up to ~2 mm for a live host's widely spaced views) the samples are bucketed
// (counting sort) into cells of edge r, each split into sub³ sub-cells of about kSubCellMm (only
// gates of 1.2 mm and more are split, as a live host's first level): every
// sample within r of a query lies in the 3 × 3 × 3 cells around the query's cell (⌈r/c⌉ rings
// when a grid had to be coarsened; a gate within kShareGateRatio of the next larger one searches
// that one's grid). The query's own sub-cell is scanned first; its nearest sample
// bounds the search, and every plane, row, cell or sub-cell whose box lies farther than the best
// match so far is skipped: a query near the surface reads the samples of its own (sub-)cell and
// few others, one with nothing within r only the occupied (sub-)cells within r of it. It suits
// dense targets with gates of a few sample spacings (the tracker's model: 0.08 mm samples, gates
// 0.15–2 mm; d3d-bench-register: 1.4–1.5× faster ICP than the k-d tree, plus no tree to build);
// sparse targets with wide gates (the bunny scans: 5 mm) are 3–4× faster with the k-d tree.
//
// Same result as KdTreeTarget: the sample with the smallest squared distance strictly below r²
// (distances summed in float in nanoflann's order, so both pick the same sample but for exact
// ties), refused when its normal is not finite.
//
// Threads: Build() by one thread (the owner, e.g. the tracker's); Find() is const and may run on
// any number of threads at once between builds (RegisterIcp with threads > 1). The buffers are
// kept across builds: after the first few views a build allocates nothing.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "pipeline/register/icp.h"
#include "pipeline/register/surface_points.h"

namespace d3d {

class GridTarget final : public IcpTarget {
 public:
  // Grids hold at most this many slots (sub-cells) each, 4 bytes a slot: a target spread wider gets
  // fewer sub-cells, then coarser cells (more rings searched; still exact).
  static constexpr int64_t kMaxCells = int64_t{1} << 23;
  // Sub-cell edge (mm) aimed at. Measured with d3d-bench-register's tracker ICP cases (gates 0.8 /
  // 0.3 / 0.15 mm and 1.96 / 0.3 / 0.15 mm): 0.8 → 17.4 / 17.2 ms, one level (no sub-cells) 17.1 /
  // 21.6 ms, 0.4 → 16.8-22 / 20.6-26.7 ms, 0.15 → 38-39 / 51-53 ms (the k-d tree 25.8 / 23.5 ms):
  // small sub-cells cost more in skip tests than they save in distances.
  static constexpr float kSubCellMm = 0.8f;

  // A gate at most this many times smaller than the next larger gate gets no grid of its own: the
  // larger one's serves it (Find stays exact: it searches the cells within the query's gate,
  // whatever their edge). The tracker's 0.15 and 0.3 mm levels then share the 0.3 mm grid, one
  // Build pass fewer over ~100k model samples while dwelling over a tooth: register CPU 30.3 → 27.7
  // ms per burst (lossless replay of 900 bursts circling one molar; the same poses, byte for byte),
  // the 0.15 mm level's Finds reading the 0.3 mm cells costing less than its grid's build (2.7 ms).
  static constexpr double kShareGateRatio = 2.0;

  GridTarget() = default;
  // Voxels per cell edge of a decimated grid (see Build).
  static constexpr int kDecimateVoxels = 4;

  // (Re)builds over `target` (normals required, same size as points; samples with a non-finite
  // coordinate are left out) with one grid per distinct gate of `gates_mm` (each > 0), but for
  // gates that share the next one's (kShareGateRatio). Throws std::invalid_argument for missing
  // normals or a gate ≤ 0. decimate_min_gate_mm > 0: the grids of gates at least this large hold
  // one sample per voxel of a quarter of their cell (the first in `target`'s order with a finite
  // normal; voxel downsampling as KISS-ICP's map, Vizzo et al. 2023, Sec. III-B), so that Find
  // there is exact for the decimated samples only. For a coarse ICP level: its wide gate puts ~150
  // samples of a 0.08 mm model in each 1 mm cell, which Find reads; decimated, ~16.
  void Build(const SurfacePoints& target, const std::vector<double>& gates_mm,
             double decimate_min_gate_mm = 0);
  // Nearest sample strictly within max_distance_mm of `query`: see the file comment.
  bool Find(const Eigen::Vector3f& query, float max_distance_mm, Eigen::Vector3f* point,
            Eigen::Vector3f* normal) const override;
  // As Find, with the clearance RegisterIcp needs to reuse the answer while the query moves
  // (IcpTarget::FindCertified): every sample within reach = min(max_distance_mm + margin_mm, the
  // searched ring) is looked at, and cells are skipped beyond the nearest so far plus margin_mm
  // (Find skips beyond the nearest: a few more cells are read). The nearest sample (ties: the one
  // Find takes) is Find's answer when it lies within max_distance_mm.
  bool FindCertified(const Eigen::Vector3f& query, float max_distance_mm, float margin_mm,
                     CertifiedNearest* out) const override;
  size_t size() const { return size_; }
  size_t grids() const {
    return used_grids_;
  }  // grids the last Build made (gates shared: kShareGateRatio)
  // Samples held by the grid that serves max_distance_mm (fewer than size() when decimated).
  size_t samples(float max_distance_mm) const;

 private:
  struct Grid {
    float gate = 0;      // the gate this grid serves (mm)
    float cell = 0;      // cell edge (mm), ≥ gate unless the grid was capped
    int sub = 1;         // sub-cells per cell edge
    float sub_cell = 0;  // cell / sub
    Eigen::Vector3f origin = Eigen::Vector3f::Zero();
    int nx = 0, ny = 0, nz = 0;
    std::vector<uint32_t> start;  // nx·ny·nz·sub³ + 1: first sample of each slot in `points`
    std::vector<Eigen::Vector3f> points;   // the samples in cell order
    std::vector<Eigen::Vector3f> normals;  // ... and their normals, in the same order (a match's
                                           // normal then lies beside the samples just read: looked
                                           // up by the target's order it missed the cache, ~17 % of
                                           // Find's time)
  };
  void BuildGrid(Grid* g, const SurfacePoints& target, bool decimate);
  // One search (Find's, or FindCertified's with kCertify): the nearest sample's index in the grid
  // (found, −1 for none), its distance² (best), the next nearest distance² seen (second), the skip
  // bound² at the end (bound) and the reach (mm). Returns found >= 0.
  struct Hit {
    int64_t found = -1;
    float best = 0, second = 0, bound = 0, reach = 0;
  };
  template <bool kCertify>
  bool Search(const Eigen::Vector3f& query, float max_distance_mm, float margin_mm, Hit* hit) const;
  const Grid* GridFor(float max_distance_mm) const;

  Eigen::Vector3f lo_ = Eigen::Vector3f::Zero(),
                  hi_ = Eigen::Vector3f::Zero();  // finite samples' bounds
  size_t size_ = 0;                               // samples of the current build
  std::vector<Grid> grids_;                       // by increasing gate
  size_t used_grids_ = 0;              // grids_[0, used_grids_) belong to the current build
  std::vector<uint32_t> slot_of_;      // per sample, scratch of BuildGrid
  std::vector<uint64_t> voxel_taken_;  // per cell, its 4³ voxels taken (decimated grids), scratch
};

}  // namespace d3d
