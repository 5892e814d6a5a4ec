// The main job's host end to end on a short recording: bursts of the virtual probe are written to a
// recording (common/recording, as d3d-record does, with one malformed burst among them), then
// replayed through `d3d-scan --replay --headless` (the stage graph, lossless) twice: the report
// carries the fields of issues 5 and 6 with a sane trueness, the malformed burst is dropped and
// counted, the two runs give bit-identical meshes and poses, and the preview picture shows the
// model. The second run uses a real window under Xvfb when xvfb-run is installed.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "common/recording/recording.h"
#include "protocol/codec.h"
#include "protocol/protocol.h"
#include "sim/session/sim_session.h"

namespace fs = std::filesystem;

namespace d3d {
namespace {

const std::string kBin = D3D_BIN_DIR;
constexpr int64_t kFirst = 300, kCount = 16;

std::string ReadAll(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

// Writes kCount bursts of the full-arch scan path (seed 1) from burst kFirst, burst_seq = index,
// and one malformed burst (a frame too short) after the fifth.
void MakeRecording(const std::string& path) {
  SimSessionOptions so;
  std::unique_ptr<SimSession> session;
  ASSERT_TRUE(SimSession::Create(so, &session).ok());
  RecordingHeader h;
  h.protocol_version = proto::kProtocolVersion;
  h.probe_serial = "SIM-TEST";
  h.calibration_json = session->calibration().ToJson();
  h.channels = {{0, proto::kTopicPhaseBurst, proto::kSchemaBurst}};
  RecordingWriter w;
  ASSERT_TRUE(w.Open(path, h).ok());
  std::string bytes;
  int64_t log_ns = 1'700'000'000'000'000'000;
  for (int64_t i = kFirst; i < kFirst + kCount; ++i) {
    const Burst b = session->RenderBurst(i, false);
    proto::BurstMsg m;
    m.serial = "SIM-TEST";
    m.protocol_version = proto::kProtocolVersion;
    m.burst_seq = static_cast<uint64_t>(i);
    m.exposure_ns = 1'000'000;
    m.frame_interval_ns = 2'500'000;
    m.pattern_set = "phase4-marker";
    m.width = static_cast<uint32_t>(b.frames[0].image.cols);
    m.height = static_cast<uint32_t>(b.frames[0].image.rows);
    for (size_t k = 0; k < b.frames.size(); ++k) {
      proto::FrameMsg f;
      f.pattern = "phase4-marker/" + std::to_string(k);
      f.pattern_index = static_cast<uint16_t>(k);
      f.timestamp_ns = b.frames[k].timestamp_ns;
      f.camera_frame_seq = static_cast<uint64_t>(i * 4) + k;
      const cv::Mat img = b.frames[k].image.clone();
      f.pixels.assign(img.data, img.data + img.total());
      m.frames.push_back(std::move(f));
    }
    bytes.clear();
    proto::Encode(m, &bytes);
    ASSERT_TRUE(w.Add(0, log_ns += 33'333'333, bytes).ok());
    if (i == kFirst + 4) {  // a malformed sample: the receiver's checks must drop it
      m.burst_seq = 900000;
      m.frames[2].pixels.resize(100);
      bytes.clear();
      proto::Encode(m, &bytes);
      ASSERT_TRUE(w.Add(0, log_ns += 1'000'000, bytes).ok());
    }
  }
  ASSERT_TRUE(w.Close().ok());
}

bool HaveXvfbRun() { return std::system("command -v xvfb-run > /dev/null 2>&1") == 0; }

// A fresh folder `name` in the temp folder with the short recording in it; returns its path.
std::string FreshRecording(const std::string& name, fs::path* dir) {
  *dir = fs::temp_directory_path() / name;
  fs::remove_all(*dir);
  fs::create_directories(*dir);
  const std::string rec = (*dir / "short.d3drec").string();
  MakeRecording(rec);
  return rec;
}

TEST(ScanReplay, LosslessReplayThroughTheHostGivesTheReportAndAPicture) {
  fs::path dir;
  const std::string rec = FreshRecording("d3d_scan_replay_test", &dir);
  ASSERT_FALSE(HasFatalFailure());
  ASSERT_TRUE(fs::exists(rec));
  const std::string common =
      kBin + "/d3d-scan --replay " + rec +
      " --reference typodont --sim-trajectory full-arch --sim-seed 1 --quiet --json";
  const std::string run1 = common + " --headless --out " + (dir / "a").string() + " > " +
                           (dir / "a.json").string() + " 2> " + (dir / "a.err").string();
  ASSERT_EQ(std::system(run1.c_str()), 0) << ReadAll(dir / "a.err");
  const nlohmann::json j = nlohmann::json::parse(ReadAll(dir / "a" / "report.json"));
  for (const char* k : {"bursts", "fused", "rejected", "tracking_lost", "trueness_rms_um",
                        "trueness_mean_um", "trueness_p95_um", "coverage_pct", "ate_mm", "ate_deg",
                        "ms_per_burst", "bursts_received", "bursts_processed", "bursts_dropped",
                        "bursts_per_s", "latency_ms_p50", "latency_ms_p95", "peak_rss_mib"})
    EXPECT_TRUE(j.contains(k)) << k;
  EXPECT_EQ(j["policy"], "lossless");
  EXPECT_EQ(j["bursts_received"], kCount + 1);
  EXPECT_EQ(j["bursts_malformed"], 1);
  EXPECT_EQ(j["bursts_processed"], kCount);
  EXPECT_EQ(j["bursts_dropped"], 0);
  EXPECT_EQ(j["slow_down_cues"], 0)
      << "every burst kept: no reason to tell the dentist to slow down";
  EXPECT_EQ(j["bursts"], kCount);
  EXPECT_GE(j["fused"].get<int>(), kCount - 2);
  EXPECT_LT(j["trueness_rms_um"].get<double>(), 20.0);
  EXPECT_LT(j["ate_mm"].get<double>(), 0.1);
  EXPECT_GT(j["bursts_per_s"].get<double>(), 0.0);
  for (const auto& [name, s] : j["stages"].items()) EXPECT_EQ(s["order_violations"], 0) << name;
  // The memory timeline: one entry of each figure per RSS sample.
  ASSERT_TRUE(j.contains("memory_per_s") && j.contains("rss_mib_per_s"));
  for (const char* k :
       {"views", "model_samples", "model_mib", "undo_journal_mib", "keyframes", "keyframes_mib",
        "tsdf_mib", "views_kept_memory_mib", "preview_points", "heap_in_use_mib"})
    EXPECT_EQ(j["memory_per_s"][k].size(), j["rss_mib_per_s"].size()) << k;
  for (const char* f : {"scan.ply", "scan.stl", "poses.txt", "report.json"})
    EXPECT_TRUE(fs::exists(dir / "a" / f)) << f;
  // The kept frames went to an unnamed file in the --out folder: memory held their index only, and
  // the folder holds just the outputs.
  EXPECT_TRUE(j["views_spilled"].get<bool>());
  EXPECT_EQ(j["views_spill_failures"], 0);
  EXPECT_GT(j["views_kept_mib"].get<double>(), 0.5);
  EXPECT_LT(j["views_kept_memory_mib"].get<double>(), 0.01);
  for (const auto& e : fs::directory_iterator(dir / "a")) {
    const std::string name = e.path().filename().string();
    EXPECT_TRUE(name == "scan.ply" || name == "scan.stl" || name == "poses.txt" ||
                name == "report.json" || name == "preview.png" || name == "heatmap.png")
        << "left in --out: " << name;
  }

  // The second run: same bytes out (lossless is deterministic), in a window under Xvfb if possible,
  // with the kept frames in memory (the mesh does not depend on where they were kept).
  const bool xvfb = HaveXvfbRun();
  const std::string run2 = (xvfb ? "xvfb-run -a " + common : common + " --headless") +
                           " --spill-views memory --out " + (dir / "b").string() + " > " +
                           (dir / "b.json").string() + " 2> " + (dir / "b.err").string();
  ASSERT_EQ(std::system(run2.c_str()), 0) << ReadAll(dir / "b.err");
  EXPECT_EQ(ReadAll(dir / "a" / "scan.ply"), ReadAll(dir / "b" / "scan.ply"))
      << "lossless replay is not bit-identical";
  EXPECT_EQ(ReadAll(dir / "a" / "poses.txt"), ReadAll(dir / "b" / "poses.txt"));
  const nlohmann::json j2 = nlohmann::json::parse(ReadAll(dir / "b" / "report.json"));
  EXPECT_FALSE(j2["views_spilled"].get<bool>());
  EXPECT_GE(j2["views_kept_memory_mib"].get<double>(), j2["views_kept_mib"].get<double>());
  if (xvfb) {
    EXPECT_EQ(j2["preview"], "window") << ReadAll(dir / "b.err");
  }

  // The preview pictures show the model: many lit pixels in the middle of a dark background.
  for (const char* run : {"a", "b"}) {
    const cv::Mat png = cv::imread((dir / run / "preview.png").string(), cv::IMREAD_GRAYSCALE);
    if (png.empty()) {
      ADD_FAILURE() << run << ": no preview.png (" << ReadAll(dir / (std::string(run) + ".err"))
                    << ")";
      continue;
    }
    const cv::Mat middle = png(cv::Rect(png.cols / 4, png.rows / 4, png.cols / 2, png.rows / 2));
    const double lit =
        static_cast<double>(cv::countNonZero(middle > 90)) / static_cast<double>(middle.total());
    EXPECT_GT(lit, 0.03) << run << ": the preview looks empty";
  }
  fs::remove_all(dir);
}

// A damaged recording (issue 55): the header of its second chunk flipped, so that the 7 bursts in
// it (306..312) are lost. The replay still scans every intact burst and saves the scan, but warns
// on stderr naming the file and the loss, counts the 7 lost bursts in report.json and exits 3.
TEST(ScanReplay, ADamagedRecordingIsScannedWarnedAboutAndExitsThree) {
  fs::path dir;
  const std::string rec = FreshRecording("d3d_scan_replay_damaged_test", &dir);
  ASSERT_FALSE(HasFatalFailure());
  std::string bytes = ReadAll(rec);
  {
    std::unique_ptr<RecordingReader> r;
    ASSERT_TRUE(RecordingReader::Open(MemorySource(bytes), &r).ok());
    ASSERT_EQ(r->chunks().size(), 3u)
        << "7 messages a chunk at 8 MiB (6 bursts and the malformed one, 7 bursts, 3 bursts)";
    EXPECT_EQ(r->chunks()[1].message_count, 7u);
    bytes[r->chunks()[1].offset + 5] ^= 0x20;
  }
  const fs::path damaged = dir / "damaged.d3drec";
  std::ofstream(damaged, std::ios::binary) << bytes;
  const std::string run = kBin + "/d3d-scan --replay " + damaged.string() +
                          " --quiet --no-preview --out " + (dir / "d").string() + " > " +
                          (dir / "d.out").string() + " 2> " + (dir / "d.err").string();
  const int status = std::system(run.c_str());
  const std::string err = ReadAll(dir / "d.err");
  ASSERT_TRUE(WIFEXITED(status)) << err;
  EXPECT_EQ(WEXITSTATUS(status), 3) << err;
  EXPECT_NE(err.find("warning: " + damaged.string() + " is damaged"), std::string::npos) << err;
  EXPECT_NE(err.find("bursts lost: 7 "), std::string::npos) << err;
  for (const char* f : {"scan.ply", "scan.stl", "poses.txt", "report.json"})
    EXPECT_TRUE(fs::exists(dir / "d" / f)) << f;
  const nlohmann::json j = nlohmann::json::parse(ReadAll(dir / "d" / "report.json"));
  EXPECT_EQ(j["bursts_lost_in_recording"], 7);
  EXPECT_EQ(j["bursts_lost_in_recording_max"], 7);
  EXPECT_EQ(j["bursts_missing_upstream"], 0)
      << "the jump lies across the lost chunk, not in intact data";
  EXPECT_EQ(j["recording_damaged"], true);
  EXPECT_EQ(j["recording_lost"], "1 chunk, 7 messages");
  EXPECT_EQ(j["bursts_received"], kCount + 1 - 7);
  fs::remove_all(dir);
}

// "Undo last seconds" from the command line (--undo-after: the 'u' key pressed right after the
// 12th burst): the views of the last 0.1 s leave the scan and the report says so.
TEST(ScanReplay, AScriptedUndoTakesTheLastViewsOut) {
  fs::path dir;
  const std::string rec = FreshRecording("d3d_scan_replay_undo_test", &dir);
  ASSERT_FALSE(HasFatalFailure());
  const std::string run = kBin + "/d3d-scan --replay " + rec +
                          " --reference typodont --sim-trajectory full-arch --sim-seed 1 --quiet "
                          "--no-preview --undo-after 12 --undo-seconds 0.1 --out " +
                          (dir / "u").string() + " > " + (dir / "u.out").string() + " 2> " +
                          (dir / "u.err").string();
  ASSERT_EQ(std::system(run.c_str()), 0) << ReadAll(dir / "u.err");
  const nlohmann::json j = nlohmann::json::parse(ReadAll(dir / "u" / "report.json"));
  EXPECT_EQ(j["bursts_processed"], kCount);  // the undo request is not a burst
  EXPECT_EQ(j["undo_requests"], 1);
  EXPECT_EQ(j["undos_applied"], 1);
  EXPECT_GE(j["views_undone"].get<int>(), 3);  // 100 ms of bursts 33.3 ms apart
  EXPECT_LE(j["views_undone"].get<int>(), 4);
  EXPECT_TRUE(j["fused_again_at_optimised_poses"].get<bool>());
  EXPECT_EQ(j["views_kept"], j["fused"].get<int>() - j["views_undone"].get<int>());
  EXPECT_LT(j["trueness_rms_um"].get<double>(), 20.0);
  bool logged = false;
  for (const auto& e : j["events"]) logged |= e["state"] == "undo";
  EXPECT_TRUE(logged) << j["events"].dump();
  fs::remove_all(dir);
}

// --replay-views: a live run's views again, losslessly. Here the "live run" is every other view of
// a full replay: only the bursts whose capture times its poses.txt lists go through, the others are
// skipped (not received, not dropped), and the run uses the live tracker's gates (--step 6).
TEST(ScanReplay, ReplayViewsTakesOnlyTheListedBursts) {
  fs::path dir;
  const std::string rec = FreshRecording("d3d_scan_replay_views_test", &dir);
  ASSERT_FALSE(HasFatalFailure());
  const std::string common = kBin + "/d3d-scan --replay " + rec + " --quiet --no-preview";
  const std::string full = common + " --out " + (dir / "a").string() + " > " +
                           (dir / "a.out").string() + " 2> " + (dir / "a.err").string();
  ASSERT_EQ(std::system(full.c_str()), 0) << ReadAll(dir / "a.err");
  std::vector<std::string>
      stamps;  // the timestamps of every other pose, as the TUM file gives them
  {
    std::ifstream in(dir / "a" / "poses.txt");
    std::ofstream out(dir / "views.txt");
    int k = 0;
    for (std::string line; std::getline(in, line);) {
      if (line.empty() || line[0] == '#') continue;
      if (k++ % 2 != 0) continue;
      out << line << "\n";
      stamps.push_back(line.substr(0, line.find(' ')));
    }
  }
  ASSERT_EQ(stamps.size(), static_cast<size_t>(kCount / 2));
  const std::string views = common + " --replay-views " + (dir / "views.txt").string() + " --out " +
                            (dir / "b").string() + " > " + (dir / "b.out").string() + " 2> " +
                            (dir / "b.err").string();
  ASSERT_EQ(std::system(views.c_str()), 0) << ReadAll(dir / "b.err");
  const nlohmann::json j = nlohmann::json::parse(ReadAll(dir / "b" / "report.json"));
  EXPECT_EQ(j["bursts_processed"], kCount / 2);
  EXPECT_EQ(j["bursts_skipped"], kCount / 2);
  EXPECT_EQ(j["bursts_received"],
            kCount / 2 + 1);  // and the malformed one, which is never selected
  EXPECT_EQ(j["bursts_dropped"], 0);
  EXPECT_EQ(j["step"], 6.0);
  std::vector<std::string> got;
  std::ifstream in(dir / "b" / "poses.txt");
  for (std::string line; std::getline(in, line);)
    if (!line.empty() && line[0] != '#') got.push_back(line.substr(0, line.find(' ')));
  EXPECT_EQ(got, stamps);
  // A file that is no trajectory is refused before anything runs.
  std::ofstream(dir / "bad.txt") << "not a pose\n";
  const std::string bad = common + " --replay-views " + (dir / "bad.txt").string() + " --out " +
                          (dir / "c").string() + " 2> " + (dir / "c.err").string();
  EXPECT_NE(std::system(bad.c_str()), 0);
  EXPECT_NE(ReadAll(dir / "c.err").find("--replay-views"), std::string::npos)
      << ReadAll(dir / "c.err");
  fs::remove_all(dir);
}

}  // namespace
}  // namespace d3d
