#include "common/mesh/mesh_clean.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <vector>

namespace d3d {
namespace {

struct UnionFind {
  std::vector<int32_t> parent;
  explicit UnionFind(size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }
  int32_t Find(int32_t a) {
    while (parent[static_cast<size_t>(a)] != a) {
      parent[static_cast<size_t>(a)] = parent[static_cast<size_t>(parent[static_cast<size_t>(a)])];
      a = parent[static_cast<size_t>(a)];
    }
    return a;
  }
  void Join(int32_t a, int32_t b) {
    a = Find(a), b = Find(b);
    if (a != b) parent[static_cast<size_t>(std::max(a, b))] = std::min(a, b);
  }
};

// Each vertex's faces (CSR: faces of vertex v at order[start[v] .. start[v+1])).
struct VertexFaces {
  std::vector<int32_t> start, order;
  explicit VertexFaces(const TriangleMesh& m) : start(m.vertices.size() + 1, 0) {
    for (const Eigen::Vector3i& f : m.faces)
      for (int c = 0; c < 3; ++c) ++start[static_cast<size_t>(f[c]) + 1];
    std::partial_sum(start.begin(), start.end(), start.begin());
    order.resize(static_cast<size_t>(start.back()));
    std::vector<int32_t> fill(start.begin(), start.end() - 1);
    for (size_t i = 0; i < m.faces.size(); ++i)
      for (int c = 0; c < 3; ++c)
        order[static_cast<size_t>(fill[static_cast<size_t>(m.faces[i][c])]++)] =
            static_cast<int32_t>(i);
  }
};

// The fans of vertex v: for each of its faces (in VertexFaces order) the index of its fan, 0-based
// in order of first appearance; returns the fan count. Faces around v are joined when they share
// an edge through v (another vertex u).
int Fans(const TriangleMesh& m, const VertexFaces& vf, int32_t v, std::vector<int32_t>* fan) {
  const int32_t b = vf.start[static_cast<size_t>(v)], e = vf.start[static_cast<size_t>(v) + 1];
  const int32_t n = e - b;
  fan->assign(static_cast<size_t>(n), 0);
  if (n <= 1) return n;
  UnionFind uf(static_cast<size_t>(n));
  for (int32_t i = 0; i < n; ++i) {
    const Eigen::Vector3i& fi = m.faces[static_cast<size_t>(vf.order[static_cast<size_t>(b + i)])];
    for (int32_t j = i + 1; j < n; ++j) {
      const Eigen::Vector3i& fj =
          m.faces[static_cast<size_t>(vf.order[static_cast<size_t>(b + j)])];
      bool shared = false;
      for (int c = 0; c < 3 && !shared; ++c)
        if (fi[c] != v)
          for (int d = 0; d < 3; ++d) shared = shared || fi[c] == fj[d];
      if (shared) uf.Join(i, j);
    }
  }
  std::vector<int32_t> label(static_cast<size_t>(n), -1);
  int fans = 0;
  for (int32_t i = 0; i < n; ++i) {
    const int32_t r = uf.Find(i);
    if (label[static_cast<size_t>(r)] < 0) label[static_cast<size_t>(r)] = fans++;
    (*fan)[static_cast<size_t>(i)] = label[static_cast<size_t>(r)];
  }
  return fans;
}

// Pieces: faces joined through shared vertices. Returns each face's piece root.
std::vector<int32_t> PieceOfFace(const TriangleMesh& m) {
  UnionFind uf(m.vertices.size());
  for (const Eigen::Vector3i& f : m.faces) {
    uf.Join(f[0], f[1]);
    uf.Join(f[0], f[2]);
  }
  std::vector<int32_t> piece(m.faces.size());
  for (size_t i = 0; i < m.faces.size(); ++i) piece[i] = uf.Find(m.faces[i][0]);
  return piece;
}

template <typename T>
void KeepFaces(const std::vector<char>& keep, std::vector<T>* v) {
  if (v->empty()) return;
  size_t out = 0;
  for (size_t i = 0; i < keep.size(); ++i)
    if (keep[i]) (*v)[out++] = (*v)[i];
  v->resize(out);
}

}  // namespace

void MeshCleanOptions::Check() const {
  if (!(min_piece_area_mm2 >= 0) || !std::isfinite(min_piece_area_mm2))
    throw std::invalid_argument("MeshCleanOptions: min_piece_area_mm2 must be >= 0, got " +
                                std::to_string(min_piece_area_mm2));
}

int64_t CountNonManifoldVertices(const TriangleMesh& mesh) {
  const VertexFaces vf(mesh);
  std::vector<int32_t> fan;
  int64_t n = 0;
  for (size_t v = 0; v < mesh.vertices.size(); ++v)
    if (Fans(mesh, vf, static_cast<int32_t>(v), &fan) > 1) ++n;
  return n;
}

int64_t CountPieces(const TriangleMesh& mesh) {
  std::vector<int32_t> piece = PieceOfFace(mesh);
  std::sort(piece.begin(), piece.end());
  return std::unique(piece.begin(), piece.end()) - piece.begin();
}

MeshCleanReport CleanMesh(const MeshCleanOptions& options, TriangleMesh* mesh) {
  options.Check();
  mesh->Check();
  MeshCleanReport report;
  TriangleMesh& m = *mesh;
  if (options.split_nonmanifold_vertices) {
    const VertexFaces vf(m);
    std::vector<int32_t> fan;
    const size_t n = m.vertices.size();
    for (size_t v = 0; v < n; ++v) {
      const int fans = Fans(m, vf, static_cast<int32_t>(v), &fan);
      if (fans <= 1) continue;
      // Fan k ≥ 1 gets vertex copy first_copy + k − 1.
      const int32_t first_copy = static_cast<int32_t>(m.vertices.size());
      for (int k = 1; k < fans; ++k) {
        m.vertices.push_back(m.vertices[v]);
        if (!m.vertex_normals.empty()) m.vertex_normals.push_back(m.vertex_normals[v]);
      }
      report.vertices_split += fans - 1;
      for (size_t i = 0; i < fan.size(); ++i) {
        if (fan[i] == 0) continue;
        Eigen::Vector3i& f = m.faces[static_cast<size_t>(vf.order[vf.start[v] + i])];
        for (int c = 0; c < 3; ++c)
          if (f[c] == static_cast<int32_t>(v)) f[c] = first_copy + fan[i] - 1;
      }
    }
  }
  // Pieces by area; the small ones go.
  const std::vector<int32_t> piece = PieceOfFace(m);
  std::vector<double> area(m.vertices.size(), 0.0);
  for (size_t i = 0; i < m.faces.size(); ++i)
    area[static_cast<size_t>(piece[i])] += m.FaceArea(static_cast<int>(i));
  std::vector<char> keep(m.faces.size(), 1);
  std::vector<char> counted(m.vertices.size(), 0);
  for (size_t i = 0; i < m.faces.size(); ++i) {
    const size_t p = static_cast<size_t>(piece[i]);
    const bool small = area[p] < options.min_piece_area_mm2;
    if (!counted[p]) {
      counted[p] = 1;
      ++(small ? report.pieces_removed : report.pieces_kept);
    }
    if (small) {
      keep[i] = 0;
      ++report.faces_removed;
    }
  }
  if (report.faces_removed > 0) {
    KeepFaces(keep, &m.faces);
    KeepFaces(keep, &m.face_colors);
    KeepFaces(keep, &m.face_labels);
    KeepFaces(keep, &m.face_tooth_ids);
  }
  // The vertices no face uses go; the rest keep their order.
  std::vector<int32_t> remap(m.vertices.size(), -1);
  for (const Eigen::Vector3i& f : m.faces)
    for (int c = 0; c < 3; ++c) remap[static_cast<size_t>(f[c])] = 0;
  int32_t next = 0;
  for (size_t v = 0; v < remap.size(); ++v)
    if (remap[v] == 0) {
      remap[v] = next;
      m.vertices[static_cast<size_t>(next)] = m.vertices[v];
      if (!m.vertex_normals.empty())
        m.vertex_normals[static_cast<size_t>(next)] = m.vertex_normals[v];
      ++next;
    }
  m.vertices.resize(static_cast<size_t>(next));
  if (!m.vertex_normals.empty()) m.vertex_normals.resize(static_cast<size_t>(next));
  for (Eigen::Vector3i& f : m.faces)
    for (int c = 0; c < 3; ++c) f[c] = remap[static_cast<size_t>(f[c])];
  return report;
}

}  // namespace d3d
