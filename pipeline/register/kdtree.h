// A nanoflann k-d tree over a vector of 3-D float points (mm). The points must outlive the tree.
#pragma once

#include <Eigen/Core>
#include <limits>
#include <memory>
#include <vector>

namespace d3d {

class PointKdTree {
 public:
  explicit PointKdTree(const std::vector<Eigen::Vector3f>* points, int leaf_size = 16);
  ~PointKdTree();
  PointKdTree(const PointKdTree&) = delete;
  PointKdTree& operator=(const PointKdTree&) = delete;
  // Index of the nearest point and its squared distance (mm²); -1 for an empty tree or when no
  // point is closer than √max_dist2 (a bound prunes the search: ICP's association gate).
  int Nearest(const Eigen::Vector3f& q, float* dist2,
              float max_dist2 = std::numeric_limits<float>::max()) const;
  // Up to k nearest (sorted by distance); returns the count found.
  int Knn(const Eigen::Vector3f& q, int k, int* indices, float* dist2) const;
  // Indices within radius (mm), unsorted.
  void Radius(const Eigen::Vector3f& q, float radius_mm, std::vector<int>* indices) const;
  size_t size() const { return points_->size(); }

 private:
  struct Impl;
  const std::vector<Eigen::Vector3f>* points_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace d3d
