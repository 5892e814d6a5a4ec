#include "common/recording/recording.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <cstring>
#include <random>

namespace d3d {
namespace {

namespace fs = std::filesystem;

RecordingHeader TestHeader() {
  RecordingHeader h;
  h.protocol_version = 101;
  h.created_ns = 1'700'000'000'000'000'000;
  h.probe_serial = "SIM-0001";
  h.calibration_json = "{\"format\": \"d3dscan.calibration\"}";
  h.channels = {{0, "d3d/PhaseBurst", "burst/test"}, {1, "d3d/ProbeStatus", "status/test"}};
  h.metadata["tool"] = "recording_test";
  return h;
}

// Message k: channel k % 2, time 1e9 + k·33 ms, `size` seeded pseudo-random bytes (k in the first 4).
std::string Payload(int k, size_t size) {
  std::mt19937 rng(static_cast<uint32_t>(k) * 7919u + 1u);
  std::string s(size, '\0');
  for (auto& c : s) c = static_cast<char>(rng() & 0x3f);  // compressible but not trivially
  std::memcpy(s.data(), &k, sizeof k);
  return s;
}

std::string ReadAll(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(f)), {});
}

fs::path WriteTestRecording(const std::string& name, int n, size_t size, bool close = true) {
  const fs::path p = fs::temp_directory_path() / name;
  RecordingWriter w;
  RecordingWriterOptions o;
  o.chunk_bytes = 3 * size;  // a chunk every ~3 messages
  EXPECT_TRUE(w.Open(p.string(), TestHeader(), o).ok());
  for (int k = 0; k < n; ++k) EXPECT_TRUE(w.Add(static_cast<uint16_t>(k % 2), 1'000'000'000 + k * 33'000'000LL, Payload(k, size)).ok());
  if (close) {
    EXPECT_TRUE(w.Close().ok());
  } else {
    EXPECT_TRUE(w.Flush().ok());
    const std::string bytes = ReadAll(p);  // what a killed recorder leaves: chunks, no index/footer
    EXPECT_TRUE(w.Close().ok());
    std::ofstream(p, std::ios::binary | std::ios::trunc) << bytes;
  }
  return p;
}

// Message indices k recovered from a reader (payload carries k).
std::vector<int> Recovered(RecordingReader* r, size_t size) {
  std::vector<int> ks;
  r->ForEach([&](const RecordedMessage& m) {
    int k = -1;
    std::memcpy(&k, m.data.data(), sizeof k);
    EXPECT_EQ(m.data, Payload(k, size));
    EXPECT_EQ(m.channel, k % 2);
    EXPECT_EQ(m.log_time_ns, 1'000'000'000 + k * 33'000'000LL);
    ks.push_back(k);
    return true;
  });
  return ks;
}

std::unique_ptr<RecordingReader> OpenBytes(std::string bytes, Status* s) {
  std::unique_ptr<RecordingReader> r;
  *s = RecordingReader::Open(MemorySource(std::move(bytes)), &r);
  return r;
}

TEST(Recording, RoundTripUsesIndex) {
  const auto p = WriteTestRecording("d3d_rec_roundtrip.d3drec", 20, 5000);
  std::unique_ptr<RecordingReader> r;
  ASSERT_TRUE(RecordingReader::OpenFile(p.string(), &r).ok());
  EXPECT_TRUE(r->diagnostics().index_used);
  EXPECT_TRUE(r->diagnostics().problems.empty());
  EXPECT_EQ(r->header().probe_serial, "SIM-0001");
  EXPECT_EQ(r->header().calibration_json, TestHeader().calibration_json);
  ASSERT_EQ(r->header().channels.size(), 2u);
  EXPECT_EQ(r->header().FindTopic("d3d/ProbeStatus")->id, 1);
  EXPECT_EQ(r->header().metadata.at("tool"), "recording_test");
  EXPECT_GE(r->chunks().size(), 6u);
  std::vector<int> expect(20);
  for (int k = 0; k < 20; ++k) expect[k] = k;
  EXPECT_EQ(Recovered(r.get(), 5000), expect);
}

TEST(Recording, KilledWriterLeavesEveryCompleteChunk) {
  const auto closed = ReadAll(WriteTestRecording("d3d_rec_full.d3drec", 20, 5000));
  std::unique_ptr<RecordingReader> full;
  Status s;
  full = OpenBytes(closed, &s);
  ASSERT_TRUE(s.ok());
  const auto chunks = full->chunks();
  // Cut the file at every byte of the chunk area: all chunks that end before the cut are read.
  const size_t data_start = chunks.front().offset;
  for (size_t cut = data_start; cut <= closed.size(); cut += 97) {
    auto r = OpenBytes(closed.substr(0, cut), &s);
    ASSERT_TRUE(s.ok()) << cut << " " << s.ToString();
    size_t complete = 0, expect_msgs = 0;
    for (const auto& c : chunks)
      if (c.offset + 40 + c.compressed_size <= cut) {
        ++complete;
        expect_msgs += c.message_count;
      }
    EXPECT_EQ(r->chunks().size(), complete) << cut;
    EXPECT_EQ(Recovered(r.get(), 5000).size(), expect_msgs) << cut;
    if (cut < closed.size()) {
      EXPECT_FALSE(r->diagnostics().index_used);
    }
  }
  // A writer that never closed (no index, no footer).
  const auto p = WriteTestRecording("d3d_rec_killed.d3drec", 20, 5000, /*close=*/false);
  std::unique_ptr<RecordingReader> r;
  ASSERT_TRUE(RecordingReader::OpenFile(p.string(), &r).ok());
  EXPECT_FALSE(r->diagnostics().index_used);
  EXPECT_EQ(Recovered(r.get(), 5000).size(), 20u);
}

TEST(Recording, BitFlipsLoseOnlyTheDamagedChunk) {
  const auto closed = ReadAll(WriteTestRecording("d3d_rec_flip.d3drec", 30, 5000));
  Status s;
  auto clean = OpenBytes(closed, &s);
  ASSERT_TRUE(s.ok());
  const auto chunks = clean->chunks();
  std::mt19937 rng(4242);
  for (int trial = 0; trial < 200; ++trial) {
    std::string b = closed;
    const size_t pos = chunks.front().offset + rng() % (b.size() - chunks.front().offset);
    b[pos] = static_cast<char>(b[pos] ^ (1 << (rng() % 8)));
    auto r = OpenBytes(b, &s);
    ASSERT_TRUE(s.ok()) << pos;
    // Messages of every chunk that does not contain the flipped byte are recovered.
    size_t expect = 0;
    for (const auto& c : chunks)
      if (pos < c.offset || pos >= c.offset + 40 + c.compressed_size) expect += c.message_count;
    const size_t got = Recovered(r.get(), 5000).size();
    EXPECT_GE(got, expect) << "flip at " << pos;
    if (got < 30) {
      EXPECT_FALSE(r->diagnostics().problems.empty()) << "loss must be reported, flip at " << pos;
    }
  }
}

TEST(Recording, WrongMagicNewerVersionDamagedHeader) {
  const auto closed = ReadAll(WriteTestRecording("d3d_rec_hdr.d3drec", 4, 100));
  Status s;
  std::string b = closed;
  b[1] = 'X';
  OpenBytes(b, &s);
  EXPECT_EQ(s.code(), StatusCode::kParseError);
  EXPECT_NE(s.message().find("wrong magic"), std::string::npos);
  b = closed;
  b[8] = 2;  // major 2
  OpenBytes(b, &s);
  EXPECT_EQ(s.code(), StatusCode::kUnsupported);
  EXPECT_NE(s.message().find("newer"), std::string::npos);
  b = closed;
  b[20] = static_cast<char>(b[20] ^ 1);  // inside the JSON
  OpenBytes(b, &s);
  EXPECT_EQ(s.code(), StatusCode::kCorrupt);
  OpenBytes(closed.substr(0, 10), &s);
  EXPECT_EQ(s.code(), StatusCode::kParseError);
  OpenBytes("", &s);
  EXPECT_EQ(s.code(), StatusCode::kParseError);
  std::unique_ptr<RecordingReader> r;
  EXPECT_EQ(RecordingReader::OpenFile("/nonexistent/x.d3drec", &r).code(), StatusCode::kNotFound);
}

TEST(Recording, RejectsUndeclaredChannel) {
  RecordingWriter w;
  ASSERT_TRUE(w.Open((fs::temp_directory_path() / "d3d_rec_ch.d3drec").string(), TestHeader()).ok());
  EXPECT_EQ(w.Add(7, 0, "x").code(), StatusCode::kInvalidArgument);
  EXPECT_TRUE(w.Close().ok());
}

// Format 1.0 stays readable: a file written by the first version of the writer is committed in
// testdata/ (regenerate only for a new format version, never for 1.0).
TEST(Recording, GoldenFileReads) {
  const fs::path golden = fs::path(D3D_RECORDING_TESTDATA) / "golden_v1_0.d3drec";
  const auto fresh = WriteTestRecording("d3d_rec_golden.d3drec", 7, 300);
  std::unique_ptr<RecordingReader> r;
  ASSERT_TRUE(RecordingReader::OpenFile(golden.string(), &r).ok()) << golden;
  EXPECT_TRUE(r->diagnostics().index_used);
  EXPECT_EQ(r->header().format_major, 1);
  EXPECT_EQ(r->header().format_minor, 0);
  EXPECT_EQ(r->header().probe_serial, "SIM-0001");
  std::vector<int> expect(7);
  for (int k = 0; k < 7; ++k) expect[k] = k;
  EXPECT_EQ(Recovered(r.get(), 300), expect);
  // The current writer produces the same bytes from the same input (zstd level 1 of Debian 12's zstd).
  EXPECT_EQ(ReadAll(fresh), ReadAll(golden)) << "format drift: bump kRecordingMinor/Major and add a new golden file";
}

}  // namespace
}  // namespace d3d
