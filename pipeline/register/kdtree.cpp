#include "pipeline/register/kdtree.h"

#include <nanoflann.hpp>

namespace d3d {

// The adaptor and tree are Impl's own types (not in an anonymous namespace: a unity build
// includes this file into another, where GCC warns of a member of internal linkage).
struct PointKdTree::Impl {
  struct Adaptor {
    const std::vector<Eigen::Vector3f>* pts;
    size_t kdtree_get_point_count() const { return pts->size(); }
    float kdtree_get_pt(size_t i, size_t d) const {
      return (*pts)[i][static_cast<Eigen::Index>(d)];
    }
    template <class BBOX>
    bool kdtree_get_bbox(BBOX&) const {
      return false;
    }
  };
  using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, Adaptor>,
                                                   Adaptor, 3, uint32_t>;
  Adaptor adaptor;
  Tree tree;
  Impl(const std::vector<Eigen::Vector3f>* p, int leaf)
      : adaptor{p},
        tree(3, adaptor, nanoflann::KDTreeSingleIndexAdaptorParams(static_cast<size_t>(leaf))) {
    tree.buildIndex();
  }
};

PointKdTree::PointKdTree(const std::vector<Eigen::Vector3f>* points, int leaf_size)
    : points_(points), impl_(std::make_unique<Impl>(points, leaf_size)) {}
PointKdTree::~PointKdTree() = default;

int PointKdTree::Nearest(const Eigen::Vector3f& q, float* dist2, float max_dist2) const {
  if (points_->empty()) return -1;
  uint32_t idx = 0;
  float d2 = 0;
  nanoflann::KNNResultSet<float, uint32_t> rs(1);
  rs.init(&idx, &d2);
  d2 = max_dist2;  // the result set's worst distance: only closer points are visited and taken
  impl_->tree.findNeighbors(rs, q.data(), nanoflann::SearchParams(32, 0.0f, false));
  if (rs.size() == 0) return -1;
  if (dist2) *dist2 = d2;
  return static_cast<int>(idx);
}

int PointKdTree::Knn(const Eigen::Vector3f& q, int k, int* indices, float* dist2) const {
  if (points_->empty() || k <= 0) return 0;
  std::vector<uint32_t> idx(static_cast<size_t>(k));
  nanoflann::KNNResultSet<float, uint32_t> rs(static_cast<uint32_t>(k));
  rs.init(idx.data(), dist2);
  impl_->tree.findNeighbors(rs, q.data(), nanoflann::SearchParams(32, 0.0f, true));
  const int n = static_cast<int>(rs.size());
  for (int i = 0; i < n; ++i) indices[i] = static_cast<int>(idx[static_cast<size_t>(i)]);
  return n;
}

void PointKdTree::Radius(const Eigen::Vector3f& q, float radius_mm,
                         std::vector<int>* indices) const {
  indices->clear();
  if (points_->empty()) return;
  std::vector<std::pair<uint32_t, float>> m;
  nanoflann::SearchParams p(32, 0.0f, false);
  impl_->tree.radiusSearch(q.data(), radius_mm * radius_mm, m, p);
  indices->reserve(m.size());
  for (const auto& e : m) indices->push_back(static_cast<int>(e.first));
}

}  // namespace d3d
