#include "pipeline/eval/report_json.h"

#include <gtest/gtest.h>

namespace d3d {
namespace {

// The head says what the file is and what made it; what is not known is null, not "".
TEST(ReportJson, TheHeadNamesTheSchemaTheToolTheTimeAndTheReference) {
  ReportHead h;
  h.tool = "d3d-fuse";
  h.tool_version = "1.2.3";
  h.git_commit = "0123456789ab-modified";
  h.build_type = "Release";
  h.created_unix_s = 1'795'824'000;  // 2026-11-28 00:00:00 UTC
  nlohmann::json j;
  AddReportHead(h, &j);
  EXPECT_EQ(j["schema"], "d3dscan.scan_report");
  EXPECT_EQ(j["schema_version"], kScanReportSchemaVersion);
  EXPECT_EQ(j["tool"], "d3d-fuse");
  EXPECT_EQ(j["tool_version"], "1.2.3");
  EXPECT_EQ(j["git_commit"], "0123456789ab-modified");
  EXPECT_EQ(j["build_type"], "Release");
  EXPECT_EQ(j["created_utc"], "2026-11-28T00:00:00Z");
  EXPECT_TRUE(j["probe_serial"].is_null());
  EXPECT_TRUE(j["reference"].is_null());
  h.probe_serial = "SIM-0001";
  h.reference = "arch.ply";
  AddReportHead(h, &j);
  EXPECT_EQ(j["probe_serial"], "SIM-0001");
  EXPECT_EQ(j["reference"], "arch.ply");
}

}  // namespace
}  // namespace d3d
