// One fuzzing step for the mesh loaders, shared by the libFuzzer target d3d_mesh_fuzz and the
// deterministic mutation test in mesh_io_test.cpp.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

namespace d3d {

struct FuzzLoadOutcome {
  int loaded = 0;   // parses that succeeded (each passed TriangleMesh::Check)
  int refused = 0;  // parses that returned a non-ok Status
  std::string
      violation;  // empty, or what broke the loaders' contract (an exception, a bad mesh, INTERNAL)
};

// Feeds `data` to LoadMeshFromMemory with auto-detection and with each format forced (PLY, STL,
// OBJ). A successful load must give a mesh with faces, finite vertices and Check() passing; a
// failure must be a Status other than INTERNAL (which signals an exception caught inside).
// Never throws.
FuzzLoadOutcome FuzzLoadMeshOnce(const uint8_t* data, size_t size);

}  // namespace d3d
