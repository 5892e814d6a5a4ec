// The head of a tool's scan report (pipeline/eval/report_json.h) filled with what this build is
// (build_info.h) and the time now; the caller adds the probe serial and the reference.
#pragma once

#include <ctime>

#include "pipeline/eval/report_json.h"
#include "tools/d3d/build_info.h"

namespace d3d {

inline ReportHead ToolReportHead(const char* tool) {
  ReportHead h;
  h.tool = tool;
  h.tool_version = BuildVersion();
  h.git_commit = BuildGitCommit();
  h.build_type = BuildType();
  h.created_unix_s = static_cast<int64_t>(std::time(nullptr));
  return h;
}

}  // namespace d3d
