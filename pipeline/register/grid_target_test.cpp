#include "pipeline/register/grid_target.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "pipeline/register/icp.h"
#include "pipeline/register/test_surfaces.h"

namespace d3d {
namespace {

using testing::HeightField;
using testing::LookDown;
using testing::RenderHeightField;
using testing::TestCamera;

// A view of the bumpy surface, samples every 2nd pixel, one with a NaN normal (a NaN point would
// spoil the k-d tree's splits, not the grid: see RebuildsAndRefusesBadInput).
SurfacePoints Surface() {
  const HeightField hf(5);
  const auto v = RenderHeightField(hf, TestCamera(), LookDown(0, 0, 30), 0.005, 1);
  SurfacePoints s = SampleOrganised(v.points, v.normals, v.quality, 2);
  s.normals[20] = Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN());
  return s;
}

// Queries near the surface (a sample moved by up to ±`spread` mm per axis) and some far away.
std::vector<Eigen::Vector3f> Queries(const SurfacePoints& s, float spread, int n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<size_t> pick(0, s.size() - 1);
  std::uniform_real_distribution<float> off(-spread, spread);
  std::vector<Eigen::Vector3f> q;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3f p = s.points[pick(rng)];
    q.push_back(p + Eigen::Vector3f(off(rng), off(rng), off(rng)));
  }
  q.push_back(Eigen::Vector3f(1e6f, -1e6f, 1e6f));  // far outside the grid
  q.push_back(Eigen::Vector3f(0, 0, -50));
  return q;
}

// The grid's answer to q within `gate` is the k-d tree's: the same refusal, or the same sample with
// the same normal. *found: whether there is a match.
::testing::AssertionResult SameAsKdTree(const KdTreeTarget& tree, const GridTarget& grid,
                                        const Eigen::Vector3f& q, float gate, bool* found) {
  Eigen::Vector3f pt, nt, pg, ng;
  *found = tree.Find(q, gate, &pt, &nt);
  const bool g = grid.Find(q, gate, &pg, &ng);
  if (*found != g)
    return ::testing::AssertionFailure() << "gate " << gate << " query " << q.transpose()
                                         << ": k-d tree " << *found << ", grid " << g;
  if (*found && (pt != pg || nt != ng))
    return ::testing::AssertionFailure()
           << "gate " << gate << " query " << q.transpose() << ": k-d tree " << pt.transpose()
           << " (normal " << nt.transpose() << "), grid " << pg.transpose() << " (normal "
           << ng.transpose() << ")";
  return ::testing::AssertionSuccess();
}

// Every query gets the k-d tree's match (same point, same normal, same refusals), for the gates
// the grids were built for and for one between them and one beyond them (more rings searched).
TEST(GridTarget, FindsWhatTheKdTreeFinds) {
  const SurfacePoints s = Surface();
  const KdTreeTarget tree(s);
  GridTarget grid;
  grid.Build(s, {1.0, 0.3, 0.15, 1.96});
  int matched = 0, refused = 0;
  for (float gate : {0.15f, 0.3f, 1.0f, 1.96f, 0.2f, 2.5f}) {
    for (const Eigen::Vector3f& q : Queries(s, 2 * gate, 3000, 7)) {
      bool found = false;
      ASSERT_TRUE(SameAsKdTree(tree, grid, q, gate, &found));
      matched += found;
      refused += !found;
    }
  }
  EXPECT_GT(matched, 5000);  // both outcomes exercised
  EXPECT_GT(refused, 1000);
}

// The tracker's gates 0.15 / 0.3 / 1.0 mm (decimated from 0.5 mm): 0.15 mm shares the 0.3 mm grid
// (within kShareGateRatio), 1.0 mm keeps its own (decimated: it cannot serve finer gates), and a
// 0.15 mm query on the shared grid still finds what the k-d tree finds. Gates farther apart, or
// one below a decimated gate, get grids of their own.
TEST(GridTarget, AGateWithinTwiceTheNextSharesItsGrid) {
  const SurfacePoints s = Surface();
  const KdTreeTarget tree(s);
  GridTarget grid;
  grid.Build(s, {0.15, 0.3, 1.0}, 0.5);
  EXPECT_EQ(grid.grids(), 2u);
  EXPECT_EQ(grid.samples(0.15f), grid.samples(0.3f));
  EXPECT_LT(grid.samples(1.0f), grid.samples(0.3f));  // the decimated one
  int matched = 0;
  for (const Eigen::Vector3f& q : Queries(s, 0.3f, 3000, 11)) {
    bool found = false;
    ASSERT_TRUE(SameAsKdTree(tree, grid, q, 0.15f, &found));
    matched += found;
  }
  EXPECT_GT(matched, 1000);
  grid.Build(s, {0.15, 0.31}, 0);
  EXPECT_EQ(grid.grids(), 2u);
  grid.Build(s, {0.3, 0.6}, 0.5);  // 0.6 is decimated
  EXPECT_EQ(grid.grids(), 2u);
  grid.Build(s, {0.3, 0.6}, 0);
  EXPECT_EQ(grid.grids(), 1u);
}

// Decimated above 0.5 mm: the 1.0 mm grid keeps one sample per 0.25 mm voxel, and finds the
// nearest of those: never nearer than the exact nearest sample, never farther than it plus a voxel
// diagonal, always a sample of the target with its own normal. The 0.15 mm grid stays exact.
TEST(GridTarget, ADecimatedGridKeepsOneSamplePerVoxel) {
  const SurfacePoints s = Surface();
  const KdTreeTarget tree(s);
  GridTarget grid;
  grid.Build(s, {1.0, 0.15}, 0.5);
  EXPECT_EQ(grid.samples(0.15f), s.size());
  EXPECT_GT(grid.samples(1.0f), 0u);
  EXPECT_LT(grid.samples(1.0f), s.size() / 3);
  const float voxel = 1.0f / GridTarget::kDecimateVoxels, diagonal = std::sqrt(3.0f) * voxel;
  int exact = 0, decimated = 0, farther = 0;
  for (const Eigen::Vector3f& q : Queries(s, 0.3f, 3000, 11)) {
    bool found = false;
    ASSERT_TRUE(SameAsKdTree(tree, grid, q, 0.15f, &found));
    exact += found;
    Eigen::Vector3f pt, nt, pg, ng;
    if (!tree.Find(q, 1.0f - diagonal, &pt, &nt)) continue;
    ASSERT_TRUE(grid.Find(q, 1.0f, &pg, &ng)) << q.transpose();
    const float d_exact = (q - pt).norm(), d_grid = (q - pg).norm();
    EXPECT_GE(d_grid, d_exact - 1e-5f);
    EXPECT_LE(d_grid, d_exact + diagonal + 1e-5f);
    farther += d_grid > d_exact + 1e-5f;
    Eigen::Vector3f p_same, n_same;  // a sample of the target, with its own normal
    ASSERT_TRUE(tree.Find(pg, 1e-4f, &p_same, &n_same));
    EXPECT_EQ(p_same, pg);
    if (std::isfinite(n_same.x())) {
      EXPECT_EQ(n_same, ng);
    }
    ++decimated;
  }
  EXPECT_GT(exact, 1000);
  EXPECT_GT(decimated, 2500);
  EXPECT_GT(farther, decimated / 4);  // the decimation did leave samples out
  grid.Build(s, {1.0, 0.15});         // not decimated: every sample again
  EXPECT_EQ(grid.samples(1.0f), s.size());
}

// A target spread over metres gets coarser cells than its gates (kMaxCells), and stays exact.
TEST(GridTarget, ACappedGridIsStillExact) {
  SurfacePoints s = Surface();
  const size_t n = s.size();
  for (size_t i = 0; i < n; i += 3) {  // a second copy 5 m away
    s.points.push_back(s.points[i] + Eigen::Vector3f(5000, 3000, 2000));
    s.normals.push_back(s.normals[i]);
  }
  const KdTreeTarget tree(s);
  GridTarget grid;
  grid.Build(s, {0.15});
  for (const Eigen::Vector3f& q : Queries(s, 0.3f, 3000, 9)) {
    bool found = false;
    ASSERT_TRUE(SameAsKdTree(tree, grid, q, 0.15f, &found));
  }
}

// Rebuilt over another target, the grid forgets the first; an empty target finds nothing; bad
// input throws at set-up.
TEST(GridTarget, RebuildsAndRefusesBadInput) {
  GridTarget grid;
  SurfacePoints a;
  a.points = {Eigen::Vector3f(0, 0, 0)};
  a.normals = {Eigen::Vector3f(0, 0, 1)};
  grid.Build(a, {0.5});
  Eigen::Vector3f p, n;
  EXPECT_TRUE(grid.Find(Eigen::Vector3f(0.1f, 0, 0), 0.5f, &p, &n));
  SurfacePoints b;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  b.points = {Eigen::Vector3f(10, 0, 0),
              Eigen::Vector3f(nan, 0, 0)};  // a non-finite sample is left out
  b.normals = {Eigen::Vector3f(1, 0, 0), Eigen::Vector3f(0, 1, 0)};
  grid.Build(b, {0.5});
  EXPECT_FALSE(grid.Find(Eigen::Vector3f(0.1f, 0, 0), 0.5f, &p, &n));
  EXPECT_TRUE(grid.Find(Eigen::Vector3f(10.2f, 0, 0), 0.5f, &p, &n));
  EXPECT_EQ(n, Eigen::Vector3f(1, 0, 0));
  EXPECT_FALSE(grid.Find(Eigen::Vector3f(10.6f, 0, 0), 0.5f, &p, &n));  // beyond the gate
  grid.Build(SurfacePoints{}, {0.5});
  EXPECT_FALSE(grid.Find(Eigen::Vector3f(10, 0, 0), 0.5f, &p, &n));
  SurfacePoints no_normals;
  no_normals.points = {Eigen::Vector3f(0, 0, 0)};
  EXPECT_THROW(grid.Build(no_normals, {0.5}), std::invalid_argument);
  EXPECT_THROW(grid.Build(a, {0.0}), std::invalid_argument);
}

// FindCertified: the nearest sample (Find's answer within the gate), a clearance that no other
// sample breaks (checked against every sample), and, for the query moved, the answers
// CertifiedNearest promises without a search are Find's.
TEST(GridTarget, ACertifiedAnswerIsFindsAndHoldsWhereItSaysItDoes) {
  const SurfacePoints s = Surface();
  GridTarget grid;
  grid.Build(s, {1.0, 0.3, 0.15});
  std::mt19937 rng(21);
  std::uniform_real_distribution<float> dir(-1.0f, 1.0f), len(0.0f, 0.04f);
  int reusable_found = 0, reusable_none = 0, checked = 0;  // checked: queries with a margin
  for (const float gate : {1.0f, 0.3f, 0.15f})
    for (const float margin : {0.0f, 0.1f * gate}) {
      for (const Eigen::Vector3f& q : Queries(s, 0.3f, 600, 17)) {
        CertifiedNearest c;
        ASSERT_TRUE(grid.FindCertified(q, gate, margin, &c));
        ASSERT_TRUE(c.certified);
        Eigen::Vector3f p, n;
        const bool find = grid.Find(q, gate, &p, &n);
        const bool within = c.found && (q - c.point).squaredNorm() < gate * gate;
        if (within && std::isfinite(c.normal.x())) {
          ASSERT_TRUE(find) << q.transpose();
          EXPECT_EQ(p, c.point);
          EXPECT_EQ(n, c.normal);
        } else {
          EXPECT_FALSE(find) << q.transpose() << " gate " << gate;
        }
        if (c.found) {
          EXPECT_NEAR(c.distance_mm, (q - c.point).norm(), 1e-6f);
          EXPECT_GE(c.clearance_mm, c.distance_mm);
        }
        if (!c.found) {
          EXPECT_GE(c.clearance_mm, gate);  // nothing within at least the gate
        }
        for (size_t i = 0; i < s.size(); ++i) {
          if (c.found && s.points[i] == c.point) continue;
          const float d = (q - s.points[i]).norm();
          ASSERT_GE(d, c.clearance_mm - 1e-5f)
              << "sample " << i << " inside the clearance of " << q.transpose();
          if (c.found) {
            ASSERT_GE(d, c.distance_mm - 1e-6f);
          }
        }
        // The query moved: where CertifiedNearest says the answer holds, it is Find's.
        Eigen::Vector3f delta(dir(rng), dir(rng), dir(rng));
        delta = delta.normalized() * len(rng) * (margin > 0 ? 0.5f * margin / 0.04f : 1.0f);
        const Eigen::Vector3f q2 = q + delta;
        const bool find2 = grid.Find(q2, gate, &p, &n);
        if (c.found && (q2 - c.point).norm() + delta.norm() < c.clearance_mm) {
          ++reusable_found;
          const bool hit =
              (q2 - c.point).squaredNorm() < gate * gate && std::isfinite(c.normal.x());
          ASSERT_EQ(find2, hit) << q2.transpose();
          if (hit) {
            EXPECT_EQ(p, c.point);
          }
        } else if (!c.found && gate + delta.norm() < c.clearance_mm) {
          ++reusable_none;
          EXPECT_FALSE(find2) << q2.transpose();
        }
        checked += margin > 0;
      }
    }
  // With a margin, many answers stay reusable for moves within half of it (and this test is not
  // vacuous).
  EXPECT_GT(reusable_found, checked / 4);
  EXPECT_GT(reusable_none, 0);
  CertifiedNearest c;
  EXPECT_FALSE(grid.FindCertified(Eigen::Vector3f(std::numeric_limits<float>::quiet_NaN(), 0, 0),
                                  0.3f, 0.03f, &c));
  EXPECT_FALSE(c.certified);
}

// ICP with either association ends at the same pose.
TEST(GridTarget, IcpGivesTheKdTreesPose) {
  const HeightField hf(11);
  const auto cam = TestCamera();
  const Rigid3d wa = LookDown(0, 0, 30), wb = LookDown(1.5, 0.3, 30.2, 0.03, -0.04, 0.05);
  const auto va = RenderHeightField(hf, cam, wa, 0.005, 1),
             vb = RenderHeightField(hf, cam, wb, 0.005, 2);
  const SurfacePoints target = SampleOrganised(va.points, va.normals, va.quality, 1);
  const SurfacePoints source = SampleOrganised(vb.points, vb.normals, vb.quality, 2);
  Rigid3d init = wa.inverse() * wb;
  init.translation() += Eigen::Vector3d(0.2, -0.1, 0.05);
  const IcpOptions o;
  std::vector<double> gates;
  for (const IcpLevel& l : o.levels) gates.push_back(l.max_distance_mm);
  GridTarget grid;
  grid.Build(target, gates);
  const IcpResult rt = RegisterIcp(source, KdTreeTarget(target), init, o);
  const IcpResult rg = RegisterIcp(source, grid, init, o);
  ASSERT_TRUE(rt.ok) << rt.reason;
  ASSERT_TRUE(rg.ok) << rg.reason;
  EXPECT_EQ(rt.iterations, rg.iterations);
  EXPECT_EQ(rt.correspondences, rg.correspondences);
  EXPECT_TRUE(rt.target_from_source.matrix().isApprox(rg.target_from_source.matrix(), 1e-12));
  EXPECT_LT(TranslationDistanceMm(rg.target_from_source, wa.inverse() * wb), 0.005);
}

}  // namespace
}  // namespace d3d
