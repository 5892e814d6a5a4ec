#include "common/recording/recording_edit.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>

namespace d3d {
namespace {

namespace fs = std::filesystem;

RecordingHeader EditHeader(const std::string& serial = "SIM-EDIT") {
  RecordingHeader h;
  h.protocol_version = 101;
  h.probe_serial = serial;
  h.calibration_json = "{}";
  h.channels = {{0, "d3d/PhaseBurst", "burst/test"}, {1, "d3d/ProbeStatus", "status/test"}};
  return h;
}

// n messages at the given log times (ns), channel k % 2, payload "k" and seeded filler; a chunk
// every 4 messages.
fs::path Write(const std::string& name, const std::vector<int64_t>& times_ns,
               const RecordingHeader& h = EditHeader()) {
  const fs::path p = fs::temp_directory_path() / name;
  RecordingWriter w;
  RecordingWriterOptions o;
  o.chunk_bytes = 4 * 200;
  EXPECT_TRUE(w.Open(p.string(), h, o).ok());
  std::mt19937 rng(57);
  for (size_t k = 0; k < times_ns.size(); ++k) {
    std::string data = std::to_string(times_ns[k]) + ":";
    while (data.size() < 200) data.push_back(static_cast<char>('a' + rng() % 26));
    EXPECT_TRUE(w.Add(static_cast<uint16_t>(k % 2), times_ns[k], data).ok());
  }
  EXPECT_TRUE(w.Close().ok());
  return p;
}

std::vector<RecordedMessage> ReadBack(const fs::path& p, RecordingDiagnostics* d = nullptr) {
  std::unique_ptr<RecordingReader> r;
  EXPECT_TRUE(RecordingReader::OpenFile(p.string(), &r).ok());
  std::vector<RecordedMessage> all;
  if (!r) return all;
  r->ForEach([&](const RecordedMessage& m) {
    all.push_back(m);
    return true;
  });
  if (d != nullptr) *d = r->diagnostics();
  return all;
}

std::vector<int64_t> Times(int n, int64_t first_ns, int64_t step_ns) {
  std::vector<int64_t> t;
  for (int k = 0; k < n; ++k) t.push_back(first_ns + k * step_ns);
  return t;
}

TEST(RecordingEdit, CopyKeepsWhatTheFilterKeepsInOrderAndBitForBit) {
  const fs::path in = Write("d3d_edit_copy_in.d3drec", Times(20, 1'000, 100));
  const fs::path out = fs::temp_directory_path() / "d3d_edit_copy_out.d3drec";
  std::unique_ptr<RecordingReader> r;
  ASSERT_TRUE(RecordingReader::OpenFile(in.string(), &r).ok());
  RecordingWriter w;
  ASSERT_TRUE(w.Open(out.string(), r->header()).ok());
  const LogTimeRange range{1'500, 2'300};  // messages 5..12
  RecordingCopyCounts counts;
  ASSERT_TRUE(CopyMessages(
                  r.get(), [&](const RecordedMessage& m) { return range.Contains(m.log_time_ns); },
                  &w, &counts)
                  .ok());
  ASSERT_TRUE(w.Close().ok());
  EXPECT_EQ(counts.messages_read, 20u);
  EXPECT_EQ(counts.messages_written, 8u);
  const std::vector<RecordedMessage> all = ReadBack(in), kept = ReadBack(out);
  ASSERT_EQ(kept.size(), 8u);
  for (size_t i = 0; i < kept.size(); ++i) {
    EXPECT_EQ(kept[i].log_time_ns, all[i + 5].log_time_ns);
    EXPECT_EQ(kept[i].channel, all[i + 5].channel);
    EXPECT_EQ(kept[i].data, all[i + 5].data);
  }
}

// Two recordings of one probe interleave by log time; equal times keep the inputs' order.
TEST(RecordingEdit, MergeOrdersEveryMessageByLogTime) {
  const fs::path a = Write("d3d_edit_merge_a.d3drec", Times(9, 1'000, 100));  // 1000, 1100, ...
  const fs::path b = Write("d3d_edit_merge_b.d3drec", Times(7, 1'050, 100));  // 1050, 1150, ...
  const fs::path c = Write("d3d_edit_merge_c.d3drec", {1'100, 1'100});
  const fs::path out = fs::temp_directory_path() / "d3d_edit_merge_out.d3drec";
  std::vector<std::unique_ptr<RecordingReader>> readers(3);
  std::vector<RecordingReader*> raw;
  const fs::path paths[] = {a, b, c};
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(RecordingReader::OpenFile(paths[i].string(), &readers[i]).ok());
    raw.push_back(readers[i].get());
  }
  RecordingWriter w;
  ASSERT_TRUE(w.Open(out.string(), readers[0]->header()).ok());
  RecordingCopyCounts counts;
  ASSERT_TRUE(MergeRecordings(raw, &w, &counts).ok());
  ASSERT_TRUE(w.Close().ok());
  EXPECT_EQ(counts.messages_read, 18u);
  EXPECT_EQ(counts.messages_written, 18u);
  const std::vector<RecordedMessage> m = ReadBack(out);
  ASSERT_EQ(m.size(), 18u);
  for (size_t i = 1; i < m.size(); ++i) EXPECT_LE(m[i - 1].log_time_ns, m[i].log_time_ns) << i;
  // At 1100: a's message first, then c's two (b has none there).
  size_t at = 0;
  while (m[at].log_time_ns != 1'100) ++at;
  EXPECT_EQ(m[at].data, ReadBack(a)[1].data);
  EXPECT_EQ(m[at + 1].data, ReadBack(c)[0].data);
  EXPECT_EQ(m[at + 2].data, ReadBack(c)[1].data);
}

TEST(RecordingEdit, RecordingsOfAnotherProbeOrCalibrationAreNotMerged) {
  RecordingHeader other_probe = EditHeader("SIM-OTHER");
  RecordingHeader other_cal = EditHeader();
  other_cal.calibration_json = "{\"other\": 1}";
  RecordingHeader other_channels = EditHeader();
  other_channels.channels[1].schema = "status/v2";
  const RecordingHeader base = EditHeader();
  std::string why;
  EXPECT_TRUE(SameStream({&base, &base}, &why));
  EXPECT_FALSE(SameStream({&base, &other_probe}, &why));
  EXPECT_NE(why.find("SIM-OTHER"), std::string::npos) << why;
  size_t differs = 0;
  EXPECT_FALSE(SameStream({&base, &base, &other_cal}, &why, &differs));
  EXPECT_NE(why.find("input 3"), std::string::npos) << why;
  EXPECT_EQ(differs, 2u);
  EXPECT_FALSE(SameStream({&base, &other_channels}, &why));

  const fs::path a = Write("d3d_edit_refuse_a.d3drec", Times(3, 1'000, 100));
  const fs::path b = Write("d3d_edit_refuse_b.d3drec", Times(3, 2'000, 100), other_probe);
  std::unique_ptr<RecordingReader> ra, rb;
  ASSERT_TRUE(RecordingReader::OpenFile(a.string(), &ra).ok());
  ASSERT_TRUE(RecordingReader::OpenFile(b.string(), &rb).ok());
  const fs::path out = fs::temp_directory_path() / "d3d_edit_refuse_out.d3drec";
  RecordingWriter w;
  ASSERT_TRUE(w.Open(out.string(), ra->header()).ok());
  RecordingCopyCounts counts;
  const Status s = MergeRecordings({ra.get(), rb.get()}, &w, &counts);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument) << s.ToString();
  EXPECT_EQ(counts.messages_written, 0u);
}

// A damaged chunk is skipped, every other message copied, and the copy is a clean file.
TEST(RecordingEdit, ACopyOfADamagedRecordingIsCleanAndHoldsEveryIntactChunk) {
  const fs::path in = Write("d3d_edit_damaged_in.d3drec", Times(16, 1'000, 100));
  std::unique_ptr<RecordingReader> probe;
  ASSERT_TRUE(RecordingReader::OpenFile(in.string(), &probe).ok());
  ASSERT_GE(probe->chunks().size(), 3u);
  const ChunkInfo second = probe->chunks()[1];
  probe.reset();
  {  // flip a byte in the second chunk's compressed data: its CRC fails
    std::fstream f(in, std::ios::in | std::ios::out | std::ios::binary);
    const auto at = static_cast<std::streamoff>(second.offset + 40 + 5);  // past its 40-byte header
    f.seekg(at);
    const char byte = static_cast<char>(f.get());
    f.seekp(at);
    f.put(static_cast<char>(byte ^ 0x5a));
  }
  std::unique_ptr<RecordingReader> r;
  ASSERT_TRUE(RecordingReader::OpenFile(in.string(), &r).ok());
  const fs::path out = fs::temp_directory_path() / "d3d_edit_damaged_out.d3drec";
  RecordingWriter w;
  ASSERT_TRUE(w.Open(out.string(), r->header()).ok());
  RecordingCopyCounts counts;
  ASSERT_TRUE(CopyMessages(
                  r.get(), [](const RecordedMessage&) { return true; }, &w, &counts)
                  .ok());
  ASSERT_TRUE(w.Close().ok());
  EXPECT_TRUE(r->diagnostics().damaged());
  EXPECT_EQ(r->diagnostics().corrupt_chunks, 1u);
  EXPECT_EQ(counts.messages_written, 16u - second.message_count);
  RecordingDiagnostics d;
  EXPECT_EQ(ReadBack(out, &d).size(), 16u - second.message_count);
  EXPECT_FALSE(d.damaged());
  EXPECT_TRUE(d.index_used);
}

}  // namespace
}  // namespace d3d
