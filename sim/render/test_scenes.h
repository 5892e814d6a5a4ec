// Analytic test scenes for the virtual probe and the stages downstream of it.
#pragma once

#include <Eigen/Geometry>

#include "common/mesh/mesh.h"

namespace d3d {

// A square of side 2·half_mm through `point` (mm) with normal `normal`, as two triangles labelled
// `label`: a plane for the probe's whole field of view.
inline TriangleMesh PlaneMesh(const Eigen::Vector3d& normal, const Eigen::Vector3d& point,
                              double half_mm = 80.0, SurfaceLabel label = SurfaceLabel::kTooth) {
  const Eigen::Vector3d n = normal.normalized(), a = n.unitOrthogonal(), b = n.cross(a);
  TriangleMesh m;
  m.vertices = {point - half_mm * a - half_mm * b, point + half_mm * a - half_mm * b,
                point + half_mm * a + half_mm * b, point - half_mm * a + half_mm * b};
  m.faces = {{0, 1, 2}, {0, 2, 3}};
  m.face_labels = {label, label};
  return m;
}

}  // namespace d3d
