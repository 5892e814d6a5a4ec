#include "pipeline/register/point_map.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "common/core/status.h"

namespace d3d {

void PointMapOptions::Check() const {
  D3D_CHECK_MSG(voxel_mm > 0 && block_mm >= voxel_mm,
                "PointMapOptions: need 0 < voxel_mm <= block_mm");
  D3D_CHECK_MSG(max_weight >= 1, "PointMapOptions: max_weight must be >= 1");
  D3D_CHECK_MSG(undo_inserts >= 0, "PointMapOptions: undo_inserts must be >= 0");
}

PointMap::PointMap(const PointMapOptions& options) : o_(options) { o_.Check(); }

namespace {
// A sample (point p, normal n, weight w) and another seen in its voxel (q, m, weight wq): the
// running mean of both (a moving average beyond max_weight).
void Blend(const Eigen::Vector3f& q, const Eigen::Vector3f& m, float wq, float max_weight,
           Eigen::Vector3f* p, Eigen::Vector3f* n, float* w) {
  *p = (*p * *w + q * wq) / (*w + wq);
  *n = (*n * *w + m * wq).normalized();
  *w = std::min(*w + wq, max_weight);
}
}  // namespace

void PointMap::Insert(const SurfacePoints& s, const Rigid3d& world_from_source, int32_t tag,
                      const std::vector<int32_t>* sample_tags) {
  D3D_CHECK_MSG(s.normals.size() == s.points.size(), "PointMap::Insert needs normals");
  D3D_CHECK_MSG(sample_tags == nullptr || sample_tags->size() == s.size(),
                "PointMap::Insert: one tag per sample");
  const Eigen::Matrix3f R = world_from_source.linear().cast<float>();
  const Eigen::Vector3f t = world_from_source.translation().cast<float>();
  const float inv = static_cast<float>(1.0 / o_.voxel_mm),
              binv = static_cast<float>(1.0 / o_.block_mm);
  ++inserts_;
  Entry* entry = nullptr;
  if (o_.undo_inserts > 0) {
    if (static_cast<int>(journal_.size()) ==
        o_.undo_inserts) {  // the oldest can no longer be undone
      spare_.push_back(std::move(journal_.front()));
      journal_.pop_front();
    }
    if (!spare_.empty()) {
      journal_.push_back(std::move(spare_.back()));
      spare_.pop_back();
    } else {
      journal_.emplace_back();
    }
    entry = &journal_.back();
    entry->samples_before = points_.size();
    entry->updates.clear();
    entry->created.clear();
  }
  for (size_t i = 0; i < s.size(); ++i) {
    const Eigen::Vector3f p = R * s.points[i] + t;
    const Eigen::Vector3f n = R * s.normals[i];
    const uint64_t k = VoxelKeyOf(p, inv);
    auto [it, fresh] = voxel_.try_emplace(k, static_cast<uint32_t>(points_.size()));
    if (fresh) {
      points_.push_back(p);
      normals_.push_back(n);
      weights_.push_back(1.0f);
      tags_.push_back(sample_tags ? (*sample_tags)[i] : tag);
      const uint64_t b = VoxelKeyOf(p, binv);
      blocks_[b].push_back(it->second);
      if (entry) entry->created.push_back({k, b});
    } else {
      const uint32_t j = it->second;
      if (normals_[j].dot(n) < 0.5f) continue;  // the other side of a thin wall
      const float w = weights_[j];
      if (entry) entry->updates.push_back({j, w, points_[j], normals_[j]});
      Blend(p, n, 1.0f, o_.max_weight, &points_[j], &normals_[j], &weights_[j]);
    }
  }
}

bool PointMap::RollBackTo(int64_t insert) {
  if (insert < oldest_undoable_insert() || insert > inserts_) return false;
  while (inserts_ > insert) {
    Entry& e = journal_.back();
    // Updates newest first restore each sample's value from before this Insert (a sample this
    // Insert updated twice gets the older value last); then the samples it created, newest first:
    // each is the last index of its block's list.
    for (auto u = e.updates.rbegin(); u != e.updates.rend(); ++u) {
      points_[u->index] = u->point;
      normals_[u->index] = u->normal;
      weights_[u->index] = u->weight;
    }
    for (size_t c = e.created.size(); c-- > 0;) {
      voxel_.erase(e.created[c].voxel);
      const auto b = blocks_.find(e.created[c].block);
      b->second.pop_back();
      if (b->second.empty()) blocks_.erase(b);
    }
    points_.resize(e.samples_before);
    normals_.resize(e.samples_before);
    weights_.resize(e.samples_before);
    tags_.resize(e.samples_before);
    spare_.push_back(std::move(e));
    journal_.pop_back();
    --inserts_;
  }
  return true;
}

void PointMap::MoveByTag(const std::vector<Rigid3d>& new_from_old) {
  std::vector<Eigen::Matrix3f> R(new_from_old.size());
  std::vector<Eigen::Vector3f> t(new_from_old.size());
  for (size_t i = 0; i < new_from_old.size(); ++i) {
    R[i] = new_from_old[i].linear().cast<float>();
    t[i] = new_from_old[i].translation().cast<float>();
  }
  const float inv = static_cast<float>(1.0 / o_.voxel_mm),
              binv = static_cast<float>(1.0 / o_.block_mm);
  std::vector<Eigen::Vector3f> points, normals;
  std::vector<float> weights;
  std::vector<int32_t> tags;
  points.reserve(points_.size());
  normals.reserve(points_.size());
  weights.reserve(points_.size());
  tags.reserve(points_.size());
  voxel_.clear();
  voxel_.reserve(points_.size());
  blocks_.clear();
  for (size_t i = 0; i < points_.size(); ++i) {
    Eigen::Vector3f p = points_[i], n = normals_[i];
    const int32_t tag = tags_[i];
    if (tag >= 0 && static_cast<size_t>(tag) < R.size()) {
      const size_t k = static_cast<size_t>(tag);
      p = R[k] * p + t[k];
      n = R[k] * n;
    }
    auto [it, fresh] = voxel_.try_emplace(VoxelKeyOf(p, inv), static_cast<uint32_t>(points.size()));
    if (fresh) {
      points.push_back(p);
      normals.push_back(n);
      weights.push_back(weights_[i]);
      tags.push_back(tag);
      continue;
    }
    // Two samples in one voxel after the move: their weighted mean, as Insert makes; one facing
    // the other way (the other side of a thin wall) is dropped, as Insert drops it.
    const uint32_t j = it->second;
    if (normals[j].dot(n) < 0.5f) continue;
    Blend(p, n, weights_[i], o_.max_weight, &points[j], &normals[j], &weights[j]);
  }
  points_ = std::move(points);
  normals_ = std::move(normals);
  weights_ = std::move(weights);
  tags_ = std::move(tags);
  // The block lists in index order, as Insert makes them: (block, index) sorted, then one list per
  // block sized at once (a push_back per sample into the block table took most of the time).
  std::vector<std::pair<uint64_t, uint32_t>> by_block(points_.size());
  for (size_t i = 0; i < points_.size(); ++i)
    by_block[i] = {VoxelKeyOf(points_[i], binv), static_cast<uint32_t>(i)};
  std::sort(by_block.begin(), by_block.end());
  for (size_t i = 0; i < by_block.size();) {
    size_t e = i;
    while (e < by_block.size() && by_block[e].first == by_block[i].first) ++e;
    std::vector<uint32_t>& list = blocks_[by_block[i].first];
    list.reserve(e - i);
    for (; i < e; ++i) list.push_back(by_block[i].second);
  }
  for (Entry& e : journal_) spare_.push_back(std::move(e));
  journal_.clear();
}

int64_t PointMap::journal_bytes() const {
  const auto of = [](const Entry& e) {
    return static_cast<int64_t>(e.updates.capacity() * sizeof(Update) +
                                e.created.capacity() * sizeof(Created));
  };
  int64_t bytes = 0;
  for (const Entry& e : journal_) bytes += of(e);
  for (const Entry& e : spare_) bytes += of(e);
  return bytes;
}

int64_t PointMap::memory_bytes() const {
  const auto chunk = [](size_t bytes) {
    return static_cast<int64_t>((bytes + 8 + 15) / 16 * 16);
  };  // + malloc's header
  int64_t bytes = static_cast<int64_t>(
      (points_.capacity() + normals_.capacity()) * sizeof(Eigen::Vector3f) +
      weights_.capacity() * sizeof(float) + tags_.capacity() * sizeof(int32_t));
  // The voxel table: one slot (key, index) and one control byte per slot of its capacity.
  bytes +=
      static_cast<int64_t>(voxel_.capacity() * (sizeof(std::pair<const uint64_t, uint32_t>) + 1));
  // A node of the block table: the next pointer and the value (std::hash<uint64_t> is not cached).
  bytes += static_cast<int64_t>(blocks_.bucket_count() * sizeof(void*)) +
           static_cast<int64_t>(blocks_.size()) *
               chunk(sizeof(void*) + sizeof(std::pair<const uint64_t, std::vector<uint32_t>>));
  for (const auto& [key, list] : blocks_) bytes += chunk(list.capacity() * sizeof(uint32_t));
  return bytes;
}

SurfacePoints PointMap::Gather(const Eigen::Vector3f& lo, const Eigen::Vector3f& hi) const {
  SurfacePoints out;
  Gather(lo, hi, &out);
  return out;
}

void PointMap::Gather(const Eigen::Vector3f& lo, const Eigen::Vector3f& hi,
                      SurfacePoints* out) const {
  out->clear();
  const double binv = 1.0 / o_.block_mm;
  const int64_t x0 = static_cast<int64_t>(std::floor(lo.x() * binv)),
                x1 = static_cast<int64_t>(std::floor(hi.x() * binv));
  const int64_t y0 = static_cast<int64_t>(std::floor(lo.y() * binv)),
                y1 = static_cast<int64_t>(std::floor(hi.y() * binv));
  const int64_t z0 = static_cast<int64_t>(std::floor(lo.z() * binv)),
                z1 = static_cast<int64_t>(std::floor(hi.z() * binv));
  if ((x1 - x0 + 1) * (y1 - y0 + 1) * (z1 - z0 + 1) > static_cast<int64_t>(blocks_.size())) {
    // A box of more blocks than the map has: the map's blocks, each sample tested. Blocks more than
    // one block outside the box's range hold none of its samples (one block of slack covers the
    // float rounding of a sample's block against the box's), so their samples are not read:
    // the same samples in the same order, without reading the whole map (a view's box took this
    // path while the map was small and, for the model anchoring's boxes, which reach along the
    // rays by whole fringe orders, often after: there it read every sample of the map).
    for (const auto& [k, v] : blocks_) {
      int64_t bx, by, bz;
      VoxelOfKey(k, &bx, &by, &bz);
      if (bx < x0 - 1 || bx > x1 + 1 || by < y0 - 1 || by > y1 + 1 || bz < z0 - 1 || bz > z1 + 1)
        continue;
      for (uint32_t i : v) {
        const Eigen::Vector3f& p = points_[i];
        if ((p.array() >= lo.array()).all() && (p.array() <= hi.array()).all()) {
          out->points.push_back(p);
          out->normals.push_back(normals_[i]);
        }
      }
    }
    return;
  }
  for (int64_t x = x0; x <= x1; ++x)
    for (int64_t y = y0; y <= y1; ++y)
      for (int64_t z = z0; z <= z1; ++z) {
        const auto it = blocks_.find(VoxelKey(x, y, z));
        if (it == blocks_.end()) continue;
        for (uint32_t i : it->second) {
          out->points.push_back(points_[i]);
          out->normals.push_back(normals_[i]);
        }
      }
}

int PointMap::Render(const Rigid3d& world_from_cam, const PinholeIntrinsics& k, int splat,
                     cv::Mat* P, cv::Mat* N) const {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  P->create(k.height, k.width, CV_32FC3);
  N->create(k.height, k.width, CV_32FC3);
  P->setTo(cv::Scalar::all(nan));
  N->setTo(cv::Scalar::all(nan));
  cv::Mat zbuf(k.height, k.width, CV_32F, cv::Scalar(std::numeric_limits<float>::infinity()));
  const Rigid3d cam_from_world = world_from_cam.inverse();
  const Eigen::Matrix3f R = cam_from_world.linear().cast<float>();
  const Eigen::Vector3f t = cam_from_world.translation().cast<float>();
  // Only blocks inside the camera's view volume: gather by the frustum's bounding box.
  const double zmax = 80.0;
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max()), hi = -lo;
  for (int cx : {0, k.width - 1})
    for (int cy : {0, k.height - 1})
      for (double z : {1.0, zmax}) {
        const Eigen::Vector3d c((cx - k.cx) / k.fx * z, (cy - k.cy) / k.fy * z, z);
        const Eigen::Vector3f w = (world_from_cam * c).cast<float>();
        lo = lo.cwiseMin(w);
        hi = hi.cwiseMax(w);
      }
  const Eigen::Vector3f o = world_from_cam.translation().cast<float>();
  lo = lo.cwiseMin(o);
  hi = hi.cwiseMax(o);
  const SurfacePoints s = Gather(lo, hi);
  int filled = 0;
  for (size_t i = 0; i < s.size(); ++i) {
    const Eigen::Vector3f c = R * s.points[i] + t;
    if (c.z() <= 0) continue;
    if ((R * s.normals[i]).dot(c) > 0) continue;  // back-facing
    const int u = static_cast<int>(std::lround(k.fx * c.x() / c.z() + k.cx));
    const int v = static_cast<int>(std::lround(k.fy * c.y() / c.z() + k.cy));
    for (int y = std::max(0, v - splat); y <= std::min(k.height - 1, v + splat); ++y)
      for (int x = std::max(0, u - splat); x <= std::min(k.width - 1, u + splat); ++x) {
        float& zb = zbuf.at<float>(y, x);
        if (c.z() >= zb) continue;
        if (!std::isfinite(zb)) ++filled;
        zb = c.z();
        P->at<cv::Vec3f>(y, x) = cv::Vec3f(s.points[i].x(), s.points[i].y(), s.points[i].z());
        N->at<cv::Vec3f>(y, x) = cv::Vec3f(s.normals[i].x(), s.normals[i].y(), s.normals[i].z());
      }
  }
  return filled;
}

double PointMap::Overlap(const SurfacePoints& s, const Rigid3d& world_from_source) const {
  if (s.empty()) return 0;
  const Eigen::Matrix3f R = world_from_source.linear().cast<float>();
  const Eigen::Vector3f t = world_from_source.translation().cast<float>();
  const float inv = static_cast<float>(1.0 / o_.voxel_mm);
  int hit = 0;
  for (const auto& q : s.points) {
    const Eigen::Vector3f p = R * q + t;
    const int64_t x = static_cast<int64_t>(std::floor(p.x() * inv)),
                  y = static_cast<int64_t>(std::floor(p.y() * inv)),
                  z = static_cast<int64_t>(std::floor(p.z() * inv));
    // The sample's own voxel first: most samples of an overlapping view hit there, one lookup
    // instead of the 14 the plain −1…1 order took to reach it (the same answer either way).
    bool any = voxel_.count(VoxelKey(x, y, z)) > 0;
    for (int dx = -1; dx <= 1 && !any; ++dx)
      for (int dy = -1; dy <= 1 && !any; ++dy)
        for (int dz = -1; dz <= 1 && !any; ++dz)
          any = (dx | dy | dz) != 0 && voxel_.count(VoxelKey(x + dx, y + dy, z + dz)) > 0;
    hit += any;
  }
  return static_cast<double>(hit) / static_cast<double>(s.size());
}

}  // namespace d3d
