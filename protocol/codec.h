// Byte encoding of protocol samples inside recordings (common/recording stores opaque payloads).
// Little-endian, one leading codec version byte (kCodecVersion), then the members in IDL order;
// strings and byte arrays as u32 length + bytes. Decode is a parser of untrusted bytes: it checks
// every length against the input and the IDL bounds and returns PARSE_ERROR (never throws or
// over-reads); UNSUPPORTED for a newer codec version. Fuzzed by tests/fuzz (d3d_recording_fuzz).
#pragma once

#include <string>
#include <string_view>

#include "protocol/messages.h"

namespace d3d::proto {

inline constexpr uint8_t kCodecVersion = 1;
// Schema names stored with each recording channel.
inline constexpr const char* kSchemaBurst = "d3d.proto.PhaseBurst/codec1";
inline constexpr const char* kSchemaInfo = "d3d.proto.ProbeInfo/codec1";
inline constexpr const char* kSchemaStatus = "d3d.proto.ProbeStatus/codec1";

void Encode(const BurstMsg& m, std::string* out);  // appends
void Encode(const InfoMsg& m, std::string* out);
void Encode(const StatusMsg& m, std::string* out);
[[nodiscard]] Status Decode(std::string_view bytes, BurstMsg* out);
[[nodiscard]] Status Decode(std::string_view bytes, InfoMsg* out);
[[nodiscard]] Status Decode(std::string_view bytes, StatusMsg* out);

}  // namespace d3d::proto
