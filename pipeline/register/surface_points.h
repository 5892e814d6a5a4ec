// Unorganised surface samples (points with unit normals, mm) and helpers to make them from an
// organised view or a raw cloud. Shared by ICP, features and the tracker.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <vector>

#include "common/core/rigid.h"

namespace d3d {

struct SurfacePoints {
  std::vector<Eigen::Vector3f> points;   // mm
  std::vector<Eigen::Vector3f> normals;  // unit; same size as points (or empty where a user needs none)
  std::vector<float> weights;            // optional per-point confidence in [0, 1] (empty = all 1)
  size_t size() const { return points.size(); }
  bool empty() const { return points.empty(); }
  void clear() { points.clear(); normals.clear(); weights.clear(); }
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
SurfacePoints SampleOrganised(const cv::Mat& points, const cv::Mat& normals, const cv::Mat& quality, int stride);

// Normals of an organised cloud from central differences on the grid, n = ∂P/∂col × ∂P/∂row
// (normalised), NaN where a neighbour is missing or farther than max_gap_mm. H×W CV_32FC3.
cv::Mat GridNormals(const cv::Mat& points, double max_gap_mm);

// Normals of an unorganised cloud by principal component analysis of the k nearest neighbours
// (Hoppe et al. 1992, "Surface reconstruction from unorganized points", §3.2), oriented toward
// `viewpoint` (mm, the cloud's frame). Points with a degenerate neighbourhood get a NaN normal.
std::vector<Eigen::Vector3f> EstimateNormals(const std::vector<Eigen::Vector3f>& points, int k,
                                             const Eigen::Vector3f& viewpoint);

}  // namespace d3d
