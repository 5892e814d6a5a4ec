// The tracking model: registered views accumulated in the world frame as a voxel-hashed set of
// surface samples (running means of point and normal per voxel). Frame-to-model ICP associates
// new views with it, either through a k-d tree over the samples near the view or through an
// image of the samples rendered from the predicted pose (projective association).
// Not thread-safe; owned by the tracker's thread.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <opencv2/core.hpp>
#include <unordered_map>
#include <vector>

#include "common/core/rigid.h"
#include "pipeline/register/icp.h"
#include "pipeline/register/surface_points.h"

namespace d3d {

struct PointMapOptions {
  double voxel_mm = 0.08;        // one sample per voxel
  double block_mm = 2.0;         // spatial index cell for region queries
  float max_weight = 50.0f;      // running mean becomes a moving average beyond this count
  void Check() const;
};

class PointMap {
 public:
  explicit PointMap(const PointMapOptions& options = {});
  // Adds samples given in their own frame, moved by world_from_source. Normals required.
  void Insert(const SurfacePoints& samples_in_source, const Rigid3d& world_from_source);
  size_t size() const { return points_.size(); }
  bool empty() const { return points_.empty(); }
  // Samples whose block intersects the axis-aligned box [lo, hi] (world, mm).
  SurfacePoints Gather(const Eigen::Vector3f& lo, const Eigen::Vector3f& hi) const;
  // Renders the samples seen from world_from_cam into an organised image (z-buffer, each sample
  // splatted to a (2·splat+1)² footprint): points and normals in the WORLD frame, NaN where empty.
  // Returns the count of filled pixels.
  int Render(const Rigid3d& world_from_cam, const PinholeIntrinsics& k, int splat, cv::Mat* points_in_world,
             cv::Mat* normals_in_world) const;
  // Fraction of `samples` (moved by world_from_source) that fall in an occupied voxel or one of
  // its 26 neighbours: the overlap index of a view with the model.
  double Overlap(const SurfacePoints& samples_in_source, const Rigid3d& world_from_source) const;

 private:
  PointMapOptions o_;
  std::vector<Eigen::Vector3f> points_, normals_;
  std::vector<float> weights_;
  std::unordered_map<uint64_t, uint32_t> voxel_;                // voxel key → sample index
  std::unordered_map<uint64_t, std::vector<uint32_t>> blocks_;  // block key → sample indices
};

}  // namespace d3d
