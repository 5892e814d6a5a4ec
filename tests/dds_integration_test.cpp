// End to end over DDS with separate processes on loopback (the shipped Cyclone config):
//   d3d-probe (sim) → d3d-record → recording → d3d-replay → this test's subscriber (host/receiver),
// with byte-for-byte checks; a late-joining host gets ProbeInfo and the calibration; damaged
// recordings give clear errors and every intact chunk back. Each test uses its own DDS domain.
#include <gtest/gtest.h>
#include <zlib.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <thread>

#include "common/recording/recording.h"
#include "host/receiver/receiver.h"
#include "protocol/codec.h"
#include "protocol/protocol.h"
#include "sim/render/probe_design.h"
#include "tests/process_util.h"

namespace d3d {
namespace {

namespace fs = std::filesystem;
const std::string kBin = D3D_BIN_DIR;

using test::Proc;
using test::ReadFile;
using test::Spawn;
using test::Wait;

fs::path TestDir(const std::string& name) {
  const fs::path d =
      fs::temp_directory_path() / ("d3d_dds_it_" + name + "_" + std::to_string(getpid()));
  fs::create_directories(d);
  return d;
}

// Probe and recorder as two processes; returns the recording path.
fs::path ProbeToRecording(const fs::path& dir, int domain, int frames, double rate) {
  const fs::path rec = dir / "probe.d3drec";
  const Proc recorder = Spawn({kBin + "/d3d-record", "--out", rec.string(), "--frames",
                               std::to_string(frames), "--domain", std::to_string(domain)},
                              (dir / "record.log").string());
  const Proc probe =
      Spawn({kBin + "/d3d-probe", "--sim", "typodont", "--rate", std::to_string(rate), "--frames",
             std::to_string(frames), "--domain", std::to_string(domain), "--wait-subscribers", "1",
             "--sim-cycle", "8", "--manifest", (dir / "manifest.txt").string()},
            (dir / "probe.log").string());
  EXPECT_EQ(Wait(probe, 180), 0) << ReadFile(probe.log);
  EXPECT_EQ(Wait(recorder, 60), 0) << ReadFile(recorder.log);
  return rec;
}

// Bursts of a recording, in file order, with their encoded bytes.
std::vector<std::pair<proto::BurstMsg, std::string>> RecordedBursts(RecordingReader* r) {
  std::vector<std::pair<proto::BurstMsg, std::string>> out;
  const uint16_t ch = r->header().FindTopic(proto::kTopicPhaseBurst)->id;
  r->ForEach([&](const RecordedMessage& m) {
    if (m.channel != ch) return true;
    proto::BurstMsg b;
    EXPECT_TRUE(proto::Decode(m.data, &b).ok());
    out.emplace_back(std::move(b), m.data);
    return true;
  });
  return out;
}

// Replays `rec` on `domain` into an in-process receiver; returns the bursts received.
std::vector<proto::BurstMsg> ReplayInto(const fs::path& rec, int domain, size_t expect,
                                        const fs::path& dir, int* exit_code) {
  proto::DdsParticipant pp;
  EXPECT_TRUE(pp.Create({domain, proto::SelectCycloneConfig(nullptr, 0, 0, nullptr)}).ok());
  ReceiverOptions o;
  o.queue_capacity = 1024;
  BurstReceiver rx(o);
  EXPECT_TRUE(rx.Start(&pp).ok());
  const Proc replay = Spawn(
      {kBin + "/d3d-replay", rec.string(), "--rate", "max", "--domain", std::to_string(domain)},
      (dir / "replay.log").string());
  std::vector<proto::BurstMsg> got;
  ReceivedSample r;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(120);
  while (got.size() < expect && std::chrono::steady_clock::now() < deadline) {
    if (!rx.Pop(&r, 200'000'000)) continue;
    if (auto* b = std::get_if<proto::BurstMsg>(&r.msg)) got.push_back(std::move(*b));
  }
  *exit_code = Wait(replay, 60);
  EXPECT_EQ(rx.counters().dropped_total(), 0u);
  return got;
}

std::vector<std::string> Lines(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string l; std::getline(in, l);) out.push_back(l);
  return out;
}

// The acceptance run: 300 bursts at 30 Hz, probe and recorder as separate processes, then
// the recording replayed into a subscriber: 300/300 both ways, identical bytes.
TEST(DdsIntegration, Probe300ToRecordToReplayByteIdentical) {
  const fs::path dir = TestDir("300");
  const fs::path rec = ProbeToRecording(dir, 71, 300, 30);
  std::unique_ptr<RecordingReader> reader;
  ASSERT_TRUE(RecordingReader::OpenFile(rec.string(), &reader).ok());
  EXPECT_TRUE(reader->diagnostics().index_used);
  EXPECT_FALSE(reader->header().calibration_json.empty());
  const auto recorded = RecordedBursts(reader.get());
  ASSERT_EQ(recorded.size(), 300u) << "recorded of 300";
  // The probe's manifest: the CRC of every frame it published. The recording holds those bytes.
  const auto manifest = Lines(ReadFile((dir / "manifest.txt").string()));
  ASSERT_EQ(manifest.size(), 300u);
  for (size_t i = 0; i < recorded.size(); ++i) {
    const proto::BurstMsg& b = recorded[i].first;
    ASSERT_EQ(b.burst_seq, i);
    std::ostringstream line;
    line << b.burst_seq;
    for (const auto& f : b.frames) {
      char hex[16];
      std::snprintf(hex, sizeof hex, " %08lx",
                    crc32(0L, f.pixels.data(), static_cast<uInt>(f.pixels.size())));
      line << hex;
    }
    EXPECT_EQ(line.str(), manifest[i]) << "burst " << i << " differs from what the probe published";
  }
  int replay_exit = -1;
  const auto replayed = ReplayInto(rec, 72, 300, dir, &replay_exit);
  EXPECT_EQ(replay_exit, 0);
  ASSERT_EQ(replayed.size(), 300u) << "replayed of 300";
  for (size_t i = 0; i < replayed.size(); ++i) {
    std::string bytes;
    proto::Encode(replayed[i], &bytes);
    EXPECT_TRUE(bytes == recorded[i].second)
        << "replayed burst " << i << " differs from the recording";
  }
  fs::remove_all(dir);
}

// A host that joins after the probe published ProbeInfo still receives it, with the calibration.
TEST(DdsIntegration, LateJoinerReceivesProbeInfoAndCalibration) {
  const fs::path dir = TestDir("late");
  constexpr int kDomain = 73;
  const Proc probe =
      Spawn({kBin + "/d3d-probe", "--sim", "typodont", "--rate", "30", "--frames", "15", "--domain",
             std::to_string(kDomain), "--wait-subscribers", "1", "--sim-cycle", "2"},
            (dir / "probe.log").string());
  proto::DdsParticipant pp;
  ASSERT_TRUE(pp.Create({kDomain, proto::SelectCycloneConfig(nullptr, 0, 0, nullptr)}).ok());
  {
    // Wait for the probe's first ProbeStatus: ProbeInfo was published before it.
    Status st;
    const dds_entity_t t = pp.Topic(&d3d_proto_ProbeStatus_desc, proto::kTopicProbeStatus, &st);
    std::unique_ptr<dds_qos_t, proto::QosDeleter> q(
        proto::MakeQos(proto::QosProfile::kStatusReader));
    const dds_entity_t r = dds_create_reader(pp.participant(), t, q.get(), nullptr);
    bool seen = false;
    for (int i = 0; i < 1200 && !seen; ++i) {
      void* s[1] = {};
      dds_sample_info_t info;
      if (dds_take(r, s, &info, 1, 1) == 1) {
        seen = true;
        dds_return_loan(r, s, 1);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    ASSERT_TRUE(seen) << ReadFile((dir / "probe.log").string());
    dds_delete(r);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  BurstReceiver late(ReceiverOptions{});  // joins now
  ASSERT_TRUE(late.Start(&pp).ok());
  proto::InfoMsg info;
  ProbeCalibration cal;
  bool got = false;
  for (int i = 0; i < 200 && !(got = late.LatestInfo(&info, &cal)); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  ASSERT_TRUE(got) << "no ProbeInfo for the late joiner";
  EXPECT_EQ(info.serial, "SIM-0001");
  EXPECT_EQ(info.capture_backend, "sim");
  EXPECT_FALSE(info.firmware_version.empty());
  EXPECT_EQ(cal.ToJson(), MakeDefaultProbeDesign(640, 480).calibration.ToJson())
      << "the probe's own calibration";
  EXPECT_EQ(Wait(probe, 120), 0);  // it streamed to the late joiner and exited
  fs::remove_all(dir);
}

// Damaged recordings: clear errors, and every intact chunk is recovered (by d3d-replay --info and
// by a replay into a subscriber).
TEST(DdsIntegration, CorruptedAndTruncatedRecordingsRecoverIntactChunks) {
  const fs::path dir = TestDir("corrupt");
  const fs::path rec = ProbeToRecording(dir, 74, 24, 30);
  const std::string good = ReadFile(rec.string());
  std::unique_ptr<RecordingReader> clean;
  ASSERT_TRUE(RecordingReader::Open(MemorySource(good), &clean).ok());
  ASSERT_GE(clean->chunks().size(), 3u);
  const auto chunks = clean->chunks();
  auto write = [&](const std::string& name, const std::string& bytes) {
    const fs::path p = dir / name;
    std::ofstream(p, std::ios::binary) << bytes;
    return p;
  };
  auto info = [&](const fs::path& p, std::string* out) {
    const Proc pr =
        Spawn({kBin + "/d3d-replay", "--info", p.string()}, (dir / "info.log").string());
    const int code = Wait(pr, 30);
    *out = ReadFile((dir / "info.log").string());
    return code;
  };
  auto bursts_in = [&](const std::string& bytes) {
    std::unique_ptr<RecordingReader> r;
    EXPECT_TRUE(RecordingReader::Open(MemorySource(bytes), &r).ok());
    return RecordedBursts(r.get()).size();
  };
  const size_t all = bursts_in(good);
  EXPECT_EQ(all, 24u);
  std::string out;
  EXPECT_EQ(info(rec, &out), 0) << out;

  // Bit flip inside the middle chunk's data: that chunk is lost, all others read.
  std::string flipped = good;
  const ChunkInfo& mid = chunks[chunks.size() / 2];
  flipped[mid.offset + 40 + mid.compressed_size / 2] ^= 0x10;
  EXPECT_EQ(info(write("flipped.d3drec", flipped), &out), 3) << out;
  EXPECT_NE(out.find("CRC mismatch"), std::string::npos) << out;
  std::unique_ptr<RecordingReader> r;
  ASSERT_TRUE(RecordingReader::Open(MemorySource(flipped), &r).ok());
  std::vector<RecordedMessage> msgs;
  size_t expect_flipped = 0;
  for (size_t i = 0; i < chunks.size(); ++i) {
    if (i == chunks.size() / 2) continue;
    ASSERT_TRUE(clean->ReadChunk(i, &msgs).ok());
    for (const auto& m : msgs) expect_flipped += m.channel == 0;
  }
  EXPECT_EQ(bursts_in(flipped), expect_flipped);

  // Cut-off tail (mid-way through the last chunk): every complete chunk is read.
  const ChunkInfo& last = chunks.back();
  const std::string cut = good.substr(0, last.offset + 40 + last.compressed_size / 2);
  EXPECT_EQ(info(write("cut.d3drec", cut), &out), 3) << out;
  EXPECT_NE(out.find("not closed"), std::string::npos) << out;
  ASSERT_TRUE(clean->ReadChunk(chunks.size() - 1, &msgs).ok());
  size_t in_last = 0;
  for (const auto& m : msgs) in_last += m.channel == 0;
  EXPECT_EQ(bursts_in(cut), all - in_last);
  // ... and replaying it delivers exactly those bursts.
  int replay_exit = -1;
  const auto replayed = ReplayInto(write("cut2.d3drec", cut), 75, all - in_last, dir, &replay_exit);
  EXPECT_EQ(replayed.size(), all - in_last);
  EXPECT_EQ(replay_exit, 3) << "replayed with losses";

  // Wrong magic and a newer format: clear errors, exit 2.
  std::string bad = good;
  bad[2] = 'X';
  EXPECT_EQ(info(write("magic.d3drec", bad), &out), 2);
  EXPECT_NE(out.find("not a d3d recording"), std::string::npos) << out;
  bad = good;
  bad[8] = 9;  // as a newer writer leaves it: the header's CRC over the new version
  uint32_t json_len = 0;
  std::memcpy(&json_len, bad.data() + 12, 4);
  const uint32_t crc =
      static_cast<uint32_t>(crc32(0L, reinterpret_cast<const Bytef*>(bad.data()), 16 + json_len));
  std::memcpy(bad.data() + 16 + json_len, &crc, 4);
  EXPECT_EQ(info(write("newer.d3drec", bad), &out), 2);
  EXPECT_NE(out.find("newer than this reader"), std::string::npos) << out;
  bad[8] = 8;  // the same with its CRC failing: a damaged header, not a newer format
  EXPECT_EQ(info(write("damaged_header.d3drec", bad), &out), 2);
  EXPECT_EQ(out.find("newer"), std::string::npos) << out;
  EXPECT_NE(out.find("header damaged"), std::string::npos) << out;
  fs::remove_all(dir);
}

}  // namespace
}  // namespace d3d
