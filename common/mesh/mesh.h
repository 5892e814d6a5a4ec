// Triangle meshes in millimetres, with optional per-face colours and surface labels.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <vector>

namespace d3d {

// What a face is made of; selects the optical material in the virtual probe.
enum class SurfaceLabel : uint8_t {
  kUnknown = 0,
  kGingiva = 1,  // soft tissue: darker, more scattering
  kTooth = 2,    // enamel: bright, slightly translucent, specular when wet
};

// An indexed triangle mesh. Faces are counter-clockwise seen from outside (normal = (b-a)×(c-a)).
// Optional arrays are either empty or have one entry per vertex/face.
struct TriangleMesh {
  std::vector<Eigen::Vector3d> vertices;            // mm
  std::vector<Eigen::Vector3i> faces;               // indices into vertices
  std::vector<Eigen::Vector3d> vertex_normals;      // optional, unit length
  std::vector<std::array<uint8_t, 4>> face_colors;  // optional RGBA as stored in the file
  std::vector<SurfaceLabel> face_labels;            // optional
  std::vector<uint8_t> face_tooth_ids;              // optional, FDI number (11..48) or 0

  bool empty() const { return faces.empty(); }
  // Throws std::invalid_argument if an index is out of range or an optional array has the wrong
  // size.
  void Check() const;
  // Unit face normal (zero for a degenerate face).
  Eigen::Vector3d FaceNormal(int face) const;
  double FaceArea(int face) const;
  double SurfaceArea() const;
  // Axis-aligned bounds (min, max) of the vertices; zero for an empty mesh.
  std::pair<Eigen::Vector3d, Eigen::Vector3d> Bounds() const;
  // Area-weighted vertex normals from the faces (overwrites vertex_normals).
  void ComputeVertexNormals();
  // Label of a face, kUnknown when the mesh has no labels.
  SurfaceLabel Label(int face) const {
    return face_labels.empty() ? SurfaceLabel::kUnknown : face_labels[static_cast<size_t>(face)];
  }
  // Appends another mesh (indices shifted); optional arrays are kept only if both have them,
  // except labels/tooth ids, which are filled with kUnknown/0 for the side that lacks them.
  void Append(const TriangleMesh& other);
};

}  // namespace d3d
