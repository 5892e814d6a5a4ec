#include "protocol/dds_setup.h"

#include <string_view>

namespace d3d::proto {

void DdsOptions::Check() const {
  D3D_CHECK_MSG(domain_id >= 0 && domain_id <= 232,
                "DDS domain id must be in 0..232, got " << domain_id);
}

Status DdsError(const char* what, dds_return_t rc) {
  std::string m(what);
  m.append(": ").append(dds_strretcode(rc));
  return Unavailable(m);
}

namespace {
// <Tag min="4MB"/>  ->  <Tag max="4MB"/>: ask for that size but accept what the kernel grants.
void RelaxMinimum(std::string* xml, std::string_view tag) {
  const size_t at = xml->find(tag);
  if (at == std::string::npos) return;
  const size_t min = xml->find("min=\"", at);
  const size_t end = xml->find("/>", at);
  if (min == std::string::npos || end == std::string::npos || min > end) return;
  xml->replace(min, 3, "max");
}
}  // namespace

std::string SelectCycloneConfig(const char* cyclonedds_uri_env, int64_t rmem_max_bytes,
                                int64_t wmem_max_bytes, std::string* warning) {
  if (cyclonedds_uri_env != nullptr && cyclonedds_uri_env[0] != '\0') return "";
  std::string xml = ShippedCycloneConfig();
  constexpr int64_t kRecvMin = 4 << 20, kSendMin = 2 << 20;
  std::string w;
  if (rmem_max_bytes > 0 && rmem_max_bytes < kRecvMin) {
    RelaxMinimum(&xml, "<SocketReceiveBufferSize");
    w.append("net.core.rmem_max is ").append(std::to_string(rmem_max_bytes)).append(" B < 4 MB; ");
  }
  if (wmem_max_bytes > 0 && wmem_max_bytes < kSendMin) {
    RelaxMinimum(&xml, "<SocketSendBufferSize");
    w.append("net.core.wmem_max is ").append(std::to_string(wmem_max_bytes)).append(" B < 2 MB; ");
  }
  if (!w.empty() && warning != nullptr) {
    *warning = w;
    warning->append(
        "large bursts may be lost or slow (sysctl -w net.core.rmem_max=8388608 "
        "net.core.wmem_max=8388608)");
  }
  return xml;
}

DdsParticipant::~DdsParticipant() {
  if (participant_ > 0) dds_delete(participant_);
  if (domain_ > 0) dds_delete(domain_);
}

Status DdsParticipant::Create(const DdsOptions& options) {
  options.Check();
  if (!options.config_xml.empty()) {
    const dds_entity_t d = dds_create_domain(static_cast<dds_domainid_t>(options.domain_id),
                                             options.config_xml.c_str());
    // PRECONDITION_NOT_MET: the domain already exists in this process (created by an earlier
    // participant).
    if (d < 0 && d != DDS_RETCODE_PRECONDITION_NOT_MET)
      return DdsError("dds_create_domain (check the Cyclone config)", d);
    if (d > 0) domain_ = d;
  }
  participant_ =
      dds_create_participant(static_cast<dds_domainid_t>(options.domain_id), nullptr, nullptr);
  if (participant_ < 0) {
    const dds_return_t rc = participant_;
    participant_ = 0;
    return DdsError("dds_create_participant", rc);
  }
  return Status::Ok();
}

dds_entity_t DdsParticipant::Topic(const dds_topic_descriptor_t* desc, const char* name,
                                   Status* status) {
  const dds_entity_t t = dds_create_topic(participant_, desc, name, nullptr, nullptr);
  if (t < 0) {
    *status = DdsError("dds_create_topic", t);
    return 0;
  }
  *status = Status::Ok();
  return t;
}

}  // namespace d3d::proto
