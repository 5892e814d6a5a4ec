// libFuzzer entry point for the mesh loaders, and the step it shares with the mutation test.
#include "common/mesh/mesh_io_fuzz.h"

#include <cstdio>
#include <cstdlib>
#include <exception>

#include "common/mesh/mesh_io.h"

namespace d3d {
namespace {

// Empty when the outcome of one load respects the loader's contract, else what is wrong.
std::string CheckOneLoad(const Status& status, const TriangleMesh& mesh, MeshFormat format) {
  const std::string where = std::string(" (format ") + MeshFormatName(format) + ")";
  if (!status.ok()) {
    if (status.code() == StatusCode::kInternal)
      return "INTERNAL status: " + status.message() + where;
    if (status.message().empty()) return "error status without a message" + where;
    return {};
  }
  if (mesh.faces.empty()) return "ok status but no faces" + where;
  for (const Eigen::Vector3d& v : mesh.vertices) {
    if (!v.allFinite()) return "ok status but a non-finite vertex" + where;
  }
  try {
    mesh.Check();
  } catch (const std::exception& e) {
    return std::string("ok status but Check() fails: ") + e.what() + where;
  }
  return {};
}

}  // namespace

FuzzLoadOutcome FuzzLoadMeshOnce(const uint8_t* data, size_t size) {
  FuzzLoadOutcome outcome;
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  for (MeshFormat format :
       {MeshFormat::kAuto, MeshFormat::kPly, MeshFormat::kStl, MeshFormat::kObj}) {
    TriangleMesh mesh;
    std::string problem;
    try {
      const Status status = LoadMeshFromMemory(bytes, format, &mesh);
      problem = CheckOneLoad(status, mesh, format);
      ++(status.ok() ? outcome.loaded : outcome.refused);
    } catch (const std::exception& e) {
      problem = std::string("exception escaped the loader: ") + e.what();
    } catch (...) {
      problem = "non-standard exception escaped the loader";
    }
    if (!problem.empty() && outcome.violation.empty()) outcome.violation = problem;
  }
  return outcome;
}

}  // namespace d3d

// libFuzzer: any contract violation aborts, so the fuzzer saves the input as a crash.
extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const d3d::FuzzLoadOutcome outcome = d3d::FuzzLoadMeshOnce(data, size);
  if (!outcome.violation.empty()) {
    std::fprintf(stderr, "mesh loader contract violated: %s\n", outcome.violation.c_str());
    std::abort();
  }
  return 0;
}
