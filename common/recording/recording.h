// A chunked, compressed, checksummed recording of timestamped messages (PhaseBurst, ProbeInfo,
// ProbeStatus samples from d3d-record), modelled on MCAP's design: a header, self-delimiting chunks
// of zstd-compressed messages, then an index of the chunks and a footer that points at it.
//
// File layout (all integers little endian; format 1.0):
//   header   magic "\x89D3DREC\n" (8) | u16 major | u16 minor | u32 json_len | json | u32 crc32(all
//   before)
//            json: {"protocol_version", "created_ns", "probe_serial", "calibration_json",
//                   "channels": [{"id", "topic", "schema"}], "metadata": {string: string}}
//   chunk*   "CHNK" | u32 compressed_size | u32 uncompressed_size | u32 message_count
//            | i64 first_time_ns | i64 last_time_ns | u32 data_crc32 (of the compressed bytes)
//            | u32 header_crc32 (of the 36 bytes before it) | compressed bytes (one zstd frame)
//            uncompressed: message* = u16 channel | i64 log_time_ns | u32 size | bytes
//   index    "INDX" | u32 n | n × (u64 offset | i64 first_time_ns | i64 last_time_ns | u32
//   message_count)
//            | u32 crc32(all before, from "INDX")
//   footer   "FOOT" | u64 index_offset | u32 crc32(the 12 bytes before) | "D3DEND\r\n"
//
// Robustness: the writer appends each chunk with one write(2) as it completes, so a recorder killed
// at any moment leaves a file whose complete chunks are all readable (only the index and footer are
// missing). The reader uses the index when the footer and index check out (a chunk the index lists
// whose header is damaged is lost, with the index's count of its messages); otherwise it scans the
// chunks from the header on, re-synchronising on the next valid chunk header after damage, and
// reports what it skipped. A chunk whose data fails its CRC or does not decompress is skipped with
// a reason; every intact chunk is still read. What was lost is counted where the file tells: an
// index (through the footer, or met by the scan after the last chunk) lists every chunk with its
// message count; an intact chunk header gives its own count; chunks that run without a gap from the
// header to the index lost nothing between them. A file that ends before its index (killed
// recorder, cut-off copy) lost an unknown amount after its last chunk; bytes skipped without an
// index to check them hold an unknown number of messages. Any finding makes the file damaged
// (RecordingDiagnostics::damaged), even when nothing was lost. Wrong magic gives PARSE_ERROR, a
// newer major version (in a header whose CRC checks out) UNSUPPORTED, a damaged header CORRUPT
// (never "newer": random bytes after the magic are damage).
//
// The header's layout up to its CRC (magic, major, minor, json_len, json, crc32) is the part every
// format version keeps: a reader checks the CRC before it believes the version fields.
//
// Threads: a writer or reader (and a SequenceLossCounter) is used by one thread at a time.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "common/core/status.h"

namespace d3d {

inline constexpr uint16_t kRecordingMajor = 1;
inline constexpr uint16_t kRecordingMinor = 0;
inline constexpr size_t kMaxChunkBytes = size_t{64}
                                         << 20;  // uncompressed, per chunk (and per message)

struct RecordingChannel {
  uint16_t id = 0;
  std::string topic;   // DDS topic, e.g. "d3d/PhaseBurst"
  std::string schema;  // payload encoding, e.g. "d3d.proto.PhaseBurst/codec1"
};

struct RecordingHeader {
  uint16_t format_major = kRecordingMajor;  // set by the writer / read from the file
  uint16_t format_minor = kRecordingMinor;
  int protocol_version = 0;  // d3d::proto::kProtocolVersion of the recorded samples
  int64_t created_ns = 0;    // Unix epoch
  std::string probe_serial;
  std::string calibration_json;  // the probe's calibration.json (from ProbeInfo), "" if none
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
  size_t chunk_bytes =
      size_t{8} << 20;  // close a chunk at this many uncompressed bytes (default 8 MiB)
  int64_t chunk_span_ns = 1'000'000'000;  // ... or when it spans this long (default 1 s)
  int zstd_level = 1;                     // 1 (fast) .. 19
  void Check() const;                     // throws std::invalid_argument
};

class RecordingWriter {
 public:
  RecordingWriter() = default;
  ~RecordingWriter();  // closes (writes index and footer) if still open; errors are lost: call
                       // Close()
  RecordingWriter(const RecordingWriter&) = delete;
  RecordingWriter& operator=(const RecordingWriter&) = delete;

  // Creates/truncates `path` and writes the header. IO_ERROR if it cannot be written.
  [[nodiscard]] Status Open(const std::string& path, const RecordingHeader& header,
                            const RecordingWriterOptions& options = {});
  // Buffers one message; may complete and write a chunk. INVALID_ARGUMENT for an unknown channel or
  // a message larger than kMaxChunkBytes; IO_ERROR if the write fails.
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
[[nodiscard]] Status OpenFileSource(const std::string& path,
                                    std::unique_ptr<ByteSource>* out);  // NOT_FOUND / IO_ERROR
std::unique_ptr<ByteSource> MemorySource(std::string bytes);

struct ChunkInfo {
  uint64_t offset = 0;  // of "CHNK"
  uint32_t compressed_size = 0;
  uint32_t uncompressed_size = 0;
  uint32_t message_count = 0;
  int64_t first_time_ns = 0;
  int64_t last_time_ns = 0;
};

// What Open (and ReadChunk, as chunks are read) found beyond the intact file: empty problems and
// index_used for a cleanly closed file.
struct RecordingDiagnostics {
  bool index_used = false;  // false: no valid index/footer (killed recorder, cut-off tail, damage)
  bool ends_before_index =
      false;  // no index after the last chunk: whatever was recorded after it is unknown
  uint64_t skipped_bytes =
      0;  // bytes between chunks that were not a valid chunk (damage, cut-off tail)
  uint64_t corrupt_chunks = 0;  // chunks lost: data failed the CRC or did not decompress (on read),
                                // or header damaged (the index lists them)
  uint64_t messages_lost =
      0;  // messages of the lost chunks whose count is known (index, chunk header)
  uint64_t uncounted_losses =
      0;  // places that lost an unknown number of messages (RecordingGap::uncounted)
  std::vector<std::string> problems;  // one line per finding, for logs and --info
  // The file is not as its writer closed it (every finding counts, even one that lost nothing).
  bool damaged() const { return !problems.empty(); }
  // "nothing", "2 chunks, 15 messages", "1 chunk, 9 messages, and an unknown number more: the file
  // ends before its index", "unknown: the file ends before its index".
  std::string LossSummary() const;
};

// Messages lost between two intact chunks (RecordingReader::gap_before), as far as the file tells.
struct RecordingGap {
  uint64_t messages = 0;   // counted: chunks the index lists whose headers are damaged
  bool uncounted = false;  // and some more whose number is unknown (bytes skipped without an index,
                           // or the file ends before its index)
  bool any() const { return messages > 0 || uncounted; }
};

class RecordingReader {
 public:
  // Reads and checks the header, then the index or (failing that) scans the chunks. PARSE_ERROR for
  // a file that is not a recording or is shorter than its header, UNSUPPORTED for a newer major
  // format, CORRUPT for a header that fails its CRC or its JSON.
  [[nodiscard]] static Status Open(std::unique_ptr<ByteSource> source,
                                   std::unique_ptr<RecordingReader>* out);
  [[nodiscard]] static Status OpenFile(const std::string& path,
                                       std::unique_ptr<RecordingReader>* out);

  const RecordingHeader& header() const { return header_; }
  const std::vector<ChunkInfo>& chunks() const { return chunks_; }
  const RecordingDiagnostics& diagnostics() const { return diagnostics_; }
  // What was lost before chunks()[i] and after chunks()[i-1]; i == chunks().size(): after the last.
  // (A chunk that fails to read is lost itself: ReadChunk's status and chunks()[i] tell.)
  const RecordingGap& gap_before(size_t i) const { return gaps_.at(i); }

  // Decompresses chunk i into *messages (replaced). CORRUPT if its CRC fails, it does not
  // decompress, or its messages are malformed (then *messages is empty and diagnostics() records
  // it). The compressed and decompressed bytes go through buffers the reader keeps, and the
  // messages already in *messages are reused: a replay that passes the same vector for every chunk
  // allocates (and page-faults) nothing once the first chunks were read.
  [[nodiscard]] Status ReadChunk(size_t i, std::vector<RecordedMessage>* messages);
  // Calls fn for every message of every intact chunk in file order; corrupt chunks are skipped and
  // recorded in diagnostics(). Stops early (returning OK) when fn returns false.
  void ForEach(const std::function<bool(const RecordedMessage&)>& fn);

 private:
  RecordingReader() = default;
  Status ParseHeader();
  struct IndexEntry {
    uint64_t offset;
    int64_t first_ns, last_ns;
    uint32_t count;
  };
  bool LoadIndex();
  void ScanChunks();
  bool ReadChunkHeader(uint64_t offset, ChunkInfo* info) const;
  // The index at `offset` if it is whole and its CRC checks out (*length: its bytes).
  bool ReadIndex(uint64_t offset, std::vector<IndexEntry>* entries, uint64_t* length) const;
  // A valid index found after the scanned chunks: counts the chunks it lists that the scan did not
  // find.
  void CountFromIndex(const std::vector<IndexEntry>& entries);
  void AddLostChunk(size_t before, const std::string& where, uint64_t messages,
                    const std::string& why);
  std::unique_ptr<ByteSource> source_;
  RecordingHeader header_;
  uint64_t data_start_ = 0;
  std::vector<ChunkInfo> chunks_;
  std::vector<bool> chunk_reported_;
  std::vector<RecordingGap> gaps_;  // chunks_.size() + 1
  RecordingDiagnostics diagnostics_;
  std::string compressed_, raw_;  // ReadChunk's buffers, kept across chunks
};

// Counts what a damaged recording lost of one channel whose messages carry consecutive sequence
// numbers (PhaseBurst's burst_seq). The caller reads the chunks in file order and reports each
// chunk (before its messages) and each message of the channel. A jump in the numbers across lost
// data is counted as lost in the file (at most as many as the lost data held, when that is known;
// the rest of the jump as missing upstream); a jump within intact data is missing upstream (lost
// before the recorder). Lost data before the first or after the last message of the channel gives a
// range: the format does not record how many of a lost chunk's messages were of which channel, so
// at most its message count, and at most as many as fit its bytes at the smallest message of the
// channel seen.
class SequenceLossCounter {
 public:
  explicit SequenceLossCounter(const RecordingReader* reader) : reader_(reader) {}
  void Chunk(size_t i, bool read_ok);  // chunks()[i] was read (read_ok) or lost; in file order
  void Message(uint64_t seq, size_t bytes);  // a message of the channel in the chunk last reported
  void End();  // after the last chunk (not when the caller stopped early)

  uint64_t lost_min() const { return lost_; }
  std::optional<uint64_t> lost_max()
      const;  // nullopt: unknown (the file ends before its index, ...)
  uint64_t missing_upstream() const { return upstream_; }
  uint64_t upstream_gaps() const { return upstream_gaps_; }  // jumps within intact data
  // "7", "0 to 7", "unknown: the file ends before its index", "at least 7, unknown: ..."
  std::string Describe() const;

 private:
  struct Lost {
    uint64_t messages, bytes;  // bytes: uncompressed, 0 if unknown
  };
  void Pass(size_t i,
            bool chunk_lost);  // the gap before chunks()[i] (and the chunk, if lost) into pending_
  uint64_t PendingBound() const;
  void ResolvePendingAsRange();
  const RecordingReader* reader_;
  size_t next_chunk_ = 0;
  std::vector<Lost> pending_;  // lost since the last message of the channel
  bool pending_uncounted_ = false;
  bool have_seq_ = false;
  uint64_t last_seq_ = 0, smallest_ = 0;
  uint64_t lost_ = 0, range_ = 0, upstream_ = 0, upstream_gaps_ = 0;
  bool unknown_ = false;
};

}  // namespace d3d
