// Unorganised surface samples (points with unit normals, mm) and helpers to make them from an
// organised view or a raw cloud. Shared by ICP, features and the tracker.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "common/core/rigid.h"

namespace d3d {

struct SurfacePoints {
  std::vector<Eigen::Vector3f> points;  // mm
  std::vector<Eigen::Vector3f>
      normals;                 // unit; same size as points (or empty where a user needs none)
  std::vector<float> weights;  // optional per-point confidence in [0, 1] (empty = all 1)
  size_t size() const { return points.size(); }
  bool empty() const { return points.empty(); }
  void clear() {
    points.clear();
    normals.clear();
    weights.clear();
  }
  // Every `stride`-th sample (stride ≥ 1), offset `phase`.
  SurfacePoints Subsample(int stride, int phase = 0) const;
  // T applied to points and its rotation to normals.
  SurfacePoints Transformed(const Rigid3d& T) const;
  // Centroid and RMS radius about it (mm); zero for an empty set.
  Eigen::Vector3d Centroid() const;
  double RadiusMm() const;
};

// Samples of an organised view on a regular pixel lattice of step `stride` (px, ≥ 1): pixels with a
// finite point and a finite normal. points, normals: H×W CV_32FC3; quality: empty or H×W CV_32F
// (copied into weights, clamped to [0, 1]). Rows are visited in an interleaved order (stride·2
// apart, then the ones between) so that SurfacePoints::Subsample(k) stays spread over the image.
SurfacePoints SampleOrganised(const cv::Mat& points, const cv::Mat& normals, const cv::Mat& quality,
                              int stride);
// The same into *out (cleared first; its capacity kept, so a caller that reuses it allocates only
// while views grow past their high-water mark).
void SampleOrganised(const cv::Mat& points, const cv::Mat& normals, const cv::Mat& quality,
                     int stride, SurfacePoints* out);

// Normals of an organised cloud from central differences on the grid, n = ∂P/∂col × ∂P/∂row
// (normalised), NaN where a neighbour is missing or farther than max_gap_mm. H×W CV_32FC3.
cv::Mat GridNormals(const cv::Mat& points, double max_gap_mm);

// Normals of an unorganised cloud by principal component analysis of the k nearest neighbours
// (Hoppe et al. 1992, "Surface reconstruction from unorganized points", §3.2), oriented toward
// `viewpoint` (mm, the cloud's frame). Points with a degenerate neighbourhood get a NaN normal.
std::vector<Eigen::Vector3f> EstimateNormals(const std::vector<Eigen::Vector3f>& points, int k,
                                             const Eigen::Vector3f& viewpoint);

// The least-squares plane normal (unit, sign arbitrary) of points[indices[0..count)): the
// eigenvector of the smallest eigenvalue of their covariance (Hoppe et al. 1992, §3.2). False when
// fewer than 3 points or the neighbourhood is degenerate (second eigenvalue ≤ 1e-12 mm²: a line).
bool PcaPlaneNormal(const std::vector<Eigen::Vector3f>& points, const int* indices, size_t count,
                    Eigen::Vector3f* normal);

// Hash key of the integer voxel (x, y, z): 21 bits per axis (cells −2²⁰ … 2²⁰ − 1, i.e. ±1 M
// voxels) packed into 64 bits. Used by the tracking model's voxel hash and by voxel downsampling.
uint64_t VoxelKey(int64_t x, int64_t y, int64_t z);
// The voxel (x, y, z) of a VoxelKey (within its ±2²⁰ range): VoxelKey's inverse.
void VoxelOfKey(uint64_t key, int64_t* x, int64_t* y, int64_t* z);
// The key of the voxel of edge 1 / inv_voxel_mm (cells aligned to the origin) holding p (mm); the
// products p·inv are formed in the precision of Scalar (float or double).
template <typename Scalar>
uint64_t VoxelKeyOf(const Eigen::Vector3f& p, Scalar inv_voxel_mm) {
  return VoxelKey(static_cast<int64_t>(std::floor(p.x() * inv_voxel_mm)),
                  static_cast<int64_t>(std::floor(p.y() * inv_voxel_mm)),
                  static_cast<int64_t>(std::floor(p.z() * inv_voxel_mm)));
}

}  // namespace d3d
