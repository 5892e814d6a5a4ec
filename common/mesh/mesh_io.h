// Reading and writing triangle meshes: PLY (ascii, binary little/big endian), STL (ascii, binary)
// and Wavefront OBJ. Coordinates are taken as millimetres, exactly as stored (no unit conversion).
//
// The loaders never throw and never crash on hostile input: every problem comes back as a Status
// naming what is wrong and where, e.g. "ply: face 12 index 9001 >= vertex count 8502".
//   NOT_FOUND         the file does not exist
//   IO_ERROR          the OS refused to read or write it
//   PARSE_ERROR       not a mesh we can read: empty, unknown format, malformed header or record
//                     (including a face of fewer than 3 vertices), truncated data, counts larger
//                     than the data can hold, no faces
//   UNSUPPORTED       a valid file we do not handle (e.g. an unknown PLY format)
//   CORRUPT           well-formed but inconsistent: index out of range, NaN/inf coordinate or
//                     normal, a label outside SurfaceLabel, a tooth_id outside 0..255
//   INVALID_ARGUMENT  null output, or a mesh that cannot be written (fails Check, no faces, NaN)
//   INTERNAL          an unexpected exception inside a loader or writer (a bug), caught and
//   reported
// On failure the output mesh is left untouched. A successful load always passes
// TriangleMesh::Check.
#pragma once

#include <string>
#include <string_view>

#include "common/core/status.h"
#include "common/mesh/mesh.h"

namespace d3d {

enum class MeshFormat {
  kAuto,  // detect from the content (PLY magic, binary STL size, "solid", OBJ records)
  kPly,
  kStl,
  kObj,
};

const char* MeshFormatName(MeshFormat format);

// The format the bytes look like, or kAuto when they match none:
//   "ply" magic → kPly; a binary STL (size == 84 + 50·n, n read at byte 80, whatever its header
//   says, "solid" included) → kStl; text starting with "solid" → kStl; a first record that is an
//   OBJ keyword (v, vn, vt, f, o, g, usemtl, mtllib, ...) → kObj.
MeshFormat DetectMeshFormat(std::string_view bytes);

// Loads a mesh file (mm). The format comes from the content (see DetectMeshFormat), falling back
// on the extension (.ply, .stl, .obj, any case) when the content is ambiguous.
//   PLY: any vertex properties in any order and of any type (char..double, int8..float64); x,y,z
//        required, nx,ny,nz → vertex_normals (normalised). Face element "face" with a list
//        "vertex_indices" or "vertex_index" (any count/index type); polygons are fan-triangulated
//        and their per-face data copied to each triangle. Optional per-face red,green,blue[,alpha]
//        → face_colors (alpha 255 if absent; float colours are taken as 0..1), "label"
//        (0 unknown, 1 gingiva, 2 tooth) → face_labels, "tooth_id" (0..255) → face_tooth_ids.
//        Other elements (edge, material, ...) and properties are skipped. Values of "float"
//        properties are rounded to float in ascii files too, so ascii and binary load alike.
//   STL: ascii or binary; identical corner positions are merged into one vertex. No normals.
//   OBJ: v, vn, f with v, v/vt, v//vn, v/vt/vn and negative (relative) indices; polygons
//        fan-triangulated; vertex_normals filled only when every vertex gets one from an f record.
//        Other records are ignored.
[[nodiscard]] Status LoadMesh(const std::string& path, TriangleMesh* out);

// Same as LoadMesh on bytes held in memory. `hint` forces a parser; kAuto detects from the content
// and fails with PARSE_ERROR when the content matches no format.
[[nodiscard]] Status LoadMeshFromMemory(const std::string& bytes, MeshFormat hint,
                                        TriangleMesh* out);

// Labels faces from their colour as in the real intraoral scans (white/grey = gingiva, each
// saturated colour = a tooth pair): saturation max(r,g,b) - min(r,g,b) < 40 → kGingiva, otherwise
// kTooth. Fills face_labels and sets face_tooth_ids to 0 (unknown) for every face. Does nothing
// when the mesh has no face colours.
void LabelFacesFromColors(TriangleMesh* mesh);

// Writes binary_little_endian PLY: float x,y,z; float nx,ny,nz when vertex_normals are present;
// uchar red,green,blue,alpha when face_colors are; uchar label / tooth_id when face_labels /
// face_tooth_ids are. INVALID_ARGUMENT for a mesh that fails Check(), has no faces or a vertex or
// normal that is not a finite float; IO_ERROR when the file cannot be written.
[[nodiscard]] Status SavePlyBinary(const std::string& path, const TriangleMesh& mesh);
// The same content as SavePlyBinary in ascii PLY (floats printed with 9 significant digits, so
// they read back bit-exact as float).
[[nodiscard]] Status SavePlyAscii(const std::string& path, const TriangleMesh& mesh);
// Writes binary STL (80-byte header not starting with "solid", float32 little endian, facet
// normals from the faces). Only geometry is kept. Errors as SavePlyBinary.
[[nodiscard]] Status SaveStlBinary(const std::string& path, const TriangleMesh& mesh);

}  // namespace d3d
