#include "common/recording/recording.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>
#include <zstd.h>

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
constexpr size_t kMaxHeaderJson = size_t{16} << 20;

uint32_t Crc32(std::string_view b) {
  return static_cast<uint32_t>(crc32(0L, reinterpret_cast<const Bytef*>(b.data()), static_cast<uInt>(b.size())));
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
  D3D_CHECK_MSG(chunk_bytes >= 256 && chunk_bytes <= kMaxChunkBytes, "chunk_bytes must be in [256 B, 64 MiB], got " << chunk_bytes);
  D3D_CHECK_MSG(chunk_span_ns > 0, "chunk_span_ns must be positive");
  D3D_CHECK_MSG(zstd_level >= 1 && zstd_level <= 19, "zstd_level must be in 1..19, got " << zstd_level);
}

// ---------------------------------------------------------------------------------------------- writer

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

Status RecordingWriter::Open(const std::string& path, const RecordingHeader& header, const RecordingWriterOptions& options) {
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
  if (!known_channel_[channel]) return InvalidArgument("recording: message on undeclared channel " + std::to_string(channel));
  if (data.size() + kMessageHeaderBytes > kMaxChunkBytes) return InvalidArgument("recording: message of " + Hex(data.size()) + " bytes exceeds 64 MiB");
  if (pending_count_ > 0 && (pending_.size() + data.size() + kMessageHeaderBytes > kMaxChunkBytes)) D3D_RETURN_IF_ERROR(Flush());
  if (pending_count_ == 0) first_ns_ = log_time_ns;
  last_ns_ = log_time_ns;
  Put<uint16_t>(&pending_, channel);
  Put<int64_t>(&pending_, log_time_ns);
  Put<uint32_t>(&pending_, static_cast<uint32_t>(data.size()));
  pending_.append(data);
  ++pending_count_;
  ++messages_;
  if (pending_.size() >= options_.chunk_bytes || last_ns_ - first_ns_ >= options_.chunk_span_ns) return Flush();
  return Status::Ok();
}

Status RecordingWriter::Flush() {
  if (fd_ < 0 || pending_count_ == 0) return Status::Ok();
  compressed_.resize(ZSTD_compressBound(pending_.size()));
  const size_t c = ZSTD_compress(compressed_.data(), compressed_.size(), pending_.data(), pending_.size(), options_.zstd_level);
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
  if (::close(fd_) != 0 && s.ok()) s = IoError(std::string("recording close: ") + std::strerror(errno));
  fd_ = -1;
  return s;
}

// ---------------------------------------------------------------------------------------------- reader

Status OpenFileSource(const std::string& path, std::unique_ptr<ByteSource>* out) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    if (errno == ENOENT) return NotFound("no such recording: '" + path + "'");
    return IoError("cannot open recording '" + path + "': " + std::strerror(errno));
  }
  struct stat st{};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    return IoError("'" + path + "' is not a regular file");
  }
  *out = std::make_unique<FileSource>(fd, static_cast<uint64_t>(st.st_size));
  return Status::Ok();
}

std::unique_ptr<ByteSource> MemorySource(std::string bytes) { return std::make_unique<MemSource>(std::move(bytes)); }

Status RecordingReader::OpenFile(const std::string& path, std::unique_ptr<RecordingReader>* out) {
  std::unique_ptr<ByteSource> src;
  D3D_RETURN_IF_ERROR(OpenFileSource(path, &src));
  return Open(std::move(src), out);
}

Status RecordingReader::Open(std::unique_ptr<ByteSource> source, std::unique_ptr<RecordingReader>* out) {
  std::unique_ptr<RecordingReader> r(new RecordingReader());
  r->source_ = std::move(source);
  D3D_RETURN_IF_ERROR(r->ParseHeader());
  if (!r->LoadIndex()) r->ScanChunks();
  r->chunk_reported_.assign(r->chunks_.size(), false);
  *out = std::move(r);
  return Status::Ok();
}

Status RecordingReader::ParseHeader() {
  std::string b;
  if (!source_->Read(0, 16, &b)) return ParseError("not a d3d recording: shorter than its 16-byte header");
  if (std::memcmp(b.data(), kMagic, 8) != 0) return ParseError("not a d3d recording: wrong magic");
  header_.format_major = Get<uint16_t>(b, 8);
  header_.format_minor = Get<uint16_t>(b, 10);
  if (header_.format_major > kRecordingMajor)
    return Unsupported("recording format " + std::to_string(header_.format_major) + "." + std::to_string(header_.format_minor) +
                       " is newer than this reader (" + std::to_string(kRecordingMajor) + ".x): update d3dscan");
  if (header_.format_major == 0) return ParseError("recording format 0.x does not exist");
  const uint32_t json_len = Get<uint32_t>(b, 12);
  if (json_len > kMaxHeaderJson) return Corrupt("recording header: implausible length " + std::to_string(json_len));
  std::string all;
  if (!source_->Read(0, 16 + size_t{json_len} + 4, &all)) return Corrupt("recording header: cut off");
  if (Crc32(std::string_view(all).substr(0, 16 + json_len)) != Get<uint32_t>(all, 16 + json_len))
    return Corrupt("recording header: CRC mismatch");
  const nlohmann::json j = nlohmann::json::parse(all.begin() + 16, all.begin() + 16 + json_len, nullptr, false);
  if (j.is_discarded() || !j.is_object()) return Corrupt("recording header: JSON does not parse");
  try {
    header_.protocol_version = j.at("protocol_version").get<int>();
    header_.created_ns = j.at("created_ns").get<int64_t>();
    header_.probe_serial = j.at("probe_serial").get<std::string>();
    header_.calibration_json = j.at("calibration_json").get<std::string>();
    for (const auto& c : j.at("channels")) {
      header_.channels.push_back({c.at("id").get<uint16_t>(), c.at("topic").get<std::string>(), c.at("schema").get<std::string>()});
    }
    if (j.contains("metadata")) header_.metadata = j.at("metadata").get<std::map<std::string, std::string>>();
  } catch (const nlohmann::json::exception& e) {
    return Corrupt(std::string("recording header: ") + e.what());
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

bool RecordingReader::LoadIndex() {
  const uint64_t size = source_->size();
  std::string f;
  if (size < data_start_ + kFooterBytes || !source_->Read(size - kFooterBytes, kFooterBytes, &f)) {
    diagnostics_.problems.push_back("no footer: the recording was not closed (killed recorder or cut-off tail); chunks scanned");
    return false;
  }
  if (std::memcmp(f.data(), "FOOT", 4) != 0 || std::memcmp(f.data() + 16, kEndMagic, 8) != 0 ||
      Crc32(std::string_view(f).substr(0, 12)) != Get<uint32_t>(f, 12)) {
    diagnostics_.problems.push_back("no valid footer: the recording was not closed or its tail is damaged; chunks scanned");
    return false;
  }
  const uint64_t ix_off = Get<uint64_t>(f, 4);
  std::string h;
  if (ix_off < data_start_ || ix_off > size - kFooterBytes || !source_->Read(ix_off, 8, &h) || std::memcmp(h.data(), "INDX", 4) != 0) {
    diagnostics_.problems.push_back("footer points at no index; chunks scanned");
    return false;
  }
  const uint64_t n = Get<uint32_t>(h, 4);
  const uint64_t ix_len = 8 + n * 28 + 4;
  std::string ix;
  if (ix_off + ix_len != size - kFooterBytes || !source_->Read(ix_off, ix_len, &ix) ||
      Crc32(std::string_view(ix).substr(0, ix_len - 4)) != Get<uint32_t>(ix, ix_len - 4)) {
    diagnostics_.problems.push_back("index damaged; chunks scanned");
    return false;
  }
  std::vector<ChunkInfo> chunks;
  for (uint64_t i = 0; i < n; ++i) {
    const uint64_t off = Get<uint64_t>(ix, 8 + i * 28);
    ChunkInfo c;
    if (off < data_start_ || off >= ix_off || !ReadChunkHeader(off, &c)) {
      diagnostics_.problems.push_back("index entry " + std::to_string(i) + " points at no valid chunk; chunks scanned");
      return false;
    }
    chunks.push_back(c);
  }
  chunks_ = std::move(chunks);
  diagnostics_.index_used = true;
  return true;
}

void RecordingReader::ScanChunks() {
  const uint64_t size = source_->size();
  uint64_t pos = data_start_;
  uint64_t bad_from = 0;
  bool in_bad = false;
  auto end_bad = [&](uint64_t at) {
    if (!in_bad) return;
    diagnostics_.skipped_bytes += at - bad_from;
    diagnostics_.problems.push_back("skipped " + Hex(at - bad_from) + " bytes at offset " + Hex(bad_from) + " that are no intact chunk");
    in_bad = false;
  };
  std::string window;
  while (pos + 4 <= size) {
    ChunkInfo c;
    if (ReadChunkHeader(pos, &c)) {
      end_bad(pos);
      chunks_.push_back(c);
      pos += kChunkHeaderBytes + c.compressed_size;
      continue;
    }
    // A clean index + footer after the last chunk ends the data (footer damaged, index intact).
    std::string m;
    if (source_->Read(pos, 4, &m) && m == "INDX" && !in_bad) break;
    if (!in_bad) {
      in_bad = true;
      bad_from = pos;
    }
    // Re-synchronise: the next "CHNK" after pos (read in 1 MiB windows).
    uint64_t next = size;
    for (uint64_t w = pos + 1; w + 4 <= size && next == size; w += (size_t{1} << 20)) {
      const size_t n = static_cast<size_t>(std::min<uint64_t>((size_t{1} << 20) + 3, size - w));
      if (!source_->Read(w, n, &window)) break;
      const size_t at = window.find("CHNK");
      if (at != std::string::npos) next = w + at;
    }
    pos = next;
  }
  if (pos < size && !in_bad) {
    // Whatever follows the last chunk: index + footer of a closed file whose footer was damaged, or a
    // cut-off chunk.
    std::string m;
    if (!(source_->Read(pos, 4, &m) && m == "INDX")) {
      in_bad = true;
      bad_from = pos;
    }
  }
  end_bad(in_bad ? size : pos);
}

Status RecordingReader::ReadChunk(size_t i, std::vector<RecordedMessage>* messages) {
  D3D_CHECK_MSG(i < chunks_.size(), "chunk " << i << " of " << chunks_.size());
  const ChunkInfo& c = chunks_[i];
  auto fail = [&](const std::string& why) {
    const std::string m = "chunk " + std::to_string(i) + " at offset " + Hex(c.offset) + ": " + why;
    if (!chunk_reported_[i]) {
      chunk_reported_[i] = true;
      ++diagnostics_.corrupt_chunks;
      diagnostics_.problems.push_back(m);
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
  if (messages->size() != c.message_count) return fail("message count differs from the chunk header");
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

}  // namespace d3d
