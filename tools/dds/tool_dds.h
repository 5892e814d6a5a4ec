// Tool-side DDS set-up shared by d3d-probe, d3d-record, d3d-replay and d3d-bench-dds: the shipped
// Cyclone configuration unless $CYCLONEDDS_URI is set (read here, in the tools, not in libraries),
// with the kernel's socket buffer limits taken into account.
#pragma once

#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>

#include "protocol/dds_setup.h"

namespace d3d::tools {

inline int64_t ReadProcBytes(const char* path) {
  std::ifstream f(path);
  int64_t v = 0;
  return (f >> v) ? v : 0;
}

// Creates the participant for `domain`; prints a warning when the socket buffers are limited.
inline Status CreateToolParticipant(int domain, proto::DdsParticipant* participant,
                                    const char* tool) {
  std::string warning;
  const std::string xml = proto::SelectCycloneConfig(
      std::getenv("CYCLONEDDS_URI"), ReadProcBytes("/proc/sys/net/core/rmem_max"),
      ReadProcBytes("/proc/sys/net/core/wmem_max"), &warning);
  if (!warning.empty()) std::fprintf(stderr, "%s: warning: %s\n", tool, warning.c_str());
  return participant->Create({domain, xml});
}

// Waits until `writer` has matched at least `n` readers; false after timeout_s.
inline bool WaitForReaders(dds_entity_t writer, int n, double timeout_s,
                           const volatile std::sig_atomic_t* stop) {
  if (n <= 0) return true;
  for (int i = 0; i < static_cast<int>(timeout_s * 100); ++i) {
    dds_publication_matched_status_t st{};
    dds_get_publication_matched_status(writer, &st);
    if (static_cast<int>(st.current_count) >= n) return true;
    if (stop != nullptr && *stop) return false;
    dds_sleepfor(DDS_MSECS(10));
  }
  return false;
}

}  // namespace d3d::tools
