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
  T.linear() = Eigen::AngleAxisd(angle, Eigen::Vector3d(0.2, 0.3, 1).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(x, 0.3 * x, 0.1);
  return T;
}

std::vector<std::array<float, 6>> Sorted(const SurfacePoints& s) {
  std::vector<std::array<float, 6>> v;
  for (size_t i = 0; i < s.size(); ++i)
    v.push_back({s.points[i].x(), s.points[i].y(), s.points[i].z(), s.normals[i].x(), s.normals[i].y(), s.normals[i].z()});
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

TEST(PointMapJournal, RollingBackInsertsGivesTheMapThatNeverHadThem) {
  PointMapOptions o;
  o.undo_inserts = 4;
  o.max_weight = 3;  // the moving-average branch too
  std::mt19937 rng(7);
  std::vector<std::pair<SurfacePoints, Rigid3d>> inserts;
  for (int i = 0; i < 7; ++i) inserts.emplace_back(Patch(&rng, Eigen::Vector3f(0.4f * i, 0, 0), 3000), Pose(0.02 * i, 0.3 * i));
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
    for (int i = 0; i < keep; ++i) plain.Insert(inserts[static_cast<size_t>(i)].first, inserts[static_cast<size_t>(i)].second);
    ExpectSameMap(journaled, plain);
  }
  EXPECT_FALSE(journaled.RollBackTo(2));  // the journal ended at insert 3
  // Inserting again after a roll back continues as a fresh map would.
  journaled.Insert(inserts[6].first, inserts[6].second);
  PointMap plain(PointMapOptions{o.voxel_mm, o.block_mm, o.max_weight, 0});
  for (int i : {0, 1, 2, 6}) plain.Insert(inserts[static_cast<size_t>(i)].first, inserts[static_cast<size_t>(i)].second);
  ExpectSameMap(journaled, plain);
  // Without a journal nothing can be rolled back.
  EXPECT_EQ(plain.oldest_undoable_insert(), plain.inserts());
  EXPECT_FALSE(plain.RollBackTo(plain.inserts() - 1));
  EXPECT_TRUE(plain.RollBackTo(plain.inserts()));
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
