#include "common/recording/recording.h"

#include <gtest/gtest.h>
#include <zlib.h>

#include <cstring>
#include <filesystem>
#include <fstream>
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

// Message k: channel k % 2, time 1e9 + k·33 ms, `size` seeded pseudo-random bytes (k in the first
// 4).
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
  for (int k = 0; k < n; ++k)
    EXPECT_TRUE(
        w.Add(static_cast<uint16_t>(k % 2), 1'000'000'000 + k * 33'000'000LL, Payload(k, size))
            .ok());
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

uint32_t Get32(const std::string& b, size_t at) {
  uint32_t v;
  std::memcpy(&v, b.data() + at, 4);
  return v;
}
void Put32(std::string* b, size_t at, uint32_t v) { std::memcpy(b->data() + at, &v, 4); }
uint32_t Crc(const std::string& b) {
  return static_cast<uint32_t>(
      crc32(0L, reinterpret_cast<const Bytef*>(b.data()), static_cast<uInt>(b.size())));
}

// A header of the current layout around `json`, with a valid CRC.
std::string HeaderWithJson(const std::string& json) {
  std::string h = std::string("\x89") + "D3DREC\n";
  h.append("\x01\x00\x00\x00", 4);
  h.append(4, '\0');
  Put32(&h, 12, static_cast<uint32_t>(json.size()));
  h.append(json);
  h.append(4, '\0');
  Put32(&h, h.size() - 4, Crc(h.substr(0, h.size() - 4)));
  return h;
}

// The burst-like channel 0 of the test recording: message k (even) carries sequence number k / 2.
SequenceLossCounter CountChannel0(RecordingReader* r) {
  SequenceLossCounter c(r);
  std::vector<RecordedMessage> msgs;
  for (size_t i = 0; i < r->chunks().size(); ++i) {
    const bool ok = r->ReadChunk(i, &msgs).ok();
    c.Chunk(i, ok);
    if (!ok) continue;
    for (const auto& m : msgs) {
      int k = -1;
      std::memcpy(&k, m.data.data(), sizeof k);
      if (m.channel == 0) c.Message(static_cast<uint64_t>(k / 2), m.data.size());
    }
  }
  c.End();
  return c;
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
    // Every flip is found, and what it lost is counted to the message: a chunk header or data has a
    // CRC, the index has one and the footer has one; without a usable footer the scan meets the
    // index.
    EXPECT_TRUE(r->diagnostics().damaged()) << "flip at " << pos;
    EXPECT_EQ(r->diagnostics().uncounted_losses, 0u)
        << "flip at " << pos << ": " << r->diagnostics().LossSummary();
    EXPECT_EQ(got + r->diagnostics().messages_lost, 30u)
        << "flip at " << pos << ": " << r->diagnostics().LossSummary();
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
  b[8] = 2;  // major 2, in a header whose CRC checks out (as a newer writer leaves it)
  const uint32_t json_len = Get32(b, 12);
  Put32(&b, 16 + json_len, Crc(b.substr(0, 16 + json_len)));
  OpenBytes(b, &s);
  EXPECT_EQ(s.code(), StatusCode::kUnsupported);
  EXPECT_NE(s.message().find("newer"), std::string::npos);
  b = closed;
  b[8] = 2;  // ... and with the CRC as it was: damage, not a newer format
  OpenBytes(b, &s);
  EXPECT_EQ(s.code(), StatusCode::kCorrupt);
  EXPECT_EQ(s.message().find("newer"), std::string::npos) << s.message();
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

TEST(Recording, RandomBytesAfterTheMagicAreADamagedHeaderNotANewerFormat) {
  std::mt19937 rng(59633);
  for (int trial = 0; trial < 200; ++trial) {
    std::string b = std::string("\x89") + "D3DREC\n";
    const size_t n = 8 + rng() % 600;
    for (size_t i = 0; i < n; ++i) b.push_back(static_cast<char>(rng()));
    Status s;
    OpenBytes(b, &s);
    EXPECT_TRUE(s.code() == StatusCode::kCorrupt || s.code() == StatusCode::kParseError)
        << s.ToString();
    EXPECT_EQ(s.message().find("newer"), std::string::npos) << s.message();
  }
}

TEST(Recording, AHeaderFieldOfTheWrongTypeIsNamed) {
  Status s;
  OpenBytes(
      HeaderWithJson(
          R"({"protocol_version": 101, "created_ns": 1, "probe_serial": 7, "calibration_json": "", "channels": []})"),
      &s);
  EXPECT_EQ(s.code(), StatusCode::kCorrupt);
  EXPECT_EQ(s.message(), "recording header: field 'probe_serial' is missing or not of its type");
  OpenBytes(
      HeaderWithJson(
          R"({"protocol_version": 101, "created_ns": 1, "probe_serial": "", "calibration_json": ""})"),
      &s);
  EXPECT_EQ(s.message(), "recording header: field 'channels' is missing or not of its type");
}

TEST(Recording, AClosedFileLostNothing) {
  Status s;
  auto r = OpenBytes(ReadAll(WriteTestRecording("d3d_rec_clean.d3drec", 20, 5000)), &s);
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(Recovered(r.get(), 5000).size(), 20u);
  EXPECT_FALSE(r->diagnostics().damaged());
  EXPECT_EQ(r->diagnostics().LossSummary(), "nothing");
  const SequenceLossCounter c = CountChannel0(r.get());
  EXPECT_EQ(c.lost_max(), 0u);
  EXPECT_EQ(c.Describe(), "0");
}

// A file cut exactly after a chunk has no skipped byte: it is known as cut from its missing index,
// and what it lost is unknown (before, a cut at a chunk boundary looked intact).
TEST(Recording, ACutAtAChunkBoundaryEndsBeforeItsIndex) {
  const auto closed = ReadAll(WriteTestRecording("d3d_rec_cutb.d3drec", 20, 5000));
  Status s;
  const auto chunks = OpenBytes(closed, &s)->chunks();
  for (size_t i = 0; i <= chunks.size(); ++i) {
    const size_t cut = i < chunks.size()
                           ? chunks[i].offset
                           : chunks.back().offset + 40 + chunks.back().compressed_size;
    auto r = OpenBytes(closed.substr(0, cut), &s);
    ASSERT_TRUE(s.ok());
    EXPECT_EQ(r->chunks().size(), i < chunks.size() ? i : chunks.size());
    EXPECT_EQ(r->diagnostics().skipped_bytes, 0u);
    EXPECT_TRUE(r->diagnostics().damaged()) << "cut at " << cut;
    EXPECT_TRUE(r->diagnostics().ends_before_index);
    EXPECT_EQ(r->diagnostics().LossSummary(), "unknown: the file ends before its index");
    EXPECT_TRUE(r->gap_before(r->chunks().size()).uncounted);
    const SequenceLossCounter c = CountChannel0(r.get());
    EXPECT_FALSE(c.lost_max().has_value());
    EXPECT_EQ(c.Describe(), "unknown: the file ends before its index");
  }
}

// A flipped chunk header in a closed file: the index still lists the chunk, so its messages are
// counted as lost (the reader used to fall back to a scan, which cannot count them).
TEST(Recording, AFlippedChunkHeaderIsCountedFromTheIndex) {
  const auto closed = ReadAll(WriteTestRecording("d3d_rec_hflip.d3drec", 30, 5000));
  Status s;
  const auto chunks = OpenBytes(closed, &s)->chunks();
  ASSERT_GE(chunks.size(), 5u);
  std::string b = closed;
  b[chunks[2].offset + 13] ^= 0x01;  // chunk 2's message count
  auto r = OpenBytes(b, &s);
  ASSERT_TRUE(s.ok());
  EXPECT_TRUE(r->diagnostics().index_used);
  EXPECT_EQ(r->chunks().size(), chunks.size() - 1);
  EXPECT_EQ(r->diagnostics().corrupt_chunks, 1u);
  EXPECT_EQ(r->diagnostics().messages_lost, chunks[2].message_count);
  EXPECT_EQ(r->gap_before(2).messages, chunks[2].message_count);
  EXPECT_EQ(Recovered(r.get(), 5000).size(), 30u - chunks[2].message_count);
  // ... and with the footer flipped too: the scan meets the index after the last chunk and counts
  // the same.
  b[b.size() - 3] ^= 0x40;
  r = OpenBytes(b, &s);
  ASSERT_TRUE(s.ok());
  EXPECT_FALSE(r->diagnostics().index_used);
  EXPECT_EQ(r->diagnostics().messages_lost, chunks[2].message_count);
  EXPECT_EQ(r->diagnostics().uncounted_losses, 0u);
  EXPECT_EQ(r->diagnostics().LossSummary(),
            "1 chunk, " + std::to_string(chunks[2].message_count) + " messages");
  // Channel 0's numbers jump across the lost chunk: exactly its channel-0 messages are lost.
  std::unique_ptr<RecordingReader> clean = OpenBytes(closed, &s);
  std::vector<RecordedMessage> msgs;
  ASSERT_TRUE(clean->ReadChunk(2, &msgs).ok());
  uint64_t in_chunk2 = 0;
  for (const auto& m : msgs) in_chunk2 += m.channel == 0;
  const SequenceLossCounter c = CountChannel0(r.get());
  EXPECT_EQ(c.lost_min(), in_chunk2);
  EXPECT_EQ(c.lost_max(), in_chunk2);
  EXPECT_EQ(c.missing_upstream(), 0u);
}

// The tail of a closed file damaged after its chunks: damaged, nothing lost.
TEST(Recording, ACutIndexAFlippedFooterAndAppendedBytesLoseNothing) {
  const auto closed = ReadAll(WriteTestRecording("d3d_rec_tail.d3drec", 20, 5000));
  Status s;
  const auto chunks = OpenBytes(closed, &s)->chunks();
  const size_t index_at = chunks.back().offset + 40 + chunks.back().compressed_size;
  std::string flipped_footer = closed;
  flipped_footer[closed.size() - 16] ^= 0x08;
  std::mt19937 rng(11);
  std::string appended = closed;
  for (int i = 0; i < 100; ++i) appended.push_back(static_cast<char>(rng()));
  for (const std::string& b : {closed.substr(0, index_at + 3), closed.substr(0, index_at + 37),
                               flipped_footer, appended, closed.substr(0, closed.size() - 1)}) {
    auto r = OpenBytes(b, &s);
    ASSERT_TRUE(s.ok());
    EXPECT_EQ(Recovered(r.get(), 5000).size(), 20u);
    EXPECT_TRUE(r->diagnostics().damaged()) << b.size();
    EXPECT_FALSE(r->diagnostics().ends_before_index) << b.size();
    EXPECT_EQ(r->diagnostics().LossSummary(), "nothing") << b.size();
    EXPECT_EQ(CountChannel0(r.get()).Describe(), "0");
  }
  auto r = OpenBytes(appended, &s);
  ASSERT_EQ(r->diagnostics().problems.size(), 1u);
  EXPECT_NE(r->diagnostics().problems[0].find("100 bytes after the end of the recording"),
            std::string::npos)
      << r->diagnostics().problems[0];
}

// Channel 0 across damage: a lost first chunk gives a range (how many of its messages were channel
// 0 is not recorded), a lost middle chunk an exact count, a jump within intact data is upstream.
TEST(Recording, SequenceLossCounterRangesAndCounts) {
  const auto closed = ReadAll(WriteTestRecording("d3d_rec_seq.d3drec", 30, 5000));
  Status s;
  const auto chunks = OpenBytes(closed, &s)->chunks();
  ASSERT_EQ(chunks[0].message_count, 3u);  // k = 0, 1, 2: two of channel 0
  std::string b = closed;
  b[chunks[0].offset + 40 + chunks[0].compressed_size / 2] ^= 0x02;
  auto r = OpenBytes(b, &s);
  SequenceLossCounter c = CountChannel0(r.get());
  EXPECT_EQ(c.lost_min(), 0u);
  EXPECT_EQ(c.lost_max(), 3u);
  EXPECT_EQ(c.Describe(), "0 to 3");
  EXPECT_EQ(r->diagnostics().LossSummary(), "1 chunk, 3 messages");
  // A lost middle chunk: the jump across it.
  b = closed;
  b[chunks[3].offset + 40 + 7] ^= 0x02;
  r = OpenBytes(b, &s);
  c = CountChannel0(r.get());
  EXPECT_EQ(c.lost_min(), c.lost_max().value_or(99));
  EXPECT_GE(c.lost_min(), 1u);
  EXPECT_EQ(c.missing_upstream(), 0u);
  // Numbers that jump within intact data: missing upstream, not lost in the file.
  const fs::path p = fs::temp_directory_path() / "d3d_rec_upstream.d3drec";
  {
    RecordingWriter w;
    ASSERT_TRUE(w.Open(p.string(), TestHeader()).ok());
    for (int k : {0, 2, 4, 10, 12}) ASSERT_TRUE(w.Add(0, k, Payload(k, 100)).ok());
    ASSERT_TRUE(w.Close().ok());
  }
  std::unique_ptr<RecordingReader> u;
  ASSERT_TRUE(RecordingReader::OpenFile(p.string(), &u).ok());
  c = CountChannel0(u.get());
  EXPECT_EQ(c.missing_upstream(), 2u);  // 3, 4 of 0, 1, 2, 5, 6 (k / 2)
  EXPECT_EQ(c.upstream_gaps(), 1u);
  EXPECT_EQ(c.Describe(), "0");
}

TEST(Recording, RejectsUndeclaredChannel) {
  RecordingWriter w;
  ASSERT_TRUE(
      w.Open((fs::temp_directory_path() / "d3d_rec_ch.d3drec").string(), TestHeader()).ok());
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
  // The current writer produces the same bytes from the same input (zstd level 1 of Debian 12's
  // zstd).
  EXPECT_EQ(ReadAll(fresh), ReadAll(golden))
      << "format drift: bump kRecordingMinor/Major and add a new golden file";
}

}  // namespace
}  // namespace d3d
