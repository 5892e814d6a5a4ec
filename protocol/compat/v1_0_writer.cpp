// An "older probe": publishes protocol-1.0 samples (frozen IDL) so that the versioning test can
// check that the current reader still takes them. Usage: d3d_protocol_v1_0_writer CONFIG.xml DOMAIN
// BURSTS Burst b (0-based) is 4 frames of 8×6 px, pixel i of frame f = (b·31 + f·7 + i) mod 256,
// serial "OLD-1"; then one ProbeStatus in state STREAMING with bursts_published = BURSTS. Exits 0
// once a reader has acknowledged everything, 1 on error or after 20 s without a reader.
#include <dds/dds.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "d3d_protocol_v1_0.h"

int main(int argc, char** argv) {
  if (argc != 4) {
    std::fprintf(stderr, "usage: %s CONFIG.xml DOMAIN BURSTS\n", argv[0]);
    return 2;
  }
  std::ifstream f(argv[1]);
  std::stringstream xml;
  xml << f.rdbuf();
  const int domain = std::atoi(argv[2]);
  const int bursts = std::atoi(argv[3]);
  if (dds_create_domain(domain, xml.str().c_str()) < 0) return 1;
  const dds_entity_t pp = dds_create_participant(domain, nullptr, nullptr);
  const dds_entity_t tb =
      dds_create_topic(pp, &d3d_proto_PhaseBurst_desc, "d3d/PhaseBurst", nullptr, nullptr);
  const dds_entity_t ts =
      dds_create_topic(pp, &d3d_proto_ProbeStatus_desc, "d3d/ProbeStatus", nullptr, nullptr);
  dds_qos_t* q = dds_create_qos();
  dds_qset_reliability(q, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  dds_qset_history(q, DDS_HISTORY_KEEP_ALL, 0);
  const dds_entity_t wb = dds_create_writer(pp, tb, q, nullptr);
  const dds_entity_t ws = dds_create_writer(pp, ts, q, nullptr);
  dds_delete_qos(q);
  if (pp < 0 || tb < 0 || ts < 0 || wb < 0 || ws < 0) return 1;
  // Wait for the reader of both topics.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  for (;;) {
    dds_publication_matched_status_t mb{}, ms{};
    dds_get_publication_matched_status(wb, &mb);
    dds_get_publication_matched_status(ws, &ms);
    if (mb.current_count > 0 && ms.current_count > 0) break;
    if (std::chrono::steady_clock::now() > deadline) return 1;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  constexpr int kW = 8, kH = 6;
  for (int b = 0; b < bursts; ++b) {
    std::vector<std::vector<uint8_t>> pixels(4, std::vector<uint8_t>(kW * kH));
    std::vector<d3d_proto_ImageFrame> frames(4);
    for (int fi = 0; fi < 4; ++fi) {
      for (int i = 0; i < kW * kH; ++i)
        pixels[fi][i] = static_cast<uint8_t>((b * 31 + fi * 7 + i) % 256);
      d3d_proto_ImageFrame& fr = frames[fi];
      std::memset(&fr, 0, sizeof fr);
      std::snprintf(fr.pattern, sizeof fr.pattern, "phase4-marker/%d", fi);
      fr.pattern_index = static_cast<uint16_t>(fi);
      fr.timestamp_ns = 1'000'000'000LL * (b + 1) + 2'500'000LL * fi;
      fr.pixels._buffer = pixels[fi].data();
      fr.pixels._length = fr.pixels._maximum = kW * kH;
    }
    d3d_proto_PhaseBurst s;
    std::memset(&s, 0, sizeof s);
    std::snprintf(s.serial, sizeof s.serial, "OLD-1");
    s.protocol_version = 100;
    s.burst_seq = static_cast<uint64_t>(b);
    s.exposure_ns = 1'000'000;
    s.frame_interval_ns = 2'500'000;
    std::snprintf(s.pattern_set, sizeof s.pattern_set, "phase4-marker");
    s.width = kW;
    s.height = kH;
    s.bit_depth = 8;
    s.frames._buffer = frames.data();
    s.frames._length = s.frames._maximum = 4;
    if (dds_write(wb, &s) < 0) return 1;
  }
  d3d_proto_ProbeStatus st;
  std::memset(&st, 0, sizeof st);
  std::snprintf(st.serial, sizeof st.serial, "OLD-1");
  st.protocol_version = 100;
  st.state = d3d_proto_PROBE_STREAMING;
  st.bursts_published = static_cast<uint64_t>(bursts);
  std::snprintf(st.last_error, sizeof st.last_error, "none");
  if (dds_write(ws, &st) < 0) return 1;
  const bool acked = dds_wait_for_acks(wb, DDS_SECS(10)) == DDS_RETCODE_OK &&
                     dds_wait_for_acks(ws, DDS_SECS(10)) == DDS_RETCODE_OK;
  dds_delete(pp);
  return acked ? 0 : 1;
}
