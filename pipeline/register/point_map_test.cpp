#include "pipeline/register/point_map.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>

namespace d3d {
namespace {

// A random patch of samples around `centre` (a bumpy plane, normals roughly +z).
SurfacePoints Patch(std::mt19937* rng, const Eigen::Vector3f& centre, int n) {
  std::uniform_real_distribution<float> u(-1.5f, 1.5f), tilt(-0.2f, 0.2f);
  SurfacePoints s;
  for (int i = 0; i < n; ++i) {
    const float x = u(*rng), y = u(*rng);
    s.points.push_back(centre + Eigen::Vector3f(x, y, 0.05f * std::sin(3 * x) * std::cos(2 * y)));
    s.normals.push_back(Eigen::Vector3f(tilt(*rng), tilt(*rng), 1).normalized());
  }
  return s;
}

Rigid3d Pose(double angle, double x) {
  Rigid3d T = Rigid3d::Identity();
  T.linear() =
      Eigen::AngleAxisd(angle, Eigen::Vector3d(0.2, 0.3, 1).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(x, 0.3 * x, 0.1);
  return T;
}

std::vector<std::array<float, 6>> Sorted(const SurfacePoints& s) {
  std::vector<std::array<float, 6>> v;
  for (size_t i = 0; i < s.size(); ++i)
    v.push_back({s.points[i].x(), s.points[i].y(), s.points[i].z(), s.normals[i].x(),
                 s.normals[i].y(), s.normals[i].z()});
  std::sort(v.begin(), v.end());
  return v;
}

void ExpectSameMap(const PointMap& a, const PointMap& b) {
  ASSERT_EQ(a.size(), b.size());
  EXPECT_TRUE(a.points() == b.points());
  EXPECT_TRUE(a.normals() == b.normals());
  EXPECT_TRUE(a.weights() == b.weights());
  // The hash tables: the same blocks (region queries) and voxels (overlap).
  const Eigen::Vector3f lo(-3, -3, -3), hi(6, 6, 3);
  EXPECT_EQ(Sorted(a.Gather(lo, hi)), Sorted(b.Gather(lo, hi)));
  std::mt19937 rng(99);
  const SurfacePoints probe = Patch(&rng, Eigen::Vector3f(1, 0.5f, 0), 4000);
  EXPECT_EQ(a.Overlap(probe, Pose(0.05, 0.3)), b.Overlap(probe, Pose(0.05, 0.3)));
}

// Gather returns every sample of the blocks the box touches, or (a box of more blocks than the map
// has) exactly the samples inside the box; it never misses one inside. Checked against a scan of
// all samples, for boxes from one block to the whole map, at and off the block grid.
TEST(PointMap, GatherFindsEverySampleInTheBox) {
  PointMapOptions o;
  o.voxel_mm = 0.1;
  o.block_mm = 1.0;
  PointMap map(o);
  std::mt19937 rng(3);
  for (int i = 0; i < 40; ++i)  // patches spread over ~60 × 20 mm: many blocks
    map.Insert(
        Patch(&rng, Eigen::Vector3f(1.5f * i - 30, 8.0f * std::sin(0.3f * i), 0.5f * (i % 5)), 600),
        Rigid3d::Identity());
  const auto inside = [&](const Eigen::Vector3f& lo, const Eigen::Vector3f& hi) {
    SurfacePoints s;
    for (size_t i = 0; i < map.size(); ++i)
      if ((map.points()[i].array() >= lo.array()).all() &&
          (map.points()[i].array() <= hi.array()).all()) {
        s.points.push_back(map.points()[i]);
        s.normals.push_back(map.normals()[i]);
      }
    return s;
  };
  // Small boxes (≤ 5³ blocks, far fewer than the map's ~500-1300) take the block path; large ones
  // (≥ 30 × 20 × 8 blocks) the path that tests each sample.
  std::uniform_real_distribution<float> at(-35, 35), small_size(0.3f, 4.0f), unit(0, 1);
  SurfacePoints
      reused;  // one buffer for every box, as the tracker passes it: the last box's samples must go
  for (int q = 0; q < 200; ++q) {
    const bool large = q % 2 == 1;
    const Eigen::Vector3f lo(at(rng), 0.4f * at(rng), large ? -6 + 4 * unit(rng) : 0.1f * at(rng));
    const Eigen::Vector3f extent =
        large ? Eigen::Vector3f(30 + 40 * unit(rng), 20 + 20 * unit(rng), 8 + 4 * unit(rng))
              : Eigen::Vector3f(small_size(rng), small_size(rng), small_size(rng));
    const Eigen::Vector3f hi = lo + extent;
    const SurfacePoints got = map.Gather(lo, hi), want = inside(lo, hi);
    map.Gather(lo, hi, &reused);
    EXPECT_EQ(reused.points, got.points) << "box " << q;
    EXPECT_EQ(reused.normals, got.normals) << "box " << q;
    const auto g = Sorted(got), w = Sorted(want);
    EXPECT_TRUE(std::includes(g.begin(), g.end(), w.begin(), w.end()))
        << "box " << q;  // everything inside is found
    if (large) {
      EXPECT_EQ(g, w) << "box " << q;  // exactly the samples inside
    } else {
      for (const auto& p : got.points)  // the samples of the touched blocks: none beyond them
        EXPECT_TRUE((p.array() >= lo.array() - 1.0f).all() &&
                    (p.array() <= hi.array() + 1.0f).all())
            << "box " << q;
    }
  }
  EXPECT_EQ(map.Gather(Eigen::Vector3f::Constant(-1e3f), Eigen::Vector3f::Constant(1e3f)).size(),
            map.size());
}

// Overlap = the share of samples with an occupied voxel among their own and its 26 neighbours:
// checked against that definition computed from the map's samples, for probes that overlap the map
// fully, partly (shifted by 0.5 to 1.5 voxels: hits through neighbours only) and not at all.
TEST(PointMap, OverlapCountsSamplesNextToAnOccupiedVoxel) {
  PointMapOptions o;
  o.voxel_mm = 0.1;
  PointMap map(o);
  std::mt19937 rng(5);
  const SurfacePoints inserted = Patch(&rng, Eigen::Vector3f(0, 0, 0), 3000);
  map.Insert(inserted, Rigid3d::Identity());
  const float inv = static_cast<float>(1.0 / o.voxel_mm);  // as the map computes a voxel
  const auto voxel_of = [&](const Eigen::Vector3f& p) {
    return Eigen::Vector3i(static_cast<int>(std::floor(p.x() * inv)),
                           static_cast<int>(std::floor(p.y() * inv)),
                           static_cast<int>(std::floor(p.z() * inv)));
  };
  std::vector<Eigen::Vector3i> occupied;  // the voxels the inserted samples fell in
  for (const Eigen::Vector3f& p : inserted.points) occupied.push_back(voxel_of(p));
  const auto reference = [&](const SurfacePoints& probe, const Rigid3d& T) {
    const Eigen::Matrix3f R = T.linear().cast<float>();
    const Eigen::Vector3f t = T.translation().cast<float>();
    int hit = 0;
    for (const Eigen::Vector3f& q : probe.points) {
      const Eigen::Vector3f p = R * q + t;
      const Eigen::Vector3i v = voxel_of(p);
      hit += std::any_of(occupied.begin(), occupied.end(), [&](const Eigen::Vector3i& o) {
        return (o - v).cwiseAbs().maxCoeff() <= 1;
      });
    }
    return static_cast<double>(hit) / static_cast<double>(probe.size());
  };
  const SurfacePoints probe = Patch(&rng, Eigen::Vector3f(0, 0, 0), 2000);
  const std::vector<std::pair<Rigid3d, const char*>> cases = {
      {Rigid3d::Identity(), "same place"},
      {Rigid3d(Eigen::Translation3d(0, 0, 0.15)), "1.5 voxels up: neighbours only"},
      {Rigid3d(Eigen::Translation3d(0, 0, 0.25)), "2.5 voxels up: hardly any"},
      {Pose(0.05, 1.2), "turned and shifted: partly"},
      {Rigid3d(Eigen::Translation3d(10, 0, 0)), "far away"}};
  for (const auto& [T, what] : cases) {
    const double want = reference(probe, T);
    EXPECT_DOUBLE_EQ(map.Overlap(probe, T), want) << what;
  }
  EXPECT_GT(map.Overlap(probe, cases[1].first), 0.5);  // hits through the neighbours count
  EXPECT_LT(map.Overlap(probe, cases[3].first), 0.9);
  EXPECT_EQ(map.Overlap(probe, cases[4].first), 0.0);
}

TEST(SurfacePoints, VoxelOfKeyInvertsVoxelKey) {
  for (const int64_t x :
       {-(int64_t{1} << 20), int64_t{-7}, int64_t{0}, int64_t{5}, (int64_t{1} << 20) - 1})
    for (const int64_t y : {int64_t{-3}, int64_t{0}, (int64_t{1} << 20) - 1})
      for (const int64_t z : {-(int64_t{1} << 20), int64_t{0}, int64_t{11}}) {
        int64_t a, b, c;
        VoxelOfKey(VoxelKey(x, y, z), &a, &b, &c);
        EXPECT_EQ(a, x);
        EXPECT_EQ(b, y);
        EXPECT_EQ(c, z);
      }
}

TEST(PointMapJournal, RollingBackInsertsGivesTheMapThatNeverHadThem) {
  PointMapOptions o;
  o.undo_inserts = 4;
  o.max_weight = 3;  // the moving-average branch too
  std::mt19937 rng(7);
  std::vector<std::pair<SurfacePoints, Rigid3d>> inserts;
  for (int i = 0; i < 7; ++i)
    inserts.emplace_back(Patch(&rng, Eigen::Vector3f(0.4f * i, 0, 0), 3000),
                         Pose(0.02 * i, 0.3 * i));
  PointMap journaled(o);
  for (const auto& [s, T] : inserts) journaled.Insert(s, T);
  EXPECT_EQ(journaled.inserts(), 7);
  EXPECT_EQ(journaled.oldest_undoable_insert(), 3);
  EXPECT_GT(journaled.journal_bytes(), 0);
  // Beyond the journal, or ahead of the map: refused, nothing changed.
  const size_t n = journaled.size();
  EXPECT_FALSE(journaled.RollBackTo(2));
  EXPECT_FALSE(journaled.RollBackTo(8));
  EXPECT_EQ(journaled.size(), n);
  // Back to 5 inserts, then to 3, each against a map built from that many.
  for (const int keep : {5, 3}) {
    ASSERT_TRUE(journaled.RollBackTo(keep));
    EXPECT_EQ(journaled.inserts(), keep);
    PointMap plain(PointMapOptions{o.voxel_mm, o.block_mm, o.max_weight, 0});
    for (int i = 0; i < keep; ++i)
      plain.Insert(inserts[static_cast<size_t>(i)].first, inserts[static_cast<size_t>(i)].second);
    ExpectSameMap(journaled, plain);
  }
  EXPECT_FALSE(journaled.RollBackTo(2));  // the journal ended at insert 3
  // Inserting again after a roll back continues as a fresh map would.
  journaled.Insert(inserts[6].first, inserts[6].second);
  PointMap plain(PointMapOptions{o.voxel_mm, o.block_mm, o.max_weight, 0});
  for (int i : {0, 1, 2, 6})
    plain.Insert(inserts[static_cast<size_t>(i)].first, inserts[static_cast<size_t>(i)].second);
  ExpectSameMap(journaled, plain);
  // Without a journal nothing can be rolled back.
  EXPECT_EQ(plain.oldest_undoable_insert(), plain.inserts());
  EXPECT_FALSE(plain.RollBackTo(plain.inserts() - 1));
  EXPECT_TRUE(plain.RollBackTo(plain.inserts()));
}

// A loop correction moves each sample with the keyframe it was tagged with: the samples of tag 1
// move by their transform and land where that view now lies, those of tag 0 stay bit for bit,
// samples moved onto one voxel merge with their weights, and nothing before can be undone.
TEST(PointMap, MoveByTagMovesEachSampleWithItsKeyframe) {
  PointMapOptions o;
  o.undo_inserts = 4;
  std::mt19937 rng(11);
  const SurfacePoints a = Patch(&rng, Eigen::Vector3f(0, 0, 0), 3000);
  const SurfacePoints b = Patch(&rng, Eigen::Vector3f(5, 0, 0), 3000);
  PointMap map(o);
  map.Insert(a, Pose(0.01, 0), 0);
  map.Insert(b, Pose(0.01, 0), 1);
  ASSERT_EQ(map.tags().size(), map.size());
  const std::vector<Eigen::Vector3f> old_points = map.points();
  const std::vector<int32_t> old_tags = map.tags();
  size_t zeros = 0;
  while (zeros < old_tags.size() && old_tags[zeros] == 0) ++zeros;
  Rigid3d moved = Rigid3d::Identity();  // tag 1's new_from_old: off the patch's plane
  moved.linear() =
      Eigen::AngleAxisd(0.01, Eigen::Vector3d(1, 0.5, 0).normalized()).toRotationMatrix();
  moved.translation() = Eigen::Vector3d(0.2, 0, 0.5);
  map.MoveByTag({Rigid3d::Identity(), moved});
  ASSERT_EQ(map.tags().size(), map.size());
  // Tag 0's samples come first and stay as they were.
  for (size_t i = 0; i < zeros; ++i) {
    ASSERT_EQ(map.tags()[i], 0);
    ASSERT_EQ(map.points()[i], old_points[i]);
  }
  // Tag 1's samples lie at their old places moved (a few merged where two fell in one voxel).
  size_t ones = 0;
  for (size_t i = zeros; i < map.size(); ++i) ones += map.tags()[i] == 1;
  EXPECT_LE(ones, old_points.size() - zeros);
  EXPECT_GT(ones, (old_points.size() - zeros) * 3 / 4);
  EXPECT_GT(map.Overlap(b, moved * Pose(0.01, 0)), 0.99);
  EXPECT_LT(map.Overlap(b, Pose(0.01, 0)), 0.05);
  const Eigen::Vector3f lo(-10, -10, -10), hi(10, 10, 10);
  EXPECT_EQ(map.Gather(lo, hi).size(), map.size());  // the block table was rebuilt
  // The journal is gone: nothing before the move can be undone.
  EXPECT_EQ(map.oldest_undoable_insert(), map.inserts());
  EXPECT_FALSE(map.RollBackTo(map.inserts() - 1));

  // The same surface seen twice, 0.3 mm apart along its normal (drift): moved back onto the
  // first, they merge.
  PointMap twice(o);
  Rigid3d off = Rigid3d::Identity();
  off.translation() = Eigen::Vector3d(0, 0, 0.3);
  twice.Insert(a, Rigid3d::Identity(), 0);
  const size_t single = twice.size();
  twice.Insert(a, off, 1);
  ASSERT_GT(twice.size(), single * 3 / 2);  // a second layer
  twice.MoveByTag({Rigid3d::Identity(), off.inverse()});
  EXPECT_LT(twice.size(), single + single / 50);
  double weight = 0;  // every sample seen counts once: the two Inserts' samples
  for (const float w : twice.weights()) weight += w;
  EXPECT_NEAR(weight, 2.0 * static_cast<double>(a.size()), 1e-3 * static_cast<double>(a.size()));
}

// Tags follow their samples: given per sample, rolled back with them.
TEST(PointMap, TagsFollowTheirSamples) {
  PointMapOptions o;
  o.undo_inserts = 2;
  std::mt19937 rng(12);
  const SurfacePoints a = Patch(&rng, Eigen::Vector3f(0, 0, 0), 500);
  std::vector<int32_t> per_sample(a.size());
  for (size_t i = 0; i < per_sample.size(); ++i) per_sample[i] = static_cast<int32_t>(i % 3);
  PointMap map(o);
  map.Insert(a, Rigid3d::Identity(), -1, &per_sample);
  for (size_t i = 0; i < map.size(); ++i) EXPECT_GE(map.tags()[i], 0);
  const size_t n = map.size();
  map.Insert(Patch(&rng, Eigen::Vector3f(4, 0, 0), 500), Rigid3d::Identity(), 7);
  EXPECT_EQ(map.tags().back(), 7);
  ASSERT_TRUE(map.RollBackTo(1));
  EXPECT_EQ(map.tags().size(), n);
  const std::vector<int32_t> too_few(3, 0);
  EXPECT_THROW(map.Insert(a, Rigid3d::Identity(), -1, &too_few), std::invalid_argument);
}

// memory_bytes counts at least the samples' arrays and one hash slot per sample, grows with new
// surface and stays put when the same surface is inserted again (a probe dwelling over a tooth).
TEST(PointMap, MemoryGrowsWithNewSurfaceOnly) {
  PointMap map;
  EXPECT_LT(map.memory_bytes(), 4096);
  std::mt19937 rng(5);
  const SurfacePoints s = Patch(&rng, Eigen::Vector3f::Zero(), 20000);
  map.Insert(s, Pose(0, 0));
  const int64_t one = map.memory_bytes();
  EXPECT_GE(one,
            static_cast<int64_t>(map.size() * (2 * sizeof(Eigen::Vector3f) + sizeof(float) + 16)));
  EXPECT_LT(one, static_cast<int64_t>(map.size() * 200));
  for (int i = 0; i < 5; ++i) map.Insert(s, Pose(0, 0));  // the same surface again: no new sample
  EXPECT_EQ(map.memory_bytes(), one);
  map.Insert(s, Pose(0, 5.0));  // new surface beside it
  EXPECT_GT(map.memory_bytes(), one + static_cast<int64_t>(0.5 * one));
}

TEST(PointMapJournal, TheJournalKeepsOnlyTheNewestInserts) {
  PointMapOptions o;
  o.undo_inserts = 2;
  PointMap map(o);
  std::mt19937 rng(3);
  const SurfacePoints s = Patch(&rng, Eigen::Vector3f::Zero(), 2000);
  for (int i = 0; i < 10; ++i) map.Insert(s, Pose(0.01 * i, 0.2 * i));
  EXPECT_EQ(map.oldest_undoable_insert(), 8);
  const int64_t bytes = map.journal_bytes();
  for (int i = 10; i < 20; ++i) map.Insert(s, Pose(0.01 * i, 0.2 * i));
  EXPECT_LE(map.journal_bytes(), bytes * 2);  // bounded: the entries' buffers are reused
  EXPECT_THROW(PointMap(PointMapOptions{0.08, 2.0, 50, -1}), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
