#include "protocol/codec.h"

#include <bit>
#include <cstring>
#include <type_traits>

namespace d3d::proto {
namespace {

class Writer {
 public:
  explicit Writer(std::string* out) : out_(out) {}
  template <typename T>
  void Put(T v) {
    static_assert(std::is_arithmetic_v<T>);
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));  // x86-64 / aarch64: little endian (static_assert below)
    out_->append(b, sizeof(T));
  }
  void Bytes(const void* p, size_t n) {
    Put(static_cast<uint32_t>(n));
    out_->append(static_cast<const char*>(p), n);
  }
  void Str(const std::string& s) { Bytes(s.data(), s.size()); }

 private:
  std::string* out_;
};
static_assert(std::endian::native == std::endian::little,
              "the recording codec assumes a little-endian host");

class Reader {
 public:
  explicit Reader(std::string_view b) : b_(b) {}
  template <typename T>
  bool Get(T* v) {
    if (b_.size() - pos_ < sizeof(T)) return Fail("truncated");
    std::memcpy(v, b_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return true;
  }
  bool Str(std::string* s, size_t max_len, const char* what) {
    uint32_t n = 0;
    if (!Get(&n)) return false;
    if (n > max_len) return Fail(what);
    if (b_.size() - pos_ < n) return Fail("truncated");
    s->assign(b_.data() + pos_, n);
    pos_ += n;
    return true;
  }
  bool Blob(std::vector<uint8_t>* v, size_t expected, const char* what) {
    uint32_t n = 0;
    if (!Get(&n)) return false;
    if (n != expected) return Fail(what);
    if (b_.size() - pos_ < n) return Fail("truncated");
    v->assign(b_.data() + pos_, b_.data() + pos_ + n);
    pos_ += n;
    return true;
  }
  bool Fail(const char* why) {
    if (error_.empty()) error_ = why;
    return false;
  }
  Status Finish(const char* type) {
    if (error_.empty() && pos_ != b_.size()) error_ = "trailing bytes";
    if (error_.empty()) return Status::Ok();
    std::string m(type);
    m.append(": ").append(error_).append(" at byte ").append(std::to_string(pos_));
    return ParseError(m);
  }
  Status Version(const char* type) {
    uint8_t v = 0;
    if (!Get(&v)) return Finish(type);
    if (v > kCodecVersion) {
      std::string m(type);
      m.append(": codec version ")
          .append(std::to_string(v))
          .append(" is newer than this reader's ")
          .append(std::to_string(kCodecVersion));
      return Unsupported(m);
    }
    if (v == 0) Fail("codec version 0");
    return Status::Ok();
  }

 private:
  std::string_view b_;
  size_t pos_ = 0;
  std::string error_;
};

// The largest image a burst may carry in a recording (16-bit 4096 × 4096).
constexpr size_t kMaxFrameBytes = size_t{4096} * 4096 * 2;

}  // namespace

void Encode(const BurstMsg& m, std::string* out) {
  Writer w(out);
  w.Put(kCodecVersion);
  w.Str(m.serial);
  w.Put(m.protocol_version);
  w.Put(m.burst_seq);
  w.Put(m.exposure_ns);
  w.Put(m.frame_interval_ns);
  w.Str(m.pattern_set);
  w.Put(m.width);
  w.Put(m.height);
  w.Put(m.bit_depth);
  w.Put(static_cast<uint8_t>(m.frames.size()));
  for (const FrameMsg& f : m.frames) {
    w.Str(f.pattern);
    w.Put(f.pattern_index);
    w.Put(f.timestamp_ns);
    w.Put(f.camera_frame_seq);
    w.Bytes(f.pixels.data(), f.pixels.size());
  }
}

Status Decode(std::string_view bytes, BurstMsg* out) {
  Reader r(bytes);
  D3D_RETURN_IF_ERROR(r.Version("PhaseBurst"));
  uint8_t nframes = 0;
  BurstMsg m;
  bool ok = r.Str(&m.serial, 32, "serial longer than 32") && r.Get(&m.protocol_version) &&
            r.Get(&m.burst_seq) && r.Get(&m.exposure_ns) && r.Get(&m.frame_interval_ns) &&
            r.Str(&m.pattern_set, 64, "pattern set longer than 64") && r.Get(&m.width) &&
            r.Get(&m.height) && r.Get(&m.bit_depth) && r.Get(&nframes);
  if (ok && (m.bit_depth < 1 || m.bit_depth > 16)) ok = r.Fail("bit depth outside 1..16");
  if (ok && nframes > 8) ok = r.Fail("more than 8 frames");
  if (ok && (m.width > 4096 || m.height > 4096)) ok = r.Fail("image larger than 4096 x 4096");
  if (ok) {
    const size_t frame_bytes = m.BytesPerFrame();
    if (frame_bytes > kMaxFrameBytes) ok = r.Fail("frame too large");
    m.frames.resize(nframes);
    for (FrameMsg& f : m.frames) {
      if (!ok) break;
      ok = r.Str(&f.pattern, 64, "pattern name longer than 64") && r.Get(&f.pattern_index) &&
           r.Get(&f.timestamp_ns) && r.Get(&f.camera_frame_seq) &&
           r.Blob(&f.pixels, frame_bytes, "frame size differs from width x height x depth");
    }
  }
  D3D_RETURN_IF_ERROR(r.Finish("PhaseBurst"));
  *out = std::move(m);
  return Status::Ok();
}

void Encode(const InfoMsg& m, std::string* out) {
  Writer w(out);
  w.Put(kCodecVersion);
  w.Str(m.serial);
  w.Put(m.protocol_version);
  w.Str(m.firmware_version);
  w.Str(m.sensor_model);
  w.Str(m.projector_model);
  w.Str(m.capture_backend);
  w.Put(m.width);
  w.Put(m.height);
  w.Put(m.bit_depth);
  w.Str(m.calibration_json);
}

Status Decode(std::string_view bytes, InfoMsg* out) {
  Reader r(bytes);
  D3D_RETURN_IF_ERROR(r.Version("ProbeInfo"));
  InfoMsg m;
  (void)(r.Str(&m.serial, 32, "serial longer than 32") && r.Get(&m.protocol_version) &&
         r.Str(&m.firmware_version, 64, "firmware version longer than 64") &&
         r.Str(&m.sensor_model, 64, "sensor model longer than 64") &&
         r.Str(&m.projector_model, 64, "projector model longer than 64") &&
         r.Str(&m.capture_backend, 32, "backend longer than 32") && r.Get(&m.width) &&
         r.Get(&m.height) && r.Get(&m.bit_depth) &&
         r.Str(&m.calibration_json, 1 << 20, "calibration longer than 1 MiB"));
  D3D_RETURN_IF_ERROR(r.Finish("ProbeInfo"));
  *out = std::move(m);
  return Status::Ok();
}

void Encode(const StatusMsg& m, std::string* out) {
  Writer w(out);
  w.Put(kCodecVersion);
  w.Str(m.serial);
  w.Put(m.protocol_version);
  w.Put(m.timestamp_ns);
  w.Put(static_cast<uint8_t>(m.state));
  w.Put(m.temperature_c);
  w.Put(m.bursts_published);
  w.Put(m.bursts_dropped_sync);
  w.Put(m.frames_dropped_camera);
  w.Put(m.publish_failures);
  w.Put(m.last_command_id);
  w.Str(m.last_error);
}

Status Decode(std::string_view bytes, StatusMsg* out) {
  Reader r(bytes);
  D3D_RETURN_IF_ERROR(r.Version("ProbeStatus"));
  StatusMsg m;
  uint8_t state = 0;
  bool ok = r.Str(&m.serial, 32, "serial longer than 32") && r.Get(&m.protocol_version) &&
            r.Get(&m.timestamp_ns) && r.Get(&state);
  if (ok && state > 3) ok = r.Fail("state outside 0..3");
  m.state = static_cast<ProbeStateKind>(state);
  (void)(ok && r.Get(&m.temperature_c) && r.Get(&m.bursts_published) &&
         r.Get(&m.bursts_dropped_sync) && r.Get(&m.frames_dropped_camera) &&
         r.Get(&m.publish_failures) && r.Get(&m.last_command_id) &&
         r.Str(&m.last_error, 256, "error text longer than 256"));
  D3D_RETURN_IF_ERROR(r.Finish("ProbeStatus"));
  *out = std::move(m);
  return Status::Ok();
}

}  // namespace d3d::proto
