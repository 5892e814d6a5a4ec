#include "sim/render/scene_prep.h"

#include <algorithm>
#include <unordered_map>

#include "sim/render/albedo_texture.h"

namespace d3d {

TriangleMesh SubdivideMidpoint(const TriangleMesh& mesh, std::vector<int>* parent_face) {
  TriangleMesh out;
  out.vertices = mesh.vertices;
  out.vertex_normals = mesh.vertex_normals;
  const bool normals = !mesh.vertex_normals.empty();
  std::unordered_map<uint64_t, int> midpoint;
  midpoint.reserve(mesh.faces.size() * 2);
  auto mid = [&](int a, int b) {
    const uint64_t key =
        (static_cast<uint64_t>(std::min(a, b)) << 32) | static_cast<uint32_t>(std::max(a, b));
    const auto it = midpoint.find(key);
    if (it != midpoint.end()) return it->second;
    const int index = static_cast<int>(out.vertices.size());
    out.vertices.push_back(
        0.5 * (mesh.vertices[static_cast<size_t>(a)] + mesh.vertices[static_cast<size_t>(b)]));
    if (normals) {
      const Eigen::Vector3d n =
          mesh.vertex_normals[static_cast<size_t>(a)] + mesh.vertex_normals[static_cast<size_t>(b)];
      out.vertex_normals.push_back(
          n.squaredNorm() > 0 ? n.normalized() : mesh.vertex_normals[static_cast<size_t>(a)]);
    }
    midpoint.emplace(key, index);
    return index;
  };
  std::vector<int> parents;
  parents.reserve(mesh.faces.size() * 4);
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    const Eigen::Vector3i& t = mesh.faces[f];
    const int ab = mid(t[0], t[1]), bc = mid(t[1], t[2]), ca = mid(t[2], t[0]);
    const Eigen::Vector3i children[4] = {
        {t[0], ab, ca}, {ab, t[1], bc}, {ca, bc, t[2]}, {ab, bc, ca}};
    for (const auto& c : children) {
      out.faces.push_back(c);
      parents.push_back(parent_face->empty() ? static_cast<int>(f) : (*parent_face)[f]);
      if (!mesh.face_labels.empty()) out.face_labels.push_back(mesh.face_labels[f]);
      if (!mesh.face_tooth_ids.empty()) out.face_tooth_ids.push_back(mesh.face_tooth_ids[f]);
      if (!mesh.face_colors.empty()) out.face_colors.push_back(mesh.face_colors[f]);
    }
  }
  *parent_face = std::move(parents);
  return out;
}

double MedianEdgeLengthMm(const TriangleMesh& mesh) {
  if (mesh.faces.empty()) return 0.0;
  std::vector<double> edges;
  const size_t step = std::max<size_t>(1, mesh.faces.size() / 20000);  // a sample is enough
  for (size_t f = 0; f < mesh.faces.size(); f += step) {
    const Eigen::Vector3i& t = mesh.faces[f];
    for (int k = 0; k < 3; ++k)
      edges.push_back((mesh.vertices[static_cast<size_t>(t[k])] -
                       mesh.vertices[static_cast<size_t>(t[(k + 1) % 3])])
                          .norm());
  }
  std::nth_element(edges.begin(), edges.begin() + static_cast<long>(edges.size() / 2), edges.end());
  return edges[edges.size() / 2];
}

PreparedScene PrepareScene(const TriangleMesh& mesh, const ProbeDesign& design, bool texture,
                           uint64_t texture_seed, double max_median_edge_mm) {
  PreparedScene s;
  s.mesh = mesh;
  s.parent_face.resize(mesh.faces.size());
  for (size_t f = 0; f < mesh.faces.size(); ++f) s.parent_face[f] = static_cast<int>(f);
  if (s.mesh.vertex_normals.empty() && !s.mesh.faces.empty()) s.mesh.ComputeVertexNormals();
  for (int round = 0;
       round < 4 && !s.mesh.faces.empty() && MedianEdgeLengthMm(s.mesh) > max_median_edge_mm;
       ++round) {
    s.mesh = SubdivideMidpoint(s.mesh, &s.parent_face);
  }
  s.corner_albedo.resize(3 * s.mesh.faces.size());
  for (size_t f = 0; f < s.mesh.faces.size(); ++f) {
    const Material& m = design.MaterialOf(s.mesh.Label(static_cast<int>(f)));
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3d& p = s.mesh.vertices[static_cast<size_t>(s.mesh.faces[f][k])];
      s.corner_albedo[3 * f + static_cast<size_t>(k)] =
          static_cast<float>(m.albedo * (texture ? AlbedoFactor(m, p, texture_seed) : 1.0));
    }
  }
  return s;
}

}  // namespace d3d
