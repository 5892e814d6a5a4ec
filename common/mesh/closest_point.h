// The closest point of a triangle to a point.
#pragma once

#include <Eigen/Core>

namespace d3d {

// Where on the triangle the closest point lies (the feature of abc it falls on).
enum TriangleRegion : int {
  kTriangleInterior = 0,
  kTriangleVertexA = 1,
  kTriangleVertexB = 2,
  kTriangleVertexC = 3,
  kTriangleEdgeAB = 4,
  kTriangleEdgeBC = 5,
  kTriangleEdgeCA = 6,
};

// The point of the triangle abc (its interior, edges and vertices) closest to p.
// p, a, b, c: 3-vectors in one frame and one length unit (mm throughout d3dscan); the result is
// in the same frame and unit, and |p − result| is the point-to-triangle distance.
// region: set to the feature the result lies on, a TriangleRegion (0 interior, 1..3 vertex a, b,
// c, 4 edge ab, 5 edge bc, 6 edge ca); the second form leaves it out.
// Method: Ericson, "Real-Time Collision Detection" (2005), 5.1.5: the Voronoi regions of vertex
// a, vertex b, edge ab, vertex c, edge ca and edge bc are tested in that order with dot products of
// the edge vectors; otherwise p projects into the triangle, and the projection is built from its
// barycentric coordinates. No square root; one division on an edge or inside. abc should have
// non-zero area: inside, the division is by |ab|²·|ac|² − (ab·ac)², zero for a degenerate triangle.
Eigen::Vector3d ClosestOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                  const Eigen::Vector3d& b, const Eigen::Vector3d& c, int* region);
Eigen::Vector3d ClosestOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                  const Eigen::Vector3d& b, const Eigen::Vector3d& c);

}  // namespace d3d
