#include "common/mesh/mesh_clean.h"

#include <gtest/gtest.h>

#include <stdexcept>

namespace d3d {
namespace {

// An n × n grid of unit-`step` squares (two faces each) in the plane z = 0 at `origin`.
TriangleMesh Grid(int n, double step, const Eigen::Vector3d& origin) {
  TriangleMesh m;
  for (int y = 0; y <= n; ++y)
    for (int x = 0; x <= n; ++x) m.vertices.push_back(origin + Eigen::Vector3d(x, y, 0) * step);
  auto id = [n](int x, int y) { return y * (n + 1) + x; };
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x) {
      m.faces.emplace_back(id(x, y), id(x + 1, y), id(x + 1, y + 1));
      m.faces.emplace_back(id(x, y), id(x + 1, y + 1), id(x, y + 1));
    }
  return m;
}

// Two 4 × 4 mm sheets that touch at one corner vertex (a bow-tie, as marching cubes leaves where
// two surfaces meet at a voxel corner): split into two pieces, each vertex-manifold.
TEST(MeshClean, ABowTieVertexIsSplitIntoOneCopyPerFan) {
  TriangleMesh a = Grid(4, 1.0, Eigen::Vector3d(0, 0, 0));
  TriangleMesh b = Grid(4, 1.0, Eigen::Vector3d(4, 4, 0));
  const int corner_a = static_cast<int>(a.vertices.size()) - 1;  // (4, 4, 0)
  const int offset = static_cast<int>(a.vertices.size());
  a.Append(b);
  for (Eigen::Vector3i& f : a.faces)  // b's (0, 0) corner becomes a's (4, 4) corner
    for (int c = 0; c < 3; ++c)
      if (f[c] == offset) f[c] = corner_a;
  a.ComputeVertexNormals();
  EXPECT_EQ(CountNonManifoldVertices(a), 1);
  EXPECT_EQ(CountPieces(a), 1);
  const size_t faces = a.faces.size();
  const MeshCleanReport r = CleanMesh(MeshCleanOptions{}, &a);
  EXPECT_EQ(r.vertices_split, 1);
  EXPECT_EQ(r.pieces_removed, 0);
  EXPECT_EQ(r.pieces_kept, 2);
  EXPECT_EQ(a.faces.size(), faces);
  EXPECT_EQ(CountNonManifoldVertices(a), 0);
  EXPECT_EQ(CountPieces(a), 2);
  EXPECT_EQ(a.vertices.size(), 50u);  // 25 + 25: b's unused corner gone, the shared one copied
  EXPECT_EQ(a.vertex_normals.size(), a.vertices.size());
  EXPECT_NO_THROW(a.Check());
}

// A speck (two faces, 0.005 mm²) beside a sheet goes with its vertices; the sheet and its labels
// stay as they were; nothing else changes.
TEST(MeshClean, SpecksGoTheSurfaceStays) {
  TriangleMesh m = Grid(10, 0.5, Eigen::Vector3d(0, 0, 0));  // 25 mm²
  TriangleMesh speck = Grid(1, 0.1, Eigen::Vector3d(2, 2, 0.3));
  m.Append(speck);
  m.face_labels.assign(m.faces.size(), SurfaceLabel::kTooth);
  m.face_labels.back() = SurfaceLabel::kGingiva;  // the speck's second face
  const TriangleMesh sheet = Grid(10, 0.5, Eigen::Vector3d(0, 0, 0));
  const MeshCleanReport r = CleanMesh(MeshCleanOptions{}, &m);
  EXPECT_EQ(r.pieces_removed, 1);
  EXPECT_EQ(r.faces_removed, 2);
  EXPECT_EQ(r.vertices_split, 0);
  ASSERT_EQ(m.faces.size(), sheet.faces.size());
  ASSERT_EQ(m.vertices.size(), sheet.vertices.size());
  for (size_t i = 0; i < m.faces.size(); ++i) EXPECT_EQ(m.faces[i], sheet.faces[i]);
  for (size_t i = 0; i < m.vertices.size(); ++i) EXPECT_EQ(m.vertices[i], sheet.vertices[i]);
  for (SurfaceLabel l : m.face_labels) EXPECT_EQ(l, SurfaceLabel::kTooth);

  // With no area limit the speck stays.
  TriangleMesh kept = sheet;
  kept.Append(speck);
  MeshCleanOptions none;
  none.min_piece_area_mm2 = 0;
  EXPECT_EQ(CleanMesh(none, &kept).pieces_removed, 0);
  EXPECT_EQ(kept.faces.size(), sheet.faces.size() + 2);
}

TEST(MeshClean, CheckRefusesANegativeArea) {
  MeshCleanOptions o;
  o.min_piece_area_mm2 = -1;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  TriangleMesh m = Grid(2, 1.0, Eigen::Vector3d::Zero());
  EXPECT_THROW(CleanMesh(o, &m), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
