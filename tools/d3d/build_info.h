// What build a tool is: the project version, the git commit it was built from (with "-modified"
// for a tree with uncommitted changes) and the build type. One translation unit reads the
// generated header (cmake/version.cmake), so a new commit recompiles it alone and relinks the
// tools that name themselves (d3d --version, the scan reports' head).
#pragma once

namespace d3d {

const char* BuildVersion();    // e.g. "0.9.0"
const char* BuildGitCommit();  // e.g. "bed566d1a2b3", "bed566d1a2b3-modified", "unknown"
const char* BuildType();       // e.g. "Release"

}  // namespace d3d
