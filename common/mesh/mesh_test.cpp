#include "common/mesh/mesh.h"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>

namespace d3d {
namespace {

// A unit cube [0,1]^3, 8 vertices, 12 outward counter-clockwise triangles.
TriangleMesh UnitCube() {
  TriangleMesh m;
  for (int i = 0; i < 8; ++i) m.vertices.emplace_back(i & 1, (i >> 1) & 1, (i >> 2) & 1);
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads) {
    m.faces.emplace_back(q[0], q[1], q[2]);
    m.faces.emplace_back(q[0], q[2], q[3]);
  }
  return m;
}

TriangleMesh OneTriangle(double offset = 0.0) {
  TriangleMesh m;
  m.vertices = {{offset, 0, 0}, {offset + 2, 0, 0}, {offset, 3, 0}};
  m.faces = {{0, 1, 2}};
  return m;
}

TEST(TriangleMesh, CheckAcceptsValidMesh) {
  TriangleMesh m = UnitCube();
  EXPECT_NO_THROW(m.Check());
  m.face_colors.assign(m.faces.size(), {1, 2, 3, 4});
  m.face_labels.assign(m.faces.size(), SurfaceLabel::kTooth);
  m.face_tooth_ids.assign(m.faces.size(), 11);
  m.ComputeVertexNormals();
  EXPECT_NO_THROW(m.Check());
  EXPECT_NO_THROW(TriangleMesh().Check());
}

TEST(TriangleMesh, CheckThrowsOnBadIndexOrSizes) {
  TriangleMesh m = UnitCube();
  m.faces[3][1] = 8;
  EXPECT_THROW(m.Check(), std::invalid_argument);
  m.faces[3][1] = -1;
  EXPECT_THROW(m.Check(), std::invalid_argument);

  m = UnitCube();
  m.vertex_normals.resize(3);
  EXPECT_THROW(m.Check(), std::invalid_argument);
  m = UnitCube();
  m.face_colors.resize(5);
  EXPECT_THROW(m.Check(), std::invalid_argument);
  m = UnitCube();
  m.face_labels.resize(13);
  EXPECT_THROW(m.Check(), std::invalid_argument);
  m = UnitCube();
  m.face_tooth_ids.resize(1);
  EXPECT_THROW(m.Check(), std::invalid_argument);
  m = UnitCube();
  m.face_labels.assign(m.faces.size(), static_cast<SurfaceLabel>(7));
  EXPECT_THROW(m.Check(), std::invalid_argument);
}

TEST(TriangleMesh, CheckMessageNamesTheFace) {
  TriangleMesh m = UnitCube();
  m.faces[5][2] = 42;
  try {
    m.Check();
    FAIL() << "Check did not throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("face 5 index 42"), std::string::npos) << e.what();
  }
}

TEST(TriangleMesh, FaceNormalAndArea) {
  const TriangleMesh m = OneTriangle();
  EXPECT_TRUE(m.FaceNormal(0).isApprox(Eigen::Vector3d(0, 0, 1)));
  EXPECT_DOUBLE_EQ(m.FaceArea(0), 3.0);
  EXPECT_DOUBLE_EQ(m.SurfaceArea(), 3.0);
  EXPECT_THROW(m.FaceNormal(1), std::invalid_argument);
  EXPECT_THROW(m.FaceArea(-1), std::invalid_argument);

  TriangleMesh degenerate;
  degenerate.vertices = {{0, 0, 0}, {1, 1, 1}, {2, 2, 2}};
  degenerate.faces = {{0, 1, 2}};
  EXPECT_EQ(degenerate.FaceNormal(0), Eigen::Vector3d::Zero());
  EXPECT_DOUBLE_EQ(degenerate.FaceArea(0), 0.0);
}

TEST(TriangleMesh, CubeNormalsPointOutward) {
  const TriangleMesh m = UnitCube();
  EXPECT_NEAR(m.SurfaceArea(), 6.0, 1e-12);
  const Eigen::Vector3d centre(0.5, 0.5, 0.5);
  for (int f = 0; f < static_cast<int>(m.faces.size()); ++f) {
    const Eigen::Vector3d c =
        (m.vertices[m.faces[f][0]] + m.vertices[m.faces[f][1]] + m.vertices[m.faces[f][2]]) / 3;
    EXPECT_GT(m.FaceNormal(f).dot(c - centre), 0.0) << "face " << f;
  }
}

TEST(TriangleMesh, Bounds) {
  const auto [lo, hi] = UnitCube().Bounds();
  EXPECT_EQ(lo, Eigen::Vector3d(0, 0, 0));
  EXPECT_EQ(hi, Eigen::Vector3d(1, 1, 1));
  TriangleMesh shifted = OneTriangle(-5.0);
  const auto [lo2, hi2] = shifted.Bounds();
  EXPECT_EQ(lo2, Eigen::Vector3d(-5, 0, 0));
  EXPECT_EQ(hi2, Eigen::Vector3d(-3, 3, 0));
  const auto [lo3, hi3] = TriangleMesh().Bounds();
  EXPECT_EQ(lo3, Eigen::Vector3d::Zero());
  EXPECT_EQ(hi3, Eigen::Vector3d::Zero());
}

TEST(TriangleMesh, VertexNormalsOfCubeCornersAreDiagonals) {
  TriangleMesh m = UnitCube();
  m.ComputeVertexNormals();
  ASSERT_EQ(m.vertex_normals.size(), 8u);
  for (size_t i = 0; i < 8; ++i) {
    const Eigen::Vector3d expected = (m.vertices[i] - Eigen::Vector3d::Constant(0.5)).normalized();
    // Each corner touches one or two triangles per face, so weights differ; the direction is close.
    EXPECT_NEAR(m.vertex_normals[i].norm(), 1.0, 1e-12);
    EXPECT_GT(m.vertex_normals[i].dot(expected), 0.9) << "vertex " << i;
  }
}

TEST(TriangleMesh, VertexNormalsAreAreaWeighted) {
  // Vertex 0 is shared by a big triangle in z=0 (normal +z) and a small one in x=0 (normal +x).
  TriangleMesh m;
  m.vertices = {{0, 0, 0}, {4, 0, 0}, {0, 4, 0}, {0, 1, 0}, {0, 0, 1}};
  m.faces = {{0, 1, 2}, {0, 3, 4}};
  m.vertices.emplace_back(9, 9, 9);  // isolated vertex: zero normal
  m.ComputeVertexNormals();
  const Eigen::Vector3d expected = Eigen::Vector3d(1.0, 0.0, 16.0).normalized();  // areas 8 and 0.5
  EXPECT_TRUE(m.vertex_normals[0].isApprox(expected, 1e-12)) << m.vertex_normals[0].transpose();
  EXPECT_EQ(m.vertex_normals[5], Eigen::Vector3d::Zero());
}

TEST(TriangleMesh, AppendShiftsIndicesAndMergesArrays) {
  TriangleMesh a = OneTriangle();
  a.face_colors = {{1, 2, 3, 255}};
  a.face_labels = {SurfaceLabel::kTooth};
  a.ComputeVertexNormals();
  TriangleMesh b = OneTriangle(10.0);
  b.face_colors = {{9, 9, 9, 255}};
  b.face_tooth_ids = {21};
  a.Append(b);
  EXPECT_NO_THROW(a.Check());
  ASSERT_EQ(a.faces.size(), 2u);
  EXPECT_EQ(a.faces[1], Eigen::Vector3i(3, 4, 5));
  EXPECT_EQ(a.vertices[3], Eigen::Vector3d(10, 0, 0));
  EXPECT_TRUE(a.vertex_normals.empty());  // b had none
  ASSERT_EQ(a.face_colors.size(), 2u);    // both had colours
  EXPECT_EQ(a.face_colors[1][0], 9);
  EXPECT_EQ(a.face_labels,
            (std::vector<SurfaceLabel>{SurfaceLabel::kTooth, SurfaceLabel::kUnknown}));
  EXPECT_EQ(a.face_tooth_ids, (std::vector<uint8_t>{0, 21}));
}

TEST(TriangleMesh, AppendToEmptyKeepsEverything) {
  TriangleMesh b = OneTriangle();
  b.ComputeVertexNormals();
  b.face_colors = {{1, 2, 3, 4}};
  TriangleMesh a;
  a.Append(b);
  EXPECT_EQ(a.vertex_normals.size(), 3u);
  EXPECT_EQ(a.face_colors.size(), 1u);
  EXPECT_TRUE(a.face_labels.empty());
  EXPECT_NO_THROW(a.Check());
}

TEST(TriangleMesh, AppendToItself) {
  TriangleMesh a = UnitCube();
  a.Append(a);
  EXPECT_EQ(a.vertices.size(), 16u);
  EXPECT_EQ(a.faces.size(), 24u);
  EXPECT_NO_THROW(a.Check());
  EXPECT_NEAR(a.SurfaceArea(), 12.0, 1e-12);
}

}  // namespace
}  // namespace d3d
