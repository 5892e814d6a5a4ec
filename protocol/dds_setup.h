// Setting up Cyclone DDS for d3dscan: the shipped configuration (protocol/config/cyclonedds.xml,
// compiled in) and a participant owner. No environment is read here: tools decide (see
// SelectCycloneConfig) and pass the result in DdsOptions.
#pragma once

#include <dds/dds.h>

#include <cstdint>
#include <string>

#include "common/core/status.h"

namespace d3d::proto {

// The text of protocol/config/cyclonedds.xml as built into the binary.
const char* ShippedCycloneConfig();

// The configuration a tool should use. `cyclonedds_uri_env`: the value of $CYCLONEDDS_URI or
// nullptr; when set, returns "" (Cyclone then reads that variable itself). Otherwise the shipped
// config; if the kernel's socket buffer limits (net.core.rmem_max / wmem_max, bytes; ≤ 0 unknown)
// are below the config's minimums, the `min` requirement is relaxed so that Cyclone still starts,
// and
// `*warning` says what to raise for lossless bursts.
std::string SelectCycloneConfig(const char* cyclonedds_uri_env, int64_t rmem_max_bytes,
                                int64_t wmem_max_bytes, std::string* warning);

struct DdsOptions {
  int domain_id = 0;       // 0..232
  std::string config_xml;  // Cyclone XML; "" = Cyclone's own default (or $CYCLONEDDS_URI)
  void Check() const;      // throws std::invalid_argument
};

// Owns a domain participant (and the explicitly created domain, if this was the first participant
// of the domain in the process). Entities created under participant() are deleted with it.
class DdsParticipant {
 public:
  DdsParticipant() = default;
  ~DdsParticipant();
  DdsParticipant(const DdsParticipant&) = delete;
  DdsParticipant& operator=(const DdsParticipant&) = delete;

  // UNAVAILABLE with Cyclone's error text when the domain or participant cannot be created (bad
  // configuration, no usable interface, socket buffer minimum not met).
  [[nodiscard]] Status Create(const DdsOptions& options);
  dds_entity_t participant() const { return participant_; }
  // A topic of the participant for a generated type descriptor; 0 and *status on error.
  dds_entity_t Topic(const dds_topic_descriptor_t* desc, const char* name, Status* status);

 private:
  dds_entity_t domain_ = 0;
  dds_entity_t participant_ = 0;
};

// "dds_create_writer: Precondition Not Met" from a negative Cyclone return code.
Status DdsError(const char* what, dds_return_t rc);

}  // namespace d3d::proto
