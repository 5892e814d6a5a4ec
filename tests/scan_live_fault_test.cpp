// The live host when the probe goes away (issue 6's fault "the probe process killed mid-scan"):
// d3d-scan subscribes on DDS, a virtual probe (d3d-probe --sim, its own process) streams, and is
// killed with SIGKILL mid-scan. The host must keep the model, show "PROBE LOST" (the status line
// carries the preview's cue), save the model on request (SIGUSR1, the 's' key) while the probe is
// away, and go on scanning when a probe streams again (a restarted probe: burst_seq from 0); at the
// end (SIGINT) the report counts the return and the bursts of both sessions.
#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "tests/process_util.h"

namespace fs = std::filesystem;

namespace d3d {
namespace {

const std::string kBin = D3D_BIN_DIR;
constexpr int kDomain = 86;

// The status lines of d3d-scan's stderr (separated by '\r' or '\n').
std::vector<std::string> StatusLines(const std::string& log) {
  std::vector<std::string> out;
  std::string line;
  for (const char c : log) {
    if (c == '\r' || c == '\n') {
      if (line.rfind("d3d-scan:", 0) == 0) out.push_back(line);
      line.clear();
    } else {
      line += c;
    }
  }
  return out;
}

// The "processed N" count of a status line (-1 when it has none).
long long Processed(const std::string& line) {
  const size_t at = line.find("processed ");
  return at == std::string::npos ? -1 : std::atoll(line.c_str() + at + 10);
}

// The processed count of the last status line that has one (-1: none yet).
long long LastProcessed(const std::string& log) {
  long long n = -1;
  for (const std::string& l : StatusLines(log))
    if (const long long p = Processed(l); p >= 0) n = p;
  return n;
}

// The first status line that shows `cue` (empty: none).
std::string FirstWith(const std::string& log, const std::string& cue) {
  for (const std::string& l : StatusLines(log))
    if (l.find(cue) != std::string::npos) return l;
  return {};
}

// The vertex count in a PLY header (0 when unreadable).
long long PlyVertices(const fs::path& ply) {
  std::istringstream in(test::ReadFile(ply.string()));
  for (std::string line; std::getline(in, line) && line != "end_header";)
    if (line.rfind("element vertex ", 0) == 0) return std::atoll(line.c_str() + 15);
  return 0;
}

std::vector<std::string> ProbeArgs(const fs::path& manifest) {
  // 12 distinct bursts of the full-arch path, repeated, at 15 Hz: light enough to render beside the
  // host on 2 cores.
  return {kBin + "/d3d-probe",
          "--sim",
          "typodont",
          "--rate",
          "15",
          "--sim-cycle",
          "12",
          "--render-threads",
          "1",
          "--domain",
          std::to_string(kDomain),
          "--wait-subscribers",
          "1",
          "--manifest",
          manifest.string()};
}

TEST(ScanLive, AProbeKilledMidScanLeavesTheModelSavableAndTheScanResumesWhenItReturns) {
  const fs::path dir =
      fs::temp_directory_path() / ("d3d_scan_live_fault_" + std::to_string(getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const fs::path out = dir / "out";
  const test::Proc scan = test::Spawn(
      {kBin + "/d3d-scan", "--domain", std::to_string(kDomain), "--policy", "live", "--no-preview",
       "--out", out.string(), "--probe-timeout", "0.5", "--wait-probe", "120"},
      (dir / "scan.log").string());
  const auto scan_log = [&] { return test::ReadFile(scan.log); };

  // The first probe streams until the host has processed 20 bursts, then dies.
  const test::Proc probe1 = test::Spawn(ProbeArgs(dir / "m1.txt"), (dir / "probe1.log").string());
  const bool streamed = test::WaitUntil([&] { return LastProcessed(scan_log()) >= 20; }, 180);
  kill(probe1.pid, SIGKILL);
  EXPECT_EQ(test::Wait(probe1, 30), -1);
  ASSERT_TRUE(streamed) << scan_log() << test::ReadFile(probe1.log);

  // The host notices (0.5 s without a burst) and keeps what it has.
  ASSERT_TRUE(test::WaitUntil([&] { return !FirstWith(scan_log(), "PROBE LOST").empty(); }, 30))
      << scan_log();
  const long long processed_before = Processed(FirstWith(scan_log(), "PROBE LOST"));
  EXPECT_GE(processed_before, 20);

  // A save while the probe is away: the live model, to --out.
  kill(scan.pid, SIGUSR1);
  ASSERT_TRUE(test::WaitUntil(
      [&] { return scan_log().find("saved " + (out / "scan.ply").string()) != std::string::npos; },
      120))
      << scan_log();
  EXPECT_GT(PlyVertices(out / "scan.ply"), 1000);
  EXPECT_TRUE(fs::exists(out / "scan.stl"));

  // A probe streams again (a restart: burst_seq from 0), 30 bursts, and the scan goes on.
  std::vector<std::string> again = ProbeArgs(dir / "m2.txt");
  again.insert(again.end(), {"--frames", "30"});
  const test::Proc probe2 = test::Spawn(again, (dir / "probe2.log").string());
  EXPECT_EQ(test::Wait(probe2, 300), 0) << test::ReadFile(probe2.log);
  EXPECT_TRUE(test::WaitUntil([&] { return LastProcessed(scan_log()) > processed_before; }, 30))
      << scan_log();
  kill(scan.pid, SIGINT);  // the end of the scan: the model and the report
  ASSERT_EQ(test::Wait(scan, 600), 0) << scan_log();

  const nlohmann::json j = nlohmann::json::parse(test::ReadFile((out / "report.json").string()));
  EXPECT_EQ(j["probe_returns"], 1) << j.dump();
  EXPECT_EQ(j["bursts_malformed"], 0);
  EXPECT_GT(j["bursts_processed"].get<long long>(), processed_before + 5)
      << "the scan did not resume";
  EXPECT_GT(j["fused"].get<long long>(), processed_before / 2);
  EXPECT_GT(PlyVertices(out / "scan.ply"), 1000);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace d3d
