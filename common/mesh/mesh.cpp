#include "common/mesh/mesh.h"

#include <Eigen/Geometry>

#include "common/core/status.h"

namespace d3d {
namespace {

constexpr uint8_t kMaxSurfaceLabel = static_cast<uint8_t>(SurfaceLabel::kTooth);

// (b - a) × (c - a): twice the area, pointing outside for a counter-clockwise face.
Eigen::Vector3d FaceCross(const TriangleMesh& mesh, const Eigen::Vector3i& f) {
  const Eigen::Vector3d& a = mesh.vertices[static_cast<size_t>(f[0])];
  const Eigen::Vector3d& b = mesh.vertices[static_cast<size_t>(f[1])];
  const Eigen::Vector3d& c = mesh.vertices[static_cast<size_t>(f[2])];
  return (b - a).cross(c - a);
}

void CheckFaceIndex(const TriangleMesh& mesh, int face) {
  D3D_CHECK_MSG(face >= 0 && static_cast<size_t>(face) < mesh.faces.size(),
                "face " << face << " out of range [0, " << mesh.faces.size() << ")");
}

void CheckOptionalSize(size_t size, size_t expected, const char* what, const char* per) {
  D3D_CHECK_MSG(size == 0 || size == expected, what << " has " << size << " entries, expected 0 or "
                                                    << expected << " (one per " << per << ")");
}

}  // namespace

void TriangleMesh::Check() const {
  const size_t nv = vertices.size();
  for (size_t i = 0; i < faces.size(); ++i) {
    for (int k = 0; k < 3; ++k) {
      const int v = faces[i][k];
      D3D_CHECK_MSG(v >= 0 && static_cast<size_t>(v) < nv,
                    "face " << i << " index " << v << " out of range [0, " << nv << ")");
    }
  }
  CheckOptionalSize(vertex_normals.size(), nv, "vertex_normals", "vertex");
  CheckOptionalSize(face_colors.size(), faces.size(), "face_colors", "face");
  CheckOptionalSize(face_labels.size(), faces.size(), "face_labels", "face");
  CheckOptionalSize(face_tooth_ids.size(), faces.size(), "face_tooth_ids", "face");
  for (size_t i = 0; i < face_labels.size(); ++i) {
    D3D_CHECK_MSG(static_cast<uint8_t>(face_labels[i]) <= kMaxSurfaceLabel,
                  "face " << i << " has invalid label " << static_cast<int>(face_labels[i]));
  }
}

Eigen::Vector3d TriangleMesh::FaceNormal(int face) const {
  CheckFaceIndex(*this, face);
  const Eigen::Vector3d n = FaceCross(*this, faces[static_cast<size_t>(face)]);
  const double len = n.norm();
  return len > 0.0 ? Eigen::Vector3d(n / len) : Eigen::Vector3d::Zero();
}

double TriangleMesh::FaceArea(int face) const {
  CheckFaceIndex(*this, face);
  return 0.5 * FaceCross(*this, faces[static_cast<size_t>(face)]).norm();
}

double TriangleMesh::SurfaceArea() const {
  double area = 0.0;
  for (const Eigen::Vector3i& f : faces) area += 0.5 * FaceCross(*this, f).norm();
  return area;
}

std::pair<Eigen::Vector3d, Eigen::Vector3d> TriangleMesh::Bounds() const {
  if (vertices.empty()) return {Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
  Eigen::Vector3d lo = vertices.front();
  Eigen::Vector3d hi = vertices.front();
  for (const Eigen::Vector3d& v : vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  return {lo, hi};
}

void TriangleMesh::ComputeVertexNormals() {
  std::vector<Eigen::Vector3d> normals(vertices.size(), Eigen::Vector3d::Zero());
  for (const Eigen::Vector3i& f : faces) {
    // The cross product's length is twice the face area: summing it weights by area.
    const Eigen::Vector3d n = FaceCross(*this, f);
    for (int k = 0; k < 3; ++k) normals[static_cast<size_t>(f[k])] += n;
  }
  for (Eigen::Vector3d& n : normals) {
    const double len = n.norm();
    n = len > 0.0 ? Eigen::Vector3d(n / len) : Eigen::Vector3d::Zero();
  }
  vertex_normals = std::move(normals);
}

void TriangleMesh::Append(const TriangleMesh& other_in) {
  // Appending a mesh to itself: work on a copy so the source does not grow while we read it.
  const TriangleMesh self_copy = (&other_in == this) ? other_in : TriangleMesh{};
  const TriangleMesh& other = (&other_in == this) ? self_copy : other_in;

  // A side without vertices (faces) cannot lack a per-vertex (per-face) array.
  const bool keep_normals = (vertices.empty() || !vertex_normals.empty()) &&
                            (other.vertices.empty() || !other.vertex_normals.empty());
  const bool keep_colors = (faces.empty() || !face_colors.empty()) &&
                           (other.faces.empty() || !other.face_colors.empty());
  const bool any_labels = !face_labels.empty() || !other.face_labels.empty();
  const bool any_tooth_ids = !face_tooth_ids.empty() || !other.face_tooth_ids.empty();
  const size_t old_faces = faces.size();
  const int offset = static_cast<int>(vertices.size());

  vertices.insert(vertices.end(), other.vertices.begin(), other.vertices.end());
  faces.reserve(old_faces + other.faces.size());
  for (const Eigen::Vector3i& f : other.faces)
    faces.push_back(f + Eigen::Vector3i::Constant(offset));

  if (keep_normals) {
    vertex_normals.insert(vertex_normals.end(), other.vertex_normals.begin(),
                          other.vertex_normals.end());
  } else {
    vertex_normals.clear();
  }
  if (keep_colors) {
    face_colors.insert(face_colors.end(), other.face_colors.begin(), other.face_colors.end());
  } else {
    face_colors.clear();
  }
  if (any_labels) {
    face_labels.resize(old_faces, SurfaceLabel::kUnknown);
    if (other.face_labels.empty()) {
      face_labels.resize(faces.size(), SurfaceLabel::kUnknown);
    } else {
      face_labels.insert(face_labels.end(), other.face_labels.begin(), other.face_labels.end());
    }
  }
  if (any_tooth_ids) {
    face_tooth_ids.resize(old_faces, 0);
    if (other.face_tooth_ids.empty()) {
      face_tooth_ids.resize(faces.size(), 0);
    } else {
      face_tooth_ids.insert(face_tooth_ids.end(), other.face_tooth_ids.begin(),
                            other.face_tooth_ids.end());
    }
  }
}

}  // namespace d3d
