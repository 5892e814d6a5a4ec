// A chunked, compressed, checksummed recording of timestamped messages (PhaseBurst, ProbeInfo,
// ProbeStatus samples from d3d-record), modelled on MCAP's design: a header, self-delimiting chunks
// of zstd-compressed messages, then an index of the chunks and a footer that points at it.
//
// File layout (all integers little endian; format 1.0):
//   header   magic "\x89D3DREC\n" (8) | u16 major | u16 minor | u32 json_len | json | u32 crc32(all before)
//            json: {"protocol_version", "created_ns", "probe_serial", "calibration_json",
//                   "channels": [{"id", "topic", "schema"}], "metadata": {string: string}}
//   chunk*   "CHNK" | u32 compressed_size | u32 uncompressed_size | u32 message_count
//            | i64 first_time_ns | i64 last_time_ns | u32 data_crc32 (of the compressed bytes)
//            | u32 header_crc32 (of the 36 bytes before it) | compressed bytes (one zstd frame)
//            uncompressed: message* = u16 channel | i64 log_time_ns | u32 size | bytes
//   index    "INDX" | u32 n | n × (u64 offset | i64 first_time_ns | i64 last_time_ns | u32 message_count)
//            | u32 crc32(all before, from "INDX")
//   footer   "FOOT" | u64 index_offset | u32 crc32(the 12 bytes before) | "D3DEND\r\n"
//
// Robustness: the writer appends each chunk with one write(2) as it completes, so a recorder killed
// at any moment leaves a file whose complete chunks are all readable (only the index and footer are
// missing). The reader uses the index when the footer and index check out; otherwise it scans the
// chunks from the header on, re-synchronising on the next valid chunk header after damage, and
// reports what it skipped. A chunk whose data fails its CRC or does not decompress is skipped with a
// reason; every intact chunk is still read. Wrong magic gives PARSE_ERROR, a newer major version
// UNSUPPORTED, a damaged header CORRUPT.
//
// Threads: a writer or reader is used by one thread at a time.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "common/core/status.h"

namespace d3d {

inline constexpr uint16_t kRecordingMajor = 1;
inline constexpr uint16_t kRecordingMinor = 0;
inline constexpr size_t kMaxChunkBytes = size_t{64} << 20;  // uncompressed, per chunk (and per message)

struct RecordingChannel {
  uint16_t id = 0;
  std::string topic;   // DDS topic, e.g. "d3d/PhaseBurst"
  std::string schema;  // payload encoding, e.g. "d3d.proto.PhaseBurst/codec1"
};

struct RecordingHeader {
  uint16_t format_major = kRecordingMajor;  // set by the writer / read from the file
  uint16_t format_minor = kRecordingMinor;
  int protocol_version = 0;        // d3d::proto::kProtocolVersion of the recorded samples
  int64_t created_ns = 0;          // Unix epoch
  std::string probe_serial;
  std::string calibration_json;    // the probe's calibration.json (from ProbeInfo), "" if none
  std::vector<RecordingChannel> channels;
  std::map<std::string, std::string> metadata;
  const RecordingChannel* FindTopic(std::string_view topic) const;
};

struct RecordedMessage {
  uint16_t channel = 0;
  int64_t log_time_ns = 0;  // when the recorder received it (Unix epoch)
  std::string data;
};

struct RecordingWriterOptions {
  size_t chunk_bytes = size_t{8} << 20;   // close a chunk at this many uncompressed bytes (default 8 MiB)
  int64_t chunk_span_ns = 1'000'000'000;  // ... or when it spans this long (default 1 s)
  int zstd_level = 1;                     // 1 (fast) .. 19
  void Check() const;                     // throws std::invalid_argument
};

class RecordingWriter {
 public:
  RecordingWriter() = default;
  ~RecordingWriter();  // closes (writes index and footer) if still open; errors are lost: call Close()
  RecordingWriter(const RecordingWriter&) = delete;
  RecordingWriter& operator=(const RecordingWriter&) = delete;

  // Creates/truncates `path` and writes the header. IO_ERROR if it cannot be written.
  [[nodiscard]] Status Open(const std::string& path, const RecordingHeader& header, const RecordingWriterOptions& options = {});
  // Buffers one message; may complete and write a chunk. INVALID_ARGUMENT for an unknown channel or a
  // message larger than kMaxChunkBytes; IO_ERROR if the write fails.
  [[nodiscard]] Status Add(uint16_t channel, int64_t log_time_ns, std::string_view data);
  [[nodiscard]] Status Flush();  // writes the pending chunk, if any
  [[nodiscard]] Status Close();  // flush, index, footer
  bool is_open() const { return fd_ >= 0; }
  uint64_t messages_written() const { return messages_; }
  uint64_t bytes_written() const { return offset_; }

 private:
  int fd_ = -1;
  RecordingWriterOptions options_;
  std::vector<bool> known_channel_;
  std::string pending_;  // uncompressed messages of the open chunk
  uint32_t pending_count_ = 0;
  int64_t first_ns_ = 0, last_ns_ = 0;
  std::string compressed_;
  struct IndexEntry {
    uint64_t offset;
    int64_t first_ns, last_ns;
    uint32_t count;
  };
  std::vector<IndexEntry> index_;
  uint64_t offset_ = 0;
  uint64_t messages_ = 0;
  Status WriteAll(std::string_view bytes);
};

// Random-access bytes: a file (pread) or memory (tests, fuzzing).
class ByteSource {
 public:
  virtual ~ByteSource() = default;
  virtual uint64_t size() const = 0;
  // Reads exactly n bytes at offset into *out; false if they are not all there.
  virtual bool Read(uint64_t offset, size_t n, std::string* out) const = 0;
};
[[nodiscard]] Status OpenFileSource(const std::string& path, std::unique_ptr<ByteSource>* out);  // NOT_FOUND / IO_ERROR
std::unique_ptr<ByteSource> MemorySource(std::string bytes);

struct ChunkInfo {
  uint64_t offset = 0;  // of "CHNK"
  uint32_t compressed_size = 0;
  uint32_t uncompressed_size = 0;
  uint32_t message_count = 0;
  int64_t first_time_ns = 0;
  int64_t last_time_ns = 0;
};

// What Open found beyond the intact file: empty problems and index_used for a cleanly closed file.
struct RecordingDiagnostics {
  bool index_used = false;       // false: no valid index/footer (killed recorder, cut-off tail, damage)
  uint64_t skipped_bytes = 0;    // bytes between chunks that were not a valid chunk (damage, cut-off tail)
  uint64_t corrupt_chunks = 0;   // chunks whose data failed the CRC or did not decompress (on read)
  std::vector<std::string> problems;  // one line per finding, for logs and --info
};

class RecordingReader {
 public:
  // Reads and checks the header, then the index or (failing that) scans the chunks. PARSE_ERROR for a
  // file that is not a recording or is shorter than its header, UNSUPPORTED for a newer major format,
  // CORRUPT for a header that fails its CRC or its JSON.
  [[nodiscard]] static Status Open(std::unique_ptr<ByteSource> source, std::unique_ptr<RecordingReader>* out);
  [[nodiscard]] static Status OpenFile(const std::string& path, std::unique_ptr<RecordingReader>* out);

  const RecordingHeader& header() const { return header_; }
  const std::vector<ChunkInfo>& chunks() const { return chunks_; }
  const RecordingDiagnostics& diagnostics() const { return diagnostics_; }

  // Decompresses chunk i into *messages (replaced). CORRUPT if its CRC fails, it does not
  // decompress, or its messages are malformed (then *messages is empty and diagnostics() records it).
  // The compressed and decompressed bytes go through buffers the reader keeps, and the messages
  // already in *messages are reused: a replay that passes the same vector for every chunk
  // allocates (and page-faults) nothing once the first chunks were read.
  [[nodiscard]] Status ReadChunk(size_t i, std::vector<RecordedMessage>* messages);
  // Calls fn for every message of every intact chunk in file order; corrupt chunks are skipped and
  // recorded in diagnostics(). Stops early (returning OK) when fn returns false.
  void ForEach(const std::function<bool(const RecordedMessage&)>& fn);

 private:
  RecordingReader() = default;
  Status ParseHeader();
  bool LoadIndex();
  void ScanChunks();
  bool ReadChunkHeader(uint64_t offset, ChunkInfo* info) const;
  std::unique_ptr<ByteSource> source_;
  RecordingHeader header_;
  uint64_t data_start_ = 0;
  std::vector<ChunkInfo> chunks_;
  std::vector<bool> chunk_reported_;
  RecordingDiagnostics diagnostics_;
  std::string compressed_, raw_;  // ReadChunk's buffers, kept across chunks
};

}  // namespace d3d
