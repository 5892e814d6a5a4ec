// Cleaning a fused model for the lab (issue 55: "models a dental lab opens without cleaning"):
// vertices where two sheets touch at one point (bow-ties) split so that every vertex's faces form
// one fan, then the small pieces the fusion leaves beside the surface (specks of a few faces)
// removed. What a lab's CAD software refuses or a technician trims by hand.
//
// Threads: pure functions of their arguments.
#pragma once

#include <cstdint>

#include "common/mesh/mesh.h"

namespace d3d {

struct MeshCleanOptions {
  // Edge-connected pieces with less area than this (mm²) are removed (0 = none): at the fusion's
  // 0.05 mm voxels a speck of 4–23 vertices is ~0.01 mm², a whole crown ~100 mm².
  double min_piece_area_mm2 = 0.5;
  // A vertex whose faces form several fans (around it, faces joined by an edge through it) gets one
  // copy per fan after the first: the mesh is then vertex-manifold.
  bool split_nonmanifold_vertices = true;
  void Check() const;  // throws std::invalid_argument
};

struct MeshCleanReport {
  int64_t vertices_split = 0;  // copies made (bow-tie vertices, counted per extra fan)
  int64_t pieces_removed = 0;
  int64_t faces_removed = 0;
  int64_t pieces_kept = 0;
};

// Cleans *mesh in place: splits, then removes the small pieces and the vertices no face uses. Every
// optional per-vertex or per-face array follows (a split vertex copies its normal). Throws
// std::invalid_argument for invalid options or a mesh that fails TriangleMesh::Check.
MeshCleanReport CleanMesh(const MeshCleanOptions& options, TriangleMesh* mesh);

// Vertices whose faces form more than one fan (bow-ties), and edge-connected pieces: what
// CleanMesh would change, for reports and tests.
int64_t CountNonManifoldVertices(const TriangleMesh& mesh);
int64_t CountPieces(const TriangleMesh& mesh);

}  // namespace d3d
