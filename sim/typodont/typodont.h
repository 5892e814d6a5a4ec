// A procedural typodont: an upper dental arch of 14 teeth with gingiva, built from anatomy tables
// (no data file). It is the default "mouth" that the virtual probe scans.
//
// Frame (the same convention as the real scan in shared/data/dental), millimetres:
//   +z anterior (toward the incisors), +y apical (toward the roots: "up" for an upper arch, so the
//   crowns point toward -y), x across the arch with the patient's left (teeth 21..27) at +x.
//   Origin: x = 0 on the midline, y = 0 on the occlusal plane (incisal edges and cusp tips near
//   y = 0, gingival margins around y = +6..+10), z = 0 half-way between the labial face of the
//   central incisors and the distal face of the second molars.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "common/mesh/mesh.h"

namespace d3d {

struct TypodontOptions {
  // Uniform scale of the anatomy (arch and teeth); 1 = average adult (values in typodont.cpp).
  // Gap and edge lengths below are absolute and not scaled.
  double scale = 1.0;
  // Smallest distance between adjacent crowns (at their contact areas, and between 11 and 21).
  // Each crown stays a separate surface: the depth discontinuity there matters to unwrapping.
  double gap_mm = 0.2;
  // Target triangle edge length on the crowns (largest edges stay below about 1.5x this).
  double crown_edge_mm = 0.15;
  // Target triangle edge length on the gingiva.
  double gingiva_edge_mm = 0.4;
  // Width of the gingival shelf around each crown at the margin (free-gingiva thickness).
  double gingiva_thickness_mm = 0.9;
  // y of the apical (top) open edge of the buccal gingiva; the gum spans from the scalloped margin
  // (y about 6..10) up to here. Scaled with `scale`.
  double gingiva_top_y_mm = 17.0;
  // How far the palatal gingiva reaches from the teeth toward the midline (start of the palate).
  double palate_width_mm = 7.0;
  // Seed of the small natural asymmetries (per-tooth rotations/tips up to +-2 deg, sizes +-2 %,
  // heights +-0.15 mm): std::mt19937 with this seed. Same options -> bit-identical mesh.
  uint32_t seed = 1;
  // Multiplies all seeded asymmetries; 0 gives an exactly mirror-symmetric arch.
  double asymmetry = 1.0;

  // Throws std::invalid_argument (D3D_CHECK_MSG) on values that cannot make an arch.
  void Check() const;
};

// Landmarks of one tooth as placed in the typodont (global frame above).
struct TypodontTooth {
  int fdi = 0;                          // 17..11, 21..27
  double arch_s = 0;                    // signed arc length of the crown on the occlusal arch curve
                                        // (0 on the midline, + toward the patient's left)
  Eigen::Vector3d cej_center{0, 0, 0};  // centre of the cervical line (cemento-enamel junction)
  Eigen::Vector3d tip{0, 0, 0};         // top of the crown axis (incisal edge / cusp level)
  Eigen::Matrix3d axes = Eigen::Matrix3d::Identity();  // columns: distal, buccal, occlusal units
  std::vector<Eigen::Vector3d> cusp_tips;              // mesh vertices at the cusp tips
                                           // (canine 1, premolars B,P, molars MB,DB,MP,DP)
};

struct TypodontInfo {
  std::vector<TypodontTooth> teeth;  // in mesh order: 17..11 then 21..27
  std::vector<Eigen::Vector3d>
      arch_curve;  // occlusal arch curve at y = 0, 1 mm steps, right to left
};

// Builds the typodont: 14 crowns (face_labels kTooth, face_tooth_ids = FDI number) followed by one
// gingiva surface (kGingiva, tooth id 0). Faces are counter-clockwise seen from outside and
// vertex_normals are area-weighted smooth normals. No crown surface lies inside the gingiva: each
// crown is clipped exactly along the gum surface (the gingiva runs on under the crowns, so the cut
// leaves no hole). The interproximal walls near the contacts (crowns gap_mm apart) stay, though a
// probe barely reaches them: they are most of what a full-arch scan leaves uncovered.
// With default options: about 467k triangles (crowns ~339k, gingiva ~129k), 0.7-0.9 s in Release
// on one core.
// `info`, when given, receives the tooth landmarks and the arch curve.
TriangleMesh MakeTypodont(const TypodontOptions& options = {}, TypodontInfo* info = nullptr);

}  // namespace d3d
