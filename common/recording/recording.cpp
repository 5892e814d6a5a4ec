#include "common/recording/recording.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>
#include <zstd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cstring>
#include <nlohmann/json.hpp>

#include "common/core/fd_io.h"

namespace d3d {
namespace {

static_assert(std::endian::native == std::endian::little, "the recording format is little endian");

constexpr char kMagic[8] = {'\x89', 'D', '3', 'D', 'R', 'E', 'C', '\n'};
constexpr char kEndMagic[8] = {'D', '3', 'D', 'E', 'N', 'D', '\r', '\n'};
constexpr size_t kChunkHeaderBytes = 40;
constexpr size_t kFooterBytes = 24;
constexpr size_t kMessageHeaderBytes = 14;
constexpr size_t kIndexEntryBytes = 28;
constexpr size_t kMaxHeaderJson = size_t{16} << 20;

uint32_t Crc32(std::string_view b) {
  return static_cast<uint32_t>(
      crc32(0L, reinterpret_cast<const Bytef*>(b.data()), static_cast<uInt>(b.size())));
}
template <typename T>
void Put(std::string* s, T v) {
  char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  s->append(b, sizeof(T));
}
template <typename T>
T Get(std::string_view s, size_t at) {
  T v;
  std::memcpy(&v, s.data() + at, sizeof(T));
  return v;
}
std::string Hex(uint64_t v) {
  char b[24];
  std::snprintf(b, sizeof b, "%llu", static_cast<unsigned long long>(v));
  return b;
}

class FileSource final : public ByteSource {
 public:
  FileSource(int fd, uint64_t size) : fd_(fd), size_(size) {}
  ~FileSource() override { ::close(fd_); }
  uint64_t size() const override { return size_; }
  bool Read(uint64_t offset, size_t n, std::string* out) const override {
    if (offset > size_ || n > size_ - offset) return false;
    out->resize(n);
    return PreadFull(fd_, out->data(), n, offset) == n;
  }

 private:
  int fd_;
  uint64_t size_;
};

class MemSource final : public ByteSource {
 public:
  explicit MemSource(std::string b) : b_(std::move(b)) {}
  uint64_t size() const override { return b_.size(); }
  bool Read(uint64_t offset, size_t n, std::string* out) const override {
    if (offset > b_.size() || n > b_.size() - offset) return false;
    out->assign(b_, static_cast<size_t>(offset), n);
    return true;
  }

 private:
  std::string b_;
};

}  // namespace

const RecordingChannel* RecordingHeader::FindTopic(std::string_view topic) const {
  for (const auto& c : channels)
    if (c.topic == topic) return &c;
  return nullptr;
}

void RecordingWriterOptions::Check() const {
  D3D_CHECK_MSG(chunk_bytes >= 256 && chunk_bytes <= kMaxChunkBytes,
                "chunk_bytes must be in [256 B, 64 MiB], got " << chunk_bytes);
  D3D_CHECK_MSG(chunk_span_ns > 0, "chunk_span_ns must be positive");
  D3D_CHECK_MSG(zstd_level >= 1 && zstd_level <= 19,
                "zstd_level must be in 1..19, got " << zstd_level);
}

// ----------------------------------------------------------------------------------------------
// writer

RecordingWriter::~RecordingWriter() {
  if (fd_ >= 0) (void)Close();
}

Status RecordingWriter::WriteAll(std::string_view bytes) {
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t w = ::write(fd_, bytes.data() + done, bytes.size() - done);
    if (w < 0 && errno == EINTR) continue;
    if (w < 0) return IoError(std::string("recording write: ") + std::strerror(errno));
    done += static_cast<size_t>(w);
  }
  offset_ += bytes.size();
  return Status::Ok();
}

Status RecordingWriter::Open(const std::string& path, const RecordingHeader& header,
                             const RecordingWriterOptions& options) {
  options.Check();
  D3D_CHECK_MSG(fd_ < 0, "RecordingWriter is already open");
  options_ = options;
  nlohmann::json j;
  j["protocol_version"] = header.protocol_version;
  j["created_ns"] = header.created_ns;
  j["probe_serial"] = header.probe_serial;
  j["calibration_json"] = header.calibration_json;
  j["channels"] = nlohmann::json::array();
  known_channel_.assign(65536, false);
  for (const auto& c : header.channels) {
    D3D_CHECK_MSG(!known_channel_[c.id], "duplicate channel id " << c.id);
    known_channel_[c.id] = true;
    j["channels"].push_back({{"id", c.id}, {"topic", c.topic}, {"schema", c.schema}});
  }
  j["metadata"] = header.metadata;
  const std::string json = j.dump();
  std::string h(kMagic, 8);
  Put<uint16_t>(&h, kRecordingMajor);
  Put<uint16_t>(&h, kRecordingMinor);
  Put<uint32_t>(&h, static_cast<uint32_t>(json.size()));
  h.append(json);
  Put<uint32_t>(&h, Crc32(h));

  fd_ = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd_ < 0) return IoError("cannot create recording '" + path + "': " + std::strerror(errno));
  offset_ = 0;
  messages_ = 0;
  index_.clear();
  pending_.clear();
  pending_count_ = 0;
  return WriteAll(h);
}

Status RecordingWriter::Add(uint16_t channel, int64_t log_time_ns, std::string_view data) {
  D3D_CHECK_MSG(fd_ >= 0, "RecordingWriter is not open");
  if (!known_channel_[channel])
    return InvalidArgument("recording: message on undeclared channel " + std::to_string(channel));
  if (data.size() + kMessageHeaderBytes > kMaxChunkBytes)
    return InvalidArgument("recording: message of " + Hex(data.size()) + " bytes exceeds 64 MiB");
  if (pending_count_ > 0 && (pending_.size() + data.size() + kMessageHeaderBytes > kMaxChunkBytes))
    D3D_RETURN_IF_ERROR(Flush());
  if (pending_count_ == 0) first_ns_ = log_time_ns;
  last_ns_ = log_time_ns;
  Put<uint16_t>(&pending_, channel);
  Put<int64_t>(&pending_, log_time_ns);
  Put<uint32_t>(&pending_, static_cast<uint32_t>(data.size()));
  pending_.append(data);
  ++pending_count_;
  ++messages_;
  if (pending_.size() >= options_.chunk_bytes || last_ns_ - first_ns_ >= options_.chunk_span_ns)
    return Flush();
  return Status::Ok();
}

Status RecordingWriter::Flush() {
  if (fd_ < 0 || pending_count_ == 0) return Status::Ok();
  compressed_.resize(ZSTD_compressBound(pending_.size()));
  const size_t c = ZSTD_compress(compressed_.data(), compressed_.size(), pending_.data(),
                                 pending_.size(), options_.zstd_level);
  if (ZSTD_isError(c)) return {StatusCode::kInternal, std::string("zstd: ") + ZSTD_getErrorName(c)};
  compressed_.resize(c);
  std::string h("CHNK");
  Put<uint32_t>(&h, static_cast<uint32_t>(c));
  Put<uint32_t>(&h, static_cast<uint32_t>(pending_.size()));
  Put<uint32_t>(&h, pending_count_);
  Put<int64_t>(&h, first_ns_);
  Put<int64_t>(&h, last_ns_);
  Put<uint32_t>(&h, Crc32(compressed_));
  Put<uint32_t>(&h, Crc32(h));
  index_.push_back({offset_, first_ns_, last_ns_, pending_count_});
  h.append(compressed_);  // one write: a killed recorder leaves whole chunks or a cut-off last one
  pending_.clear();
  pending_count_ = 0;
  return WriteAll(h);
}

Status RecordingWriter::Close() {
  if (fd_ < 0) return Status::Ok();
  Status s = Flush();
  if (s.ok()) {
    const uint64_t index_offset = offset_;
    std::string ix("INDX");
    Put<uint32_t>(&ix, static_cast<uint32_t>(index_.size()));
    for (const auto& e : index_) {
      Put<uint64_t>(&ix, e.offset);
      Put<int64_t>(&ix, e.first_ns);
      Put<int64_t>(&ix, e.last_ns);
      Put<uint32_t>(&ix, e.count);
    }
    Put<uint32_t>(&ix, Crc32(ix));
    std::string f("FOOT");
    Put<uint64_t>(&f, index_offset);
    Put<uint32_t>(&f, Crc32(f));
    f.append(kEndMagic, 8);
    ix.append(f);
    s = WriteAll(ix);
  }
  if (::close(fd_) != 0 && s.ok())
    s = IoError(std::string("recording close: ") + std::strerror(errno));
  fd_ = -1;
  return s;
}

// ----------------------------------------------------------------------------------------------
// reader

Status OpenFileSource(const std::string& path, std::unique_ptr<ByteSource>* out) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    if (errno == ENOENT) return NotFound("no such recording: '" + path + "'");
    return IoError("cannot open recording '" + path + "': " + std::strerror(errno));
  }
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    return IoError("'" + path + "' is not a regular file");
  }
  *out = std::make_unique<FileSource>(fd, static_cast<uint64_t>(st.st_size));
  return Status::Ok();
}

std::unique_ptr<ByteSource> MemorySource(std::string bytes) {
  return std::make_unique<MemSource>(std::move(bytes));
}

Status RecordingReader::OpenFile(const std::string& path, std::unique_ptr<RecordingReader>* out) {
  std::unique_ptr<ByteSource> src;
  D3D_RETURN_IF_ERROR(OpenFileSource(path, &src));
  return Open(std::move(src), out);
}

Status RecordingReader::Open(std::unique_ptr<ByteSource> source,
                             std::unique_ptr<RecordingReader>* out) {
  std::unique_ptr<RecordingReader> r(new RecordingReader());
  r->source_ = std::move(source);
  D3D_RETURN_IF_ERROR(r->ParseHeader());
  if (!r->LoadIndex()) r->ScanChunks();
  r->chunk_reported_.assign(r->chunks_.size(), false);
  for (const RecordingGap& g : r->gaps_) r->diagnostics_.uncounted_losses += g.uncounted;
  *out = std::move(r);
  return Status::Ok();
}

Status RecordingReader::ParseHeader() {
  std::string b;
  if (!source_->Read(0, 16, &b))
    return ParseError("not a d3d recording: shorter than its 16-byte header");
  if (std::memcmp(b.data(), kMagic, 8) != 0) return ParseError("not a d3d recording: wrong magic");
  header_.format_major = Get<uint16_t>(b, 8);
  header_.format_minor = Get<uint16_t>(b, 10);
  // The CRC first: the version fields of a damaged header (or random bytes after the magic) say
  // nothing.
  const uint32_t json_len = Get<uint32_t>(b, 12);
  if (json_len > kMaxHeaderJson)
    return Corrupt("recording header damaged: its length field says " + Hex(json_len) +
                   " bytes (at most " + Hex(kMaxHeaderJson) + ")");
  std::string all;
  if (!source_->Read(0, 16 + size_t{json_len} + 4, &all))
    return Corrupt("recording header damaged or cut off: the file ends within the " +
                   Hex(16 + uint64_t{json_len} + 4) + " bytes its length field says");
  if (Crc32(std::string_view(all).substr(0, 16 + json_len)) != Get<uint32_t>(all, 16 + json_len))
    return Corrupt(
        "recording header damaged: CRC mismatch (its fields, the format version among them, cannot "
        "be trusted)");
  if (header_.format_major > kRecordingMajor)
    return Unsupported("recording format " + std::to_string(header_.format_major) + "." +
                       std::to_string(header_.format_minor) + " is newer than this reader (" +
                       std::to_string(kRecordingMajor) + ".x): update d3dscan");
  if (header_.format_major == 0)
    return Corrupt("recording header: format field 0." + std::to_string(header_.format_minor) +
                   " is no format version");
  const nlohmann::json j =
      nlohmann::json::parse(all.begin() + 16, all.begin() + 16 + json_len, nullptr, false);
  if (j.is_discarded() || !j.is_object())
    return Corrupt("recording header: its JSON does not parse");
  const char* field = "";
  try {
    field = "protocol_version";
    header_.protocol_version = j.at(field).get<int>();
    field = "created_ns";
    header_.created_ns = j.at(field).get<int64_t>();
    field = "probe_serial";
    header_.probe_serial = j.at(field).get<std::string>();
    field = "calibration_json";
    header_.calibration_json = j.at(field).get<std::string>();
    field = "channels";
    for (const auto& c : j.at(field)) {
      header_.channels.push_back({c.at("id").get<uint16_t>(), c.at("topic").get<std::string>(),
                                  c.at("schema").get<std::string>()});
    }
    field = "metadata";
    if (j.contains(field)) header_.metadata = j.at(field).get<std::map<std::string, std::string>>();
  } catch (const nlohmann::json::exception&) {
    return Corrupt(std::string("recording header: field '") + field +
                   "' is missing or not of its type");
  }
  data_start_ = 16 + uint64_t{json_len} + 4;
  return Status::Ok();
}

bool RecordingReader::ReadChunkHeader(uint64_t offset, ChunkInfo* info) const {
  std::string b;
  if (!source_->Read(offset, kChunkHeaderBytes, &b)) return false;
  if (std::memcmp(b.data(), "CHNK", 4) != 0) return false;
  if (Crc32(std::string_view(b).substr(0, 36)) != Get<uint32_t>(b, 36)) return false;
  info->offset = offset;
  info->compressed_size = Get<uint32_t>(b, 4);
  info->uncompressed_size = Get<uint32_t>(b, 8);
  info->message_count = Get<uint32_t>(b, 12);
  info->first_time_ns = Get<int64_t>(b, 16);
  info->last_time_ns = Get<int64_t>(b, 24);
  if (info->uncompressed_size > kMaxChunkBytes) return false;
  // The whole chunk must be in the file (a cut-off last chunk is not a chunk).
  return offset + kChunkHeaderBytes + info->compressed_size <= source_->size();
}

bool RecordingReader::ReadIndex(uint64_t offset, std::vector<IndexEntry>* entries,
                                uint64_t* length) const {
  std::string h;
  if (!source_->Read(offset, 8, &h) || std::memcmp(h.data(), "INDX", 4) != 0) return false;
  const uint64_t n = Get<uint32_t>(h, 4);
  const uint64_t len = 8 + n * kIndexEntryBytes + 4;
  if (len > source_->size() - offset) return false;
  std::string ix;
  if (!source_->Read(offset, len, &ix) ||
      Crc32(std::string_view(ix).substr(0, len - 4)) != Get<uint32_t>(ix, len - 4))
    return false;
  entries->clear();
  for (uint64_t i = 0; i < n; ++i) {
    const size_t at = 8 + i * kIndexEntryBytes;
    entries->push_back({Get<uint64_t>(ix, at), Get<int64_t>(ix, at + 8), Get<int64_t>(ix, at + 16),
                        Get<uint32_t>(ix, at + 24)});
  }
  *length = len;
  return true;
}

void RecordingReader::AddLostChunk(size_t before, const std::string& where, uint64_t messages,
                                   const std::string& why) {
  ++diagnostics_.corrupt_chunks;
  diagnostics_.messages_lost += messages;
  gaps_[before].messages += messages;
  diagnostics_.problems.push_back(where + ": " + why + ": its " + Hex(messages) +
                                  " messages are lost");
}

bool RecordingReader::LoadIndex() {
  const uint64_t size = source_->size();
  std::string f;
  if (size < data_start_ + kFooterBytes || !source_->Read(size - kFooterBytes, kFooterBytes, &f))
    return false;
  if (std::memcmp(f.data(), "FOOT", 4) != 0 || std::memcmp(f.data() + 16, kEndMagic, 8) != 0 ||
      Crc32(std::string_view(f).substr(0, 12)) != Get<uint32_t>(f, 12))
    return false;
  const uint64_t ix_off = Get<uint64_t>(f, 4);
  std::vector<IndexEntry> entries;
  uint64_t ix_len = 0;
  if (ix_off < data_start_ || ix_off > size - kFooterBytes ||
      !ReadIndex(ix_off, &entries, &ix_len) || ix_off + ix_len != size - kFooterBytes)
    return false;
  gaps_.assign(1, RecordingGap{});
  for (size_t i = 0; i < entries.size(); ++i) {
    const IndexEntry& e = entries[i];
    ChunkInfo c;
    if (e.offset < data_start_ || e.offset >= ix_off || !ReadChunkHeader(e.offset, &c)) {
      AddLostChunk(chunks_.size(),
                   "chunk " + std::to_string(i) + " of the index at offset " + Hex(e.offset),
                   e.count, "header damaged");
      continue;
    }
    chunks_.push_back(c);
    gaps_.emplace_back();
  }
  diagnostics_.index_used = true;
  return true;
}

void RecordingReader::CountFromIndex(const std::vector<IndexEntry>& entries) {
  for (RecordingGap& g : gaps_)
    g.uncounted = false;  // the index lists every chunk: skipped bytes held no other
  size_t scanned = 0;     // chunks_ and entries are both in file order
  for (size_t i = 0; i < entries.size(); ++i) {
    const IndexEntry& e = entries[i];
    while (scanned < chunks_.size() && chunks_[scanned].offset < e.offset) ++scanned;
    if (scanned < chunks_.size() && chunks_[scanned].offset == e.offset) continue;
    AddLostChunk(scanned, "chunk " + std::to_string(i) + " of the index at offset " + Hex(e.offset),
                 e.count, "not found intact");
  }
}

void RecordingReader::ScanChunks() {
  const uint64_t size = source_->size();
  gaps_.assign(1, RecordingGap{});
  uint64_t pos = data_start_;
  uint64_t bad_from = 0;
  bool in_bad = false;
  auto end_bad = [&](uint64_t at) {
    if (!in_bad) return;
    diagnostics_.skipped_bytes += at - bad_from;
    diagnostics_.problems.push_back("skipped " + Hex(at - bad_from) + " bytes at offset " +
                                    Hex(bad_from) + " that are no intact chunk");
    gaps_.back().uncounted = true;  // unless an index tells (CountFromIndex)
    in_bad = false;
  };
  std::vector<IndexEntry> entries;
  uint64_t ix_len = 0;
  bool index_reached = false, index_valid = false;
  std::string window;
  while (pos + 4 <= size) {
    ChunkInfo c;
    if (ReadChunkHeader(pos, &c)) {
      end_bad(pos);
      chunks_.push_back(c);
      gaps_.emplace_back();
      pos += kChunkHeaderBytes + c.compressed_size;
      continue;
    }
    // The index ends the chunks: right after the last intact chunk (even when it is damaged
    // itself), or after damage when it checks out.
    std::string m;
    if (source_->Read(pos, 4, &m) && m == "INDX") {
      index_valid = ReadIndex(pos, &entries, &ix_len);
      if (!in_bad || index_valid) {
        index_reached = true;
        break;
      }
    }
    if (!in_bad) {
      in_bad = true;
      bad_from = pos;
    }
    // Re-synchronise: the next "CHNK" or "INDX" after pos (read in 1 MiB windows).
    uint64_t next = size;
    for (uint64_t w = pos + 1; w + 4 <= size && next == size; w += (size_t{1} << 20)) {
      const size_t n = static_cast<size_t>(std::min<uint64_t>((size_t{1} << 20) + 3, size - w));
      if (!source_->Read(w, n, &window)) break;
      const size_t at = std::min(window.find("CHNK"), window.find("INDX"));
      if (at != std::string::npos) next = w + at;
    }
    pos = next;
  }
  if (!index_reached && pos < size &&
      !in_bad) {  // fewer than 4 bytes after the last chunk: the index's start?
    std::string tail;
    index_reached = source_->Read(pos, size - pos, &tail) &&
                    std::string_view("INDX").substr(0, tail.size()) == tail;
    in_bad = !index_reached;
    bad_from = pos;
  }
  end_bad(index_reached ? pos : size);
  if (!index_reached) {
    diagnostics_.ends_before_index = true;
    gaps_.back().uncounted = true;
    diagnostics_.problems.push_back(
        "the file ends before its index: the recording was not closed (a killed recorder) or was "
        "cut off; what it held after offset " +
        Hex(chunks_.empty()
                ? data_start_
                : chunks_.back().offset + kChunkHeaderBytes + chunks_.back().compressed_size) +
        " is unknown");
    return;
  }
  if (!index_valid) {
    diagnostics_.problems.push_back(
        "index at offset " + Hex(pos) + " damaged or cut off" +
        (diagnostics_.skipped_bytes == 0
             ? std::string(": the chunks before it follow each other without a gap, none is lost")
             : ""));
    return;
  }
  CountFromIndex(entries);
  // After the index: its footer, and nothing else.
  const uint64_t end = pos + ix_len;
  std::string f;
  const bool footer = end + kFooterBytes <= size && source_->Read(end, kFooterBytes, &f) &&
                      std::memcmp(f.data(), "FOOT", 4) == 0 && Get<uint64_t>(f, 4) == pos &&
                      Crc32(std::string_view(f).substr(0, 12)) == Get<uint32_t>(f, 12) &&
                      std::memcmp(f.data() + 16, kEndMagic, 8) == 0;
  if (!footer) {
    diagnostics_.problems.push_back("footer at offset " + Hex(end) +
                                    " damaged or missing (the index before it checks out)");
  } else if (size > end + kFooterBytes) {
    diagnostics_.problems.push_back(
        Hex(size - end - kFooterBytes) +
        " bytes after the end of the recording (its footer ends at offset " +
        Hex(end + kFooterBytes) + "): not part of it");
  }
}

Status RecordingReader::ReadChunk(size_t i, std::vector<RecordedMessage>* messages) {
  D3D_CHECK_MSG(i < chunks_.size(), "chunk " << i << " of " << chunks_.size());
  const ChunkInfo& c = chunks_[i];
  auto fail = [&](const std::string& why) {
    const std::string m = "chunk " + std::to_string(i) + " at offset " + Hex(c.offset) + ": " + why;
    if (!chunk_reported_[i]) {
      chunk_reported_[i] = true;
      ++diagnostics_.corrupt_chunks;
      diagnostics_.messages_lost += c.message_count;
      diagnostics_.problems.push_back(m + ": its " + Hex(c.message_count) + " messages are lost");
    }
    messages->clear();
    return Corrupt(m);
  };
  std::string& b = compressed_;
  if (!source_->Read(c.offset, kChunkHeaderBytes + c.compressed_size, &b)) return fail("cut off");
  const std::string_view data = std::string_view(b).substr(kChunkHeaderBytes);
  if (Crc32(data) != Get<uint32_t>(b, 32)) return fail("data CRC mismatch");
  const unsigned long long content = ZSTD_getFrameContentSize(data.data(), data.size());
  if (content != c.uncompressed_size) return fail("zstd frame size differs from the chunk header");
  std::string& raw = raw_;
  raw.resize(c.uncompressed_size);  // zero-fills only what the buffer had never held
  const size_t d = ZSTD_decompress(raw.data(), raw.size(), data.data(), data.size());
  if (ZSTD_isError(d) || d != raw.size()) return fail("does not decompress");
  size_t at = 0, count = 0;
  while (at < raw.size()) {
    if (raw.size() - at < kMessageHeaderBytes) return fail("message header cut off");
    if (count == messages->size()) messages->emplace_back();
    RecordedMessage& m = (*messages)[count++];  // an earlier chunk's message: its buffer is reused
    m.channel = Get<uint16_t>(raw, at);
    m.log_time_ns = Get<int64_t>(raw, at + 2);
    const uint32_t n = Get<uint32_t>(raw, at + 10);
    at += kMessageHeaderBytes;
    if (raw.size() - at < n) return fail("message cut off");
    m.data.assign(raw, at, n);
    at += n;
  }
  messages->resize(count);
  if (messages->size() != c.message_count)
    return fail("message count differs from the chunk header");
  return Status::Ok();
}

void RecordingReader::ForEach(const std::function<bool(const RecordedMessage&)>& fn) {
  std::vector<RecordedMessage> msgs;
  for (size_t i = 0; i < chunks_.size(); ++i) {
    if (!ReadChunk(i, &msgs).ok()) continue;
    for (const auto& m : msgs)
      if (!fn(m)) return;
  }
}

// -------------------------------------------------------------------------------------------
// losses

std::string RecordingDiagnostics::LossSummary() const {
  std::string s;
  if (corrupt_chunks > 0)
    s = Hex(corrupt_chunks) + (corrupt_chunks == 1 ? " chunk, " : " chunks, ") +
        Hex(messages_lost) + (messages_lost == 1 ? " message" : " messages");
  if (uncounted_losses > 0) {
    const std::string why = ends_before_index
                                ? "the file ends before its index"
                                : "bytes were skipped with no index to count their messages";
    s = s.empty() ? "unknown: " + why : s + ", and an unknown number more: " + why;
  }
  return s.empty() ? "nothing" : s;
}

uint64_t SequenceLossCounter::PendingBound() const {
  uint64_t n = 0;
  for (const Lost& l : pending_)
    n += l.bytes > 0 && smallest_ > 0
             ? std::min<uint64_t>(l.messages, l.bytes / (kMessageHeaderBytes + smallest_))
             : l.messages;
  return n;
}

void SequenceLossCounter::ResolvePendingAsRange() {
  range_ += PendingBound();
  unknown_ = unknown_ || pending_uncounted_;
  pending_.clear();
  pending_uncounted_ = false;
}

void SequenceLossCounter::Pass(size_t i, bool chunk_lost) {
  const RecordingGap& g = reader_->gap_before(i);
  if (g.messages > 0) pending_.push_back({g.messages, 0});
  pending_uncounted_ = pending_uncounted_ || g.uncounted;
  if (chunk_lost)
    pending_.push_back(
        {reader_->chunks()[i].message_count, reader_->chunks()[i].uncompressed_size});
}

void SequenceLossCounter::Chunk(size_t i, bool read_ok) {
  D3D_CHECK_MSG(i >= next_chunk_ && i < reader_->chunks().size(),
                "SequenceLossCounter: chunk " << i << " out of order");
  while (next_chunk_ < i)
    Pass(next_chunk_++, true);  // a chunk the caller did not read is lost to it
  Pass(next_chunk_++, !read_ok);
}

void SequenceLossCounter::Message(uint64_t seq, size_t bytes) {
  smallest_ = smallest_ == 0 ? bytes : std::min<uint64_t>(smallest_, bytes);
  if (!have_seq_ || seq <= last_seq_) {
    ResolvePendingAsRange();  // before the first number (or a restart): how many is not recorded
  } else {
    const uint64_t jump = seq - last_seq_ - 1;
    uint64_t in_file = 0;
    if (!pending_.empty() || pending_uncounted_)
      in_file = pending_uncounted_ ? jump : std::min(jump, PendingBound());
    lost_ += in_file;
    upstream_ += jump - in_file;
    upstream_gaps_ += jump > in_file;
    pending_.clear();
    pending_uncounted_ = false;
  }
  have_seq_ = true;
  last_seq_ = seq;
}

void SequenceLossCounter::End() {
  while (next_chunk_ < reader_->chunks().size()) Pass(next_chunk_++, true);
  Pass(reader_->chunks().size(), false);  // after the last chunk
  ResolvePendingAsRange();
}

std::optional<uint64_t> SequenceLossCounter::lost_max() const {
  if (unknown_) return std::nullopt;
  return lost_ + range_;
}

std::string SequenceLossCounter::Describe() const {
  if (unknown_) {
    const std::string why = reader_->diagnostics().ends_before_index
                                ? "the file ends before its index"
                                : "bytes were skipped with no index to count them";
    return lost_ == 0 ? "unknown: " + why : "at least " + Hex(lost_) + ", unknown beyond: " + why;
  }
  return range_ == 0 ? Hex(lost_) : Hex(lost_) + " to " + Hex(lost_ + range_);
}

}  // namespace d3d
