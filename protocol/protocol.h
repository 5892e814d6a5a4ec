// The d3dscan probe protocol: version, topic names and QoS profiles of the DDS topics defined in
// protocol/idl/d3d_protocol.idl (generated C types: "protocol/d3d_protocol.h").
#pragma once

#include <dds/dds.h>

#include <cstdint>

namespace d3d::proto {

// major * 100 + minor. Readers accept any minor of their major (appendable types, see the IDL);
// a different major is rejected with a counted reason.
inline constexpr uint16_t kProtocolVersion = 101;  // 1.1
inline constexpr uint16_t ProtocolMajor(uint16_t v) { return static_cast<uint16_t>(v / 100); }
inline constexpr bool ProtocolCompatible(uint16_t v) {
  return ProtocolMajor(v) == ProtocolMajor(kProtocolVersion);
}

inline constexpr const char* kTopicPhaseBurst = "d3d/PhaseBurst";
inline constexpr const char* kTopicProbeInfo = "d3d/ProbeInfo";
inline constexpr const char* kTopicProbeStatus = "d3d/ProbeStatus";
inline constexpr const char* kTopicProbeCommand = "d3d/ProbeCommand";
inline constexpr const char* kTopicProbeCommandAck = "d3d/ProbeCommandAck";

// Who uses a QoS profile; the justification of each is in qos.cpp (MakeQos).
enum class QosProfile {
  kBurstWriter,         // the probe's PhaseBurst writer
  kBurstReplayWriter,   // d3d-replay --rate max: as fast as the readers take it, never lossy
  kBurstPreviewReader,  // live preview: only the freshest burst matters
  kBurstRecordReader,   // recorder, replay consumers, reconstruction: every burst
  kInfoWriter,          // ProbeInfo, latched for late joiners
  kInfoReader,
  kStatusWriter,
  kStatusReader,
  kCommandWriter,  // ProbeCommand and ProbeCommandAck, both directions
  kCommandReader,
};

// A new dds_qos_t for the profile; the caller owns it (dds_delete_qos). `depth` overrides the
// history depth of the KEEP_LAST profiles when > 0 (benchmarks).
dds_qos_t* MakeQos(QosProfile profile, int depth = 0);

// RAII for a dds_qos_t.
struct QosDeleter {
  void operator()(dds_qos_t* q) const { dds_delete_qos(q); }
};

}  // namespace d3d::proto
