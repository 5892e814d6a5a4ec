// The tracking model: registered views accumulated in the world frame as a voxel-hashed set of
// surface samples (running means of point and normal per voxel). Frame-to-model ICP associates
// new views with it, either through a k-d tree over the samples near the view or through an
// image of the samples rendered from the predicted pose (projective association).
// With an undo journal (PointMapOptions::undo_inserts > 0) the last Inserts can be rolled back
// exactly: what each one changed (the samples it created, the old mean, normal and weight of those
// it updated) is kept for the newest undo_inserts of them (the tracker's "undo last seconds").
// Not thread-safe; owned by the tracker's thread.
#pragma once

#include <absl/container/flat_hash_map.h>

#include <Eigen/Core>
#include <cstdint>
#include <deque>
#include <opencv2/core.hpp>
#include <unordered_map>
#include <vector>

#include "common/core/rigid.h"
#include "pipeline/register/icp.h"
#include "pipeline/register/surface_points.h"

namespace d3d {

struct PointMapOptions {
  double voxel_mm = 0.08;    // one sample per voxel
  double block_mm = 2.0;     // spatial index cell for region queries
  float max_weight = 50.0f;  // running mean becomes a moving average beyond this count
  // Inserts that RollBackTo can undo (the newest ones); 0 = no journal. Memory: ~32 bytes per
  // sample an Insert updates and 16 per sample it creates (a binned 320 × 240 view on the
  // tracker's map lattice: ~10-20k samples, ~0.3-0.6 MB per Insert).
  int undo_inserts = 0;
  void Check() const;  // throws std::invalid_argument
};

class PointMap {
 public:
  explicit PointMap(const PointMapOptions& options = {});
  // Adds samples given in their own frame, moved by world_from_source. Normals required. The
  // samples this Insert creates carry `tag` (the tracker's anchor keyframe: MoveByTag moves them
  // with it), or sample i sample_tags[i] when given (one per sample); samples it only updates keep
  // theirs.
  void Insert(const SurfacePoints& samples_in_source, const Rigid3d& world_from_source,
              int32_t tag = -1, const std::vector<int32_t>* sample_tags = nullptr);
  size_t size() const { return points_.size(); }
  bool empty() const { return points_.empty(); }
  // Samples whose block intersects the axis-aligned box [lo, hi] (world, mm), into *out (points and
  // normals; cleared first, weights left empty). *out keeps its capacity: a caller that passes the
  // same buffer every view allocates only while the boxes' contents grow past their high-water mark
  // (the tracker's and the model anchoring's gathers reach ~180k samples, 4 MB, for one view;
  // allocated afresh they were ~200 MB/s of malloc/free with page faults while dwelling on a
  // tooth).
  void Gather(const Eigen::Vector3f& lo, const Eigen::Vector3f& hi, SurfacePoints* out) const;
  SurfacePoints Gather(const Eigen::Vector3f& lo,
                       const Eigen::Vector3f& hi) const;  // the same, a new set
  // Renders the samples seen from world_from_cam into an organised image (z-buffer, each sample
  // splatted to a (2·splat+1)² footprint): points and normals in the WORLD frame, NaN where empty.
  // Returns the count of filled pixels.
  int Render(const Rigid3d& world_from_cam, const PinholeIntrinsics& k, int splat,
             cv::Mat* points_in_world, cv::Mat* normals_in_world) const;
  // Fraction of `samples` (moved by world_from_source) that fall in an occupied voxel or one of
  // its 26 neighbours: the overlap index of a view with the model.
  double Overlap(const SurfacePoints& samples_in_source, const Rigid3d& world_from_source) const;

  // The samples in insertion order (world, mm), their unit normals and running-mean weights.
  const std::vector<Eigen::Vector3f>& points() const { return points_; }
  const std::vector<Eigen::Vector3f>& normals() const { return normals_; }
  const std::vector<float>& weights() const { return weights_; }
  const std::vector<int32_t>& tags() const { return tags_; }  // the creating Insert's tag

  // Moves each sample by new_from_old[tag] (its tag's; a tag outside the list, or −1, stays) and
  // rebuilds the voxel and block tables: a loop closure moved the keyframes the samples were seen
  // from (Tracker, TrackerOptions::loop_correction). Samples that land in one voxel merge (means
  // weighted by their weights, weights summed up to max_weight, the first sample's tag). The undo
  // journal is emptied: no Insert before is undoable (inserts() goes on counting).
  void MoveByTag(const std::vector<Rigid3d>& new_from_old);

  // Undo journal. inserts(): Insert calls so far. oldest_undoable_insert(): the first Insert that
  // RollBackTo can still undo (inserts() when there is none: no journal, or none yet).
  int64_t inserts() const { return inserts_; }
  int64_t oldest_undoable_insert() const {
    return inserts_ - static_cast<int64_t>(journal_.size());
  }
  // Undoes Inserts insert, insert+1, …, inserts()−1 (newest first): the map is then what it was
  // before Insert number `insert` (the same samples in the same order with the same values; hash
  // tables hold the same keys). false (map untouched) when insert < oldest_undoable_insert() or
  // insert > inserts().
  bool RollBackTo(int64_t insert);
  // Bytes the journal holds (capacity of its buffers).
  int64_t journal_bytes() const;
  // Bytes the map holds without its journal, estimated: the samples' arrays (capacity), the voxel
  // table (slots and control bytes), the block table (buckets and nodes, libstdc++'s layout, nodes
  // rounded up to malloc's 16-byte chunks) and the blocks' index lists (capacity). O(blocks):
  // cheap enough once a second.
  int64_t memory_bytes() const;

 private:
  struct Update {  // an Insert changed sample `index` from these values
    uint32_t index;
    float weight;
    Eigen::Vector3f point, normal;
  };
  struct Created {  // an Insert created a sample under these keys
    uint64_t voxel, block;
  };
  struct Entry {  // one Insert
    size_t samples_before = 0;
    std::vector<Update> updates;
    std::vector<Created> created;  // in sample order (samples_before, samples_before + 1, …)
  };
  PointMapOptions o_;
  std::deque<Entry> journal_;  // the newest undo_inserts Inserts, oldest first
  std::vector<Entry> spare_;   // entries dropped from the journal, reused (their capacity)
  int64_t inserts_ = 0;
  std::vector<Eigen::Vector3f> points_, normals_;
  std::vector<float> weights_;
  std::vector<int32_t> tags_;
  // Voxel key → sample index: an open-addressing table (abseil's SwissTable), looked up for every
  // sample of every Insert and Overlap. std::unordered_map's node per key cost a cache miss more a
  // look-up: Insert + Overlap were ~15 % of the live register thread's CPU. Only looked up, never
  // iterated, so the results do not depend on its order.
  absl::flat_hash_map<uint64_t, uint32_t> voxel_;
  std::unordered_map<uint64_t, std::vector<uint32_t>> blocks_;  // block key → sample indices
};

}  // namespace d3d
