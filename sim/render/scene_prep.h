// Preparation of a scene mesh for the virtual probe: flat midpoint subdivision of coarse meshes
// (geometry unchanged: every new vertex lies on an original edge) so that the albedo texture can
// be baked at the vertices, and the bake itself.
#pragma once

#include <vector>

#include "common/mesh/mesh.h"
#include "sim/render/probe_design.h"

namespace d3d {

// One round of 1→4 midpoint subdivision of every face (shared edges get one midpoint: no
// T-junctions). Labels, tooth ids and colours are inherited; vertex normals are interpolated and
// renormalised. parent_face (in/out): for each face of the result, the face of the original mesh
// it came from (pass the identity for the first round).
TriangleMesh SubdivideMidpoint(const TriangleMesh& mesh, std::vector<int>* parent_face);

// Median edge length (mm) of the mesh; 0 for an empty mesh.
double MedianEdgeLengthMm(const TriangleMesh& mesh);

struct PreparedScene {
  TriangleMesh mesh;                 // possibly subdivided, with vertex normals
  std::vector<int> parent_face;      // face of the input mesh each face comes from
  std::vector<float> corner_albedo;  // ρ · texture factor at each face corner (3 per face)
};

// Subdivides until the median edge ≤ max_median_edge_mm, fills vertex normals if absent, and bakes
// the albedo of each face corner from its material (design.MaterialOf(label)) and, if `texture`,
// the procedural factor (albedo_texture.h) seeded with `texture_seed`.
PreparedScene PrepareScene(const TriangleMesh& mesh, const ProbeDesign& design, bool texture,
                           uint64_t texture_seed, double max_median_edge_mm = 0.3);

}  // namespace d3d
