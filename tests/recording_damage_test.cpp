// Damaged recordings through `d3d-replay --info` as a process (issue 55, item 1): every damaged
// file exits 3 and says what was lost, as far as the file can tell; a file that is no recording
// exits 2 and is never called "newer". The recording is laid out as d3d-record writes one
// (ProbeInfo first, then bursts with a ProbeStatus every 5), 20 small bursts of seeded pixels, 7
// bursts a chunk, so that the figures of the issue come out: a file cut at the first chunk boundary
// keeps 7 of 20. The recording editor (d3d-record trim | merge | recover | export) is tried on the
// same file, intact and damaged.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <vector>

#include "common/burst/burst_io.h"
#include "common/recording/recording.h"
#include "protocol/codec.h"
#include "protocol/protocol.h"
#include "tests/process_util.h"

namespace fs = std::filesystem;

namespace d3d {
namespace {

using test::ReadFile;
using test::Spawn;
using test::Wait;

const std::string kBin = D3D_BIN_DIR;
constexpr int kBursts = 20;

std::string EncodedBurst(uint64_t seq, std::mt19937* rng) {
  proto::BurstMsg m;
  m.serial = "SIM-DAMAGE";
  m.protocol_version = proto::kProtocolVersion;
  m.burst_seq = seq;
  m.pattern_set = "phase4-marker";
  m.width = 64;
  m.height = 48;
  for (int k = 0; k < 4; ++k) {
    proto::FrameMsg f;
    f.pattern_index = static_cast<uint16_t>(k);
    f.timestamp_ns =
        1'700'000'000'000'000'000 + static_cast<int64_t>(seq) * 33'333'333 + k * 2'500'000;
    f.pixels.resize(m.BytesPerFrame());
    for (auto& p : f.pixels) p = static_cast<uint8_t>((*rng)());
    m.frames.push_back(std::move(f));
  }
  std::string s;
  proto::Encode(m, &s);
  return s;
}

// The recording's bytes and where its chunks are.
struct Made {
  std::string bytes;
  std::vector<ChunkInfo> chunks;
};

Made MakeRecording(const fs::path& path) {
  std::mt19937 rng(55);
  const size_t burst_bytes = EncodedBurst(0, &rng).size();
  RecordingHeader h;
  h.protocol_version = proto::kProtocolVersion;
  h.probe_serial = "SIM-DAMAGE";
  h.channels = {{0, proto::kTopicPhaseBurst, proto::kSchemaBurst},
                {1, proto::kTopicProbeInfo, proto::kSchemaInfo},
                {2, proto::kTopicProbeStatus, proto::kSchemaStatus}};
  RecordingWriterOptions o;
  o.chunk_bytes = 7 * burst_bytes;  // ProbeInfo + 7 bursts (+ a status) close a chunk
  o.chunk_span_ns = int64_t{1} << 62;
  RecordingWriter w;
  EXPECT_TRUE(w.Open(path.string(), h, o).ok());
  int64_t t = 1'700'000'000'000'000'000;
  proto::InfoMsg info;
  info.serial = "SIM-DAMAGE";
  info.calibration_json = std::string(2000, 'c');
  std::string s;
  proto::Encode(info, &s);
  EXPECT_TRUE(w.Add(1, t, s).ok());
  for (int i = 0; i < kBursts; ++i) {
    EXPECT_TRUE(w.Add(0, t += 33'333'333, EncodedBurst(static_cast<uint64_t>(i), &rng)).ok());
    if (i % 5 == 4) {
      proto::StatusMsg st;
      st.serial = "SIM-DAMAGE";
      st.bursts_published = static_cast<uint64_t>(i + 1);
      s.clear();
      proto::Encode(st, &s);
      EXPECT_TRUE(w.Add(2, t + 1, s).ok());
    }
  }
  EXPECT_TRUE(w.Close().ok());
  Made m;
  m.bytes = ReadFile(path.string());
  std::unique_ptr<RecordingReader> r;
  EXPECT_TRUE(RecordingReader::Open(MemorySource(m.bytes), &r).ok());
  if (r) m.chunks = r->chunks();
  return m;
}

class RecordingDamage : public ::testing::Test {
 protected:
  void SetUp() override {
    // One folder per test process: CTest runs the cases in parallel.
    dir_ = fs::temp_directory_path() / ("d3d_recording_damage_test_" + std::to_string(getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    made_ = MakeRecording(dir_ / "intact.d3drec");
    ASSERT_EQ(made_.chunks.size(), 3u) << "ProbeInfo + 7 bursts, 7 bursts, 6 bursts";
  }
  void TearDown() override { fs::remove_all(dir_); }
  // d3d-replay --info (and `extra`) on these bytes (written to dir_/name); its exit code, output in
  // *out.
  int Info(const std::string& name, const std::string& bytes, std::string* out,
           const std::vector<std::string>& extra = {}) {
    const fs::path p = dir_ / name;
    {
      std::ofstream f(p, std::ios::binary);
      f << bytes;
    }
    std::vector<std::string> args = {kBin + "/d3d-replay", "--info", p.string()};
    args.insert(args.end(), extra.begin(), extra.end());
    const test::Proc pr = Spawn(args, (dir_ / (name + ".log")).string());
    const int code = Wait(pr, 60);
    *out = ReadFile((dir_ / (name + ".log")).string());
    return code;
  }
  const ChunkInfo& chunk(size_t i) const { return made_.chunks[i]; }
  size_t ChunkEnd(size_t i) const { return chunk(i).offset + 40 + chunk(i).compressed_size; }
  fs::path dir_;
  Made made_;
};

bool Has(const std::string& out, const std::string& what) {
  return out.find(what) != std::string::npos;
}

TEST_F(RecordingDamage, IntactFileExitsZero) {
  std::string out;
  EXPECT_EQ(Info("intact.d3drec", made_.bytes, &out), 0) << out;
  EXPECT_TRUE(Has(out, "bursts 20")) << out;
  EXPECT_TRUE(Has(out, "lost:          nothing")) << out;
  EXPECT_FALSE(Has(out, "damaged")) << out;
}

// A flipped byte in chunk 1's header: the index still lists the chunk and its 8 messages; the
// burst sequence numbers jump by 7 across it.
TEST_F(RecordingDamage, FlippedChunkHeaderCountsTheLostBursts) {
  std::string b = made_.bytes;
  b[chunk(1).offset + 5] ^= 0x04;
  std::string out;
  EXPECT_EQ(Info("header.d3drec", b, &out), 3) << out;
  EXPECT_TRUE(Has(out, "header.d3drec")) << out;
  EXPECT_TRUE(Has(out, "bursts 13")) << out;
  EXPECT_TRUE(Has(out, "lost:          1 chunk, 8 messages")) << out;
  EXPECT_TRUE(Has(out, "bursts lost:   7\n")) << out;
}

// The same damage summarised as JSON (--json): one object on stdout with the same counts, the
// damage report still on stderr, the same exit code.
TEST_F(RecordingDamage, TheJsonSummaryHoldsTheSameCounts) {
  std::string b = made_.bytes;
  b[chunk(1).offset + 5] ^= 0x04;
  std::string out;
  EXPECT_EQ(Info("header_json.d3drec", b, &out, {"--json"}), 3) << out;
  const size_t at = out.find("{\"");
  ASSERT_NE(at, std::string::npos) << out;
  const nlohmann::json j = nlohmann::json::parse(out.substr(at, out.find('\n', at) - at));
  EXPECT_EQ(j["bursts"], 13);
  EXPECT_EQ(j["bursts_lost_min"], 7);
  EXPECT_EQ(j["bursts_lost_max"], 7);
  EXPECT_EQ(j["damaged"], true);
  EXPECT_EQ(j["lost"], "1 chunk, 8 messages");
  EXPECT_TRUE(Has(out, "is damaged")) << out;  // stderr
  std::string intact;
  EXPECT_EQ(Info("intact_json.d3drec", made_.bytes, &intact, {"--json"}), 0) << intact;
  EXPECT_EQ(nlohmann::json::parse(intact.substr(intact.find("{\"")))["bursts"], 20);
}

// Corrupt zstd data in the first chunk: its header says 9 messages; the bursts among them are not
// recorded per channel, so the count is a range (0 to 7: no more bursts fit its 9 messages' bytes).
TEST_F(RecordingDamage, CorruptFirstChunkIsNotZeroBurstsMissing) {
  std::string b = made_.bytes;
  b[chunk(0).offset + 40 + chunk(0).compressed_size / 2] ^= 0x10;
  std::string out;
  EXPECT_EQ(Info("zstd0.d3drec", b, &out), 3) << out;
  EXPECT_TRUE(Has(out, "lost:          1 chunk, 9 messages")) << out;
  EXPECT_TRUE(Has(out, "bursts lost:   0 to 7")) << out;
  EXPECT_FALSE(Has(out, "bursts lost:   0\n")) << out;
}

TEST_F(RecordingDamage, CorruptMiddleChunkCountsItsBursts) {
  std::string b = made_.bytes;
  b[chunk(1).offset + 40 + chunk(1).compressed_size / 2] ^= 0x10;
  std::string out;
  EXPECT_EQ(Info("zstd1.d3drec", b, &out), 3) << out;
  EXPECT_TRUE(Has(out, "bursts lost:   7\n")) << out;
}

// Cut exactly after chunk 0 (7 of 20 bursts left): no footer, no index, no skipped byte.
TEST_F(RecordingDamage, CutAtAChunkBoundaryIsKnownAsCut) {
  std::string out;
  EXPECT_EQ(Info("cut.d3drec", made_.bytes.substr(0, ChunkEnd(0)), &out), 3) << out;
  EXPECT_TRUE(Has(out, "bursts 7")) << out;
  EXPECT_TRUE(Has(out, "unknown: the file ends before its index")) << out;
}

TEST_F(RecordingDamage, EmptyBodyExitsThree) {
  std::string out;
  EXPECT_EQ(Info("empty.d3drec", made_.bytes.substr(0, chunk(0).offset), &out), 3) << out;
  EXPECT_TRUE(Has(out, "ends before its index")) << out;
}

// The tail of a closed file damaged after the chunks: nothing lost, still damaged (exit 3).
TEST_F(RecordingDamage, CutIndexFlippedFooterAndAppendedBytesLoseNothing) {
  std::string out;
  const size_t index_at = ChunkEnd(2);
  EXPECT_EQ(Info("cutindex.d3drec", made_.bytes.substr(0, index_at + 30), &out), 3) << out;
  EXPECT_TRUE(Has(out, "lost:          nothing")) << out;
  EXPECT_TRUE(Has(out, "bursts 20")) << out;
  std::string b = made_.bytes;
  b[b.size() - 20] ^= 0x01;
  EXPECT_EQ(Info("footer.d3drec", b, &out), 3) << out;
  EXPECT_TRUE(Has(out, "lost:          nothing")) << out;
  EXPECT_TRUE(Has(out, "footer")) << out;
  std::mt19937 rng(7);
  std::string garbage(333, '\0');
  for (auto& c : garbage) c = static_cast<char>(rng());
  EXPECT_EQ(Info("appended.d3drec", made_.bytes + garbage, &out), 3) << out;
  EXPECT_TRUE(Has(out, "lost:          nothing")) << out;
  EXPECT_TRUE(Has(out, "333 bytes after the end")) << out;
}

// Random bytes after the magic are a damaged header (exit 2), never "a newer format".
TEST_F(RecordingDamage, RandomBytesAfterTheMagicAreNotANewerFormat) {
  std::mt19937 rng(59633);
  for (int trial = 0; trial < 5; ++trial) {
    std::string b = made_.bytes.substr(0, 8);
    for (int i = 0; i < 400; ++i) b.push_back(static_cast<char>(rng()));
    std::string out;
    EXPECT_EQ(Info("random.d3drec", b, &out), 2) << out;
    EXPECT_FALSE(Has(out, "newer")) << out;
    EXPECT_TRUE(Has(out, "random.d3drec")) << out;
    EXPECT_TRUE(Has(out, "header")) << out;
  }
}

// The recording editor (d3d-record trim | merge | recover | export, issue 55) as a process.
class RecordingEdit : public RecordingDamage {
 protected:
  // d3d-record with `args`; its exit code, its output in *out.
  int Edit(const std::vector<std::string>& args, std::string* out) {
    std::vector<std::string> argv = {kBin + "/d3d-record"};
    argv.insert(argv.end(), args.begin(), args.end());
    const fs::path log = dir_ / ("edit" + std::to_string(++runs_) + ".log");
    const int code = Wait(Spawn(argv, log.string()), 60);
    *out = ReadFile(log.string());
    return code;
  }
  // The burst sequence numbers of a recording, in file order (and whether it is damaged).
  std::vector<uint64_t> Bursts(const fs::path& p, bool* damaged = nullptr) {
    std::unique_ptr<RecordingReader> r;
    EXPECT_TRUE(RecordingReader::OpenFile(p.string(), &r).ok()) << p;
    std::vector<uint64_t> seq;
    if (!r) return seq;
    r->ForEach([&](const RecordedMessage& m) {
      proto::BurstMsg b;
      if (m.channel == 0 && proto::Decode(m.data, &b).ok()) seq.push_back(b.burst_seq);
      return true;
    });
    if (damaged != nullptr) *damaged = r->diagnostics().damaged();
    return seq;
  }
  std::string intact() const { return (dir_ / "intact.d3drec").string(); }
  int runs_ = 0;
};

std::vector<uint64_t> Range(uint64_t from, uint64_t to) {
  std::vector<uint64_t> v;
  for (uint64_t i = from; i < to; ++i) v.push_back(i);
  return v;
}

// Trimmed by bursts, then the two halves merged back: the same 20 bursts in order.
TEST_F(RecordingEdit, TrimmedHalvesMergeBackIntoTheWholeRecording) {
  std::string out;
  const std::string a = (dir_ / "a.d3drec").string(), b = (dir_ / "b.d3drec").string();
  ASSERT_EQ(Edit({"trim", intact(), "--bursts", "0:9", "--out", a}, &out), 0) << out;
  ASSERT_EQ(Edit({"trim", intact(), "--bursts", "9:20", "--out", b}, &out), 0) << out;
  EXPECT_EQ(Bursts(a), Range(0, 9));
  EXPECT_EQ(Bursts(b), Range(9, 20));
  const std::string m = (dir_ / "merged.d3drec").string();
  ASSERT_EQ(Edit({"merge", b, a, "--out", m}, &out), 0) << out;
  bool damaged = true;
  EXPECT_EQ(Bursts(m, &damaged), Range(0, 20));
  EXPECT_FALSE(damaged);
  // By time: the first 0.2 s after the ProbeInfo (bursts 33 ms apart) holds bursts 0..5.
  const std::string t = (dir_ / "t.d3drec").string();
  ASSERT_EQ(Edit({"trim", intact(), "--from", "0", "--to", "0.2", "--out", t}, &out), 0) << out;
  EXPECT_EQ(Bursts(t), Range(0, 6));
}

// A damaged middle chunk: recover writes the intact bursts into a clean file and exits 3, saying
// what was lost; export writes the same bursts as folders d3d-recon reads.
TEST_F(RecordingEdit, RecoverAndExportUseEveryIntactChunkOfADamagedFile) {
  std::string bytes = made_.bytes;
  bytes[chunk(1).offset + 40 + chunk(1).compressed_size / 2] ^= 0x10;
  const fs::path damaged = dir_ / "damaged.d3drec";
  std::ofstream(damaged, std::ios::binary) << bytes;
  std::string out;
  const std::string clean = (dir_ / "clean.d3drec").string();
  EXPECT_EQ(Edit({"recover", damaged.string(), "--out", clean}, &out), 3) << out;
  EXPECT_TRUE(Has(out, "lost: 1 chunk, 8 messages")) << out;
  bool is_damaged = true;
  std::vector<uint64_t> want = Range(0, 7);
  for (uint64_t i = 14; i < 20; ++i) want.push_back(i);
  EXPECT_EQ(Bursts(clean, &is_damaged), want);
  EXPECT_FALSE(is_damaged);
  EXPECT_EQ(Edit({"recover", intact(), "--out", (dir_ / "copy.d3drec").string()}, &out), 0) << out;

  // cat: a line per message of every intact chunk (ProbeInfo, 13 bursts, 3 statuses), exit 3.
  EXPECT_EQ(Edit({"cat", damaged.string()}, &out), 3) << out;
  EXPECT_TRUE(Has(out, "d3d/ProbeInfo 2")) << out;
  EXPECT_TRUE(Has(out, "burst 14, 64x48x8 bit, 4 frames")) << out;
  EXPECT_FALSE(Has(out, "burst 7,")) << out;  // in the damaged chunk
  EXPECT_EQ(Edit({"cat", intact()}, &out), 0) << out;
  EXPECT_TRUE(Has(out, "burst 7, 64x48x8 bit, 4 frames")) << out;
  EXPECT_TRUE(Has(out, "d3d/ProbeStatus")) << out;

  const fs::path folders = dir_ / "folders";
  EXPECT_EQ(Edit({"export", damaged.string(), "--bursts-dir", folders.string()}, &out), 3) << out;
  EXPECT_TRUE(Has(out, "13 bursts written")) << out;
  Burst b;
  ASSERT_TRUE(ReadBurstDir((folders / "bursts" / "000007").string(), false, &b).ok());
  EXPECT_EQ(b.sequence, 14u);
  ASSERT_EQ(b.frames.size(), 4u);
  EXPECT_EQ(b.frames[2].pattern, "phase4-marker/2");
  EXPECT_FALSE(b.poses_known);
  std::mt19937 rng(55);
  EncodedBurst(0, &rng);  // MakeRecording's size probe
  proto::BurstMsg m;
  for (uint64_t i = 0; i <= 14; ++i) {  // the seeded pixels of burst 14
    m = proto::BurstMsg{};
    ASSERT_TRUE(proto::Decode(EncodedBurst(i, &rng), &m).ok());
  }
  EXPECT_EQ(std::memcmp(b.frames[2].image.data, m.frames[2].pixels.data(), m.BytesPerFrame()), 0);
  EXPECT_EQ(ReadFile((folders / "calibration.json").string()), std::string(2000, 'c'));
}

// What a hostile user tries: the output over the input, recordings of two probes merged, a range
// the file does not hold, a file that is no recording. Clear errors, exit 2, the input intact.
TEST_F(RecordingEdit, BadRequestsAreRefusedAndTheInputIsLeftIntact) {
  std::string out;
  EXPECT_EQ(Edit({"trim", intact(), "--bursts", "0:5", "--out", intact()}, &out), 2) << out;
  EXPECT_TRUE(Has(out, "is the input")) << out;
  EXPECT_EQ(ReadFile(intact()), made_.bytes);
  EXPECT_EQ(Edit({"trim", intact(), "--bursts", "30:40", "--out", (dir_ / "x").string()}, &out), 2)
      << out;
  EXPECT_TRUE(Has(out, "holds 20 bursts")) << out;
  EXPECT_EQ(Edit({"trim", intact(), "--bursts", "5:2", "--out", (dir_ / "x").string()}, &out), 2)
      << out;
  EXPECT_EQ(Edit({"trim", intact(), "--from", "30", "--out", (dir_ / "x").string()}, &out), 2)
      << out;  // the 20 bursts span 0.7 s
  EXPECT_TRUE(Has(out, "no burst in that stretch")) << out;
  EXPECT_EQ(Edit({"trim", intact(), "--to", "-5", "--out", (dir_ / "x").string()}, &out), 2) << out;
  EXPECT_EQ(Edit({"trim", intact(), "--bursts", "0:5", "--to", "1", "--out", (dir_ / "x").string()},
                 &out),
            2)
      << out;
  const fs::path other = dir_ / "other.d3drec";
  {
    std::unique_ptr<RecordingReader> r;
    ASSERT_TRUE(RecordingReader::OpenFile(intact(), &r).ok());
    RecordingHeader h = r->header();
    h.probe_serial = "SIM-OTHER";
    RecordingWriter w;
    ASSERT_TRUE(w.Open(other.string(), h).ok());
    ASSERT_TRUE(w.Add(0, 1, "x").ok());
    ASSERT_TRUE(w.Close().ok());
  }
  EXPECT_EQ(Edit({"merge", intact(), other.string(), "--out", (dir_ / "m").string()}, &out), 2)
      << out;
  EXPECT_TRUE(Has(out, "SIM-OTHER")) << out;
  // The refusal names the file that differs, wherever it stands.
  const std::string copy = (dir_ / "copy.d3drec").string();
  std::ofstream(copy, std::ios::binary) << made_.bytes;
  EXPECT_EQ(Edit({"merge", intact(), copy, other.string(), "--out", (dir_ / "m").string()}, &out),
            2)
      << out;
  EXPECT_TRUE(Has(out, "input 3") && Has(out, "(" + other.string() + ")")) << out;
  const fs::path text = dir_ / "notes.txt";
  std::ofstream(text) << "not a recording\n";
  EXPECT_EQ(Edit({"export", text.string(), "--bursts-dir", (dir_ / "f").string()}, &out), 2) << out;
  EXPECT_TRUE(Has(out, "notes.txt")) << out;
  EXPECT_EQ(Edit({"trim", "--out", (dir_ / "x").string()}, &out), 2) << out;  // no input
}

}  // namespace
}  // namespace d3d
