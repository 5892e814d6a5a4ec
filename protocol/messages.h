// C++ values of the protocol's samples (protocol/idl/d3d_protocol.idl), conversions to and from the
// idlc-generated C types, and their byte encoding for recordings (codec.h).
//
// Ownership: a *Msg owns its bytes. ToDds() fills a generated C struct whose sequences and strings
// POINT INTO the message (no pixel copy): the message must outlive the struct, which is only valid
// for dds_write. FromDds() copies a received sample (which may be a loan) into the message.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "common/core/status.h"
#include "protocol/d3d_protocol.h"

namespace d3d::proto {

struct FrameMsg {
  std::string pattern;  // projector frame name, ≤ 64 bytes
  uint16_t pattern_index = 0;
  int64_t timestamp_ns = 0;  // middle of the exposure, ns since the Unix epoch
  uint64_t camera_frame_seq = 0;
  std::vector<uint8_t> pixels;  // H×W bytes (8 bit) or H×W×2 little endian (9..16 bit)
  bool operator==(const FrameMsg&) const = default;
};

struct BurstMsg {
  std::string serial;  // ≤ 32 bytes
  uint16_t protocol_version = 0;
  uint64_t burst_seq = 0;
  int64_t exposure_ns = 0;
  int64_t frame_interval_ns = 0;
  std::string pattern_set;  // ≤ 64 bytes
  uint32_t width = 0;
  uint32_t height = 0;
  uint8_t bit_depth = 8;
  std::vector<FrameMsg> frames;  // ≤ 8
  size_t BytesPerFrame() const {
    return static_cast<size_t>(width) * height * (bit_depth > 8 ? 2 : 1);
  }
  size_t PixelBytes() const;
  bool operator==(const BurstMsg&) const = default;
};

struct InfoMsg {
  std::string serial;
  uint16_t protocol_version = 0;
  std::string firmware_version;
  std::string sensor_model;
  std::string projector_model;
  std::string capture_backend;
  uint32_t width = 0;
  uint32_t height = 0;
  uint8_t bit_depth = 8;
  std::string calibration_json;
  bool operator==(const InfoMsg&) const = default;
};

enum class ProbeStateKind : uint8_t { kIdle = 0, kStreaming = 1, kError = 2, kRecovering = 3 };
const char* ProbeStateName(ProbeStateKind s);

struct StatusMsg {
  std::string serial;
  uint16_t protocol_version = 0;
  int64_t timestamp_ns = 0;
  ProbeStateKind state = ProbeStateKind::kIdle;
  float temperature_c = 0;
  uint64_t bursts_published = 0;
  uint64_t bursts_dropped_sync = 0;
  uint64_t frames_dropped_camera = 0;
  uint64_t publish_failures = 0;
  uint64_t last_command_id = 0;
  std::string last_error;
  bool operator==(const StatusMsg&) const = default;
};

// Fixed-size string members are truncated to their bound. Throws std::invalid_argument if a burst
// has more than 8 frames.
void ToDds(const BurstMsg& m, d3d_proto_PhaseBurst* out,
           std::vector<d3d_proto_ImageFrame>* frame_storage);
void ToDds(const InfoMsg& m, d3d_proto_ProbeInfo* out);  // out->calibration_json points into m
void ToDds(const StatusMsg& m, d3d_proto_ProbeStatus* out);
void FromDds(const d3d_proto_PhaseBurst& s, BurstMsg* out);
void FromDds(const d3d_proto_ProbeInfo& s, InfoMsg* out);
void FromDds(const d3d_proto_ProbeStatus& s, StatusMsg* out);

// Copies `src` into the fixed char array `dst` of size N (N−1 characters at most, NUL-terminated).
template <size_t N>
void CopyBounded(char (&dst)[N], const std::string& src) {
  const size_t n = src.size() < N - 1 ? src.size() : N - 1;
  src.copy(dst, n);
  dst[n] = '\0';
}
// The string of a fixed char array (stops at the first NUL or at N).
template <size_t N>
std::string FromBounded(const char (&src)[N]) {
  size_t n = 0;
  while (n < N && src[n] != '\0') ++n;
  return std::string(src, n);
}

}  // namespace d3d::proto
