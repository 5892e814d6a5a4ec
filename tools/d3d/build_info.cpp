#include "tools/d3d/build_info.h"

#include "d3d_version.h"

namespace d3d {

const char* BuildVersion() { return D3D_VERSION; }
const char* BuildGitCommit() { return D3D_GIT_HASH; }
const char* BuildType() { return D3D_BUILD_TYPE; }

}  // namespace d3d
