// d3d-record: writes every PhaseBurst, ProbeInfo and ProbeStatus sample seen on DDS to a recording
// (common/recording: chunked, zstd, CRC per chunk, index). The header carries the protocol version
// and the probe's calibration from its ProbeInfo, so recording waits (up to --info-timeout, buffering
// samples) for a ProbeInfo before it opens the file. Killed at any moment, the file is readable up
// to its last complete chunk.
//
// Threads: the receiver's DDS listener copies samples into its queue; this tool's main thread pops,
// encodes (protocol/codec.h) and writes them.
#include <CLI/CLI.hpp>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <deque>

#include "common/recording/recording.h"
#include "host/receiver/receiver.h"
#include "protocol/codec.h"
#include "protocol/protocol.h"
#include "tools/dds/tool_dds.h"

using namespace d3d;

namespace {
volatile std::sig_atomic_t g_stop = 0;
void OnSignal(int) { g_stop = 1; }
int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch()).count();
}
enum Channel : uint16_t { kBurst = 0, kInfo = 1, kStatus = 2 };
}  // namespace

int main(int argc, char** argv) {
  CLI::App cli{"d3d-record: record PhaseBurst, ProbeInfo and ProbeStatus samples to a chunked, compressed, indexed file"};
  std::string out, serial;
  double duration_s = 0, info_timeout_s = 30;
  int64_t frames = 0;
  int domain = 0;
  RecordingWriterOptions wo;
  size_t queue = 256;
  cli.add_option("--out", out, "recording file to write")->required();
  cli.add_option("--duration", duration_s, "stop after this many seconds (0 = no limit)")->capture_default_str();
  cli.add_option("--frames", frames, "stop after this many bursts (0 = no limit)")->capture_default_str();
  cli.add_option("--domain", domain, "DDS domain id")->capture_default_str();
  cli.add_option("--serial", serial, "record only this probe (default: any)");
  cli.add_option("--info-timeout", info_timeout_s, "seconds to wait for ProbeInfo (calibration) before writing without it")->capture_default_str();
  cli.add_option("--zstd-level", wo.zstd_level, "zstd level 1..19")->capture_default_str();
  cli.add_option("--queue", queue, "samples buffered between the DDS thread and the writer")->capture_default_str();
  CLI11_PARSE(cli, argc, argv);
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);

  try {
    proto::DdsParticipant participant;
    if (const Status s = tools::CreateToolParticipant(domain, &participant, "d3d-record"); !s.ok()) {
      std::fprintf(stderr, "d3d-record: DDS: %s\n", s.ToString().c_str());
      return 3;
    }
    ReceiverOptions ro;
    ro.serial = serial;
    ro.queue_capacity = queue;
    ro.log = [](const std::string& m) { std::fprintf(stderr, "d3d-record: %s\n", m.c_str()); };
    BurstReceiver rx(ro);
    if (const Status s = rx.Start(&participant); !s.ok()) {
      std::fprintf(stderr, "d3d-record: %s\n", s.ToString().c_str());
      return 3;
    }
    std::fprintf(stderr, "d3d-record: listening on domain %d\n", domain);

    RecordingWriter writer;
    std::deque<ReceivedSample> pending;  // until the header (with the calibration) can be written
    const int64_t start = NowNs();
    int64_t bursts = 0, infos = 0, statuses = 0, first_ns = 0, last_ns = 0;
    std::string bytes;
    auto open_file = [&](const proto::InfoMsg* info) -> Status {
      RecordingHeader h;
      h.protocol_version = proto::kProtocolVersion;
      h.created_ns = NowNs();
      if (info != nullptr) {
        h.probe_serial = info->serial;
        h.calibration_json = info->calibration_json;
      }
      h.channels = {{kBurst, proto::kTopicPhaseBurst, proto::kSchemaBurst},
                    {kInfo, proto::kTopicProbeInfo, proto::kSchemaInfo},
                    {kStatus, proto::kTopicProbeStatus, proto::kSchemaStatus}};
      h.metadata["tool"] = "d3d-record";
      h.metadata["domain"] = std::to_string(domain);
      return writer.Open(out, h, wo);
    };
    auto write = [&](const ReceivedSample& r) -> Status {
      bytes.clear();
      uint16_t ch;
      if (const auto* b = std::get_if<proto::BurstMsg>(&r.msg)) {
        proto::Encode(*b, &bytes);
        ch = kBurst;
        ++bursts;
        if (first_ns == 0) first_ns = r.receive_ns;
        last_ns = r.receive_ns;
      } else if (const auto* i = std::get_if<proto::InfoMsg>(&r.msg)) {
        proto::Encode(*i, &bytes);
        ch = kInfo;
        ++infos;
      } else {
        proto::Encode(std::get<proto::StatusMsg>(r.msg), &bytes);
        ch = kStatus;
        ++statuses;
      }
      return writer.Add(ch, r.receive_ns, bytes);
    };
    Status failure;
    while (!g_stop) {
      if (frames > 0 && bursts >= frames) break;
      if (duration_s > 0 && static_cast<double>(NowNs() - start) * 1e-9 >= duration_s) break;
      ReceivedSample r;
      const bool got = rx.Pop(&r, 100'000'000);
      if (!writer.is_open()) {
        const proto::InfoMsg* info = got ? std::get_if<proto::InfoMsg>(&r.msg) : nullptr;
        if (got) pending.push_back(std::move(r));
        const bool timed_out = static_cast<double>(NowNs() - start) * 1e-9 >= info_timeout_s && !pending.empty();
        if (info != nullptr || timed_out) {
          if (info == nullptr) std::fprintf(stderr, "d3d-record: warning: no ProbeInfo within %.0f s: header without calibration\n", info_timeout_s);
          failure = open_file(info != nullptr ? &std::get<proto::InfoMsg>(pending.back().msg) : nullptr);
          if (!failure.ok()) break;
          // The buffered samples, in arrival order (stop at --frames).
          for (auto& p : pending) {
            if (frames > 0 && bursts >= frames && std::holds_alternative<proto::BurstMsg>(p.msg)) continue;
            if (!(failure = write(p)).ok()) break;
          }
          pending.clear();
          if (!failure.ok()) break;
        }
        continue;
      }
      if (!got) continue;
      if (!(failure = write(r)).ok()) break;
      rx.Recycle(std::move(r));
    }
    rx.Stop();
    if (!writer.is_open() && failure.ok() && !pending.empty()) {
      failure = open_file(nullptr);
      for (auto& p : pending)
        if (failure.ok()) failure = write(p);
    }
    const Status closed = writer.Close();
    if (failure.ok()) failure = closed;
    const ReceiverCounters c = rx.counters();
    std::printf("d3d-record: %s: %lld bursts, %lld ProbeInfo, %lld ProbeStatus, %.1f MB in %.2f s; sequence gaps %llu (%llu bursts missing), dropped %llu\n",
                out.c_str(), static_cast<long long>(bursts), static_cast<long long>(infos), static_cast<long long>(statuses),
                static_cast<double>(writer.bytes_written()) / 1e6, static_cast<double>(last_ns - first_ns) * 1e-9,
                static_cast<unsigned long long>(c.sequence_gaps), static_cast<unsigned long long>(c.bursts_missing),
                static_cast<unsigned long long>(c.dropped_total()));
    if (!failure.ok()) {
      std::fprintf(stderr, "d3d-record: %s\n", failure.ToString().c_str());
      return 1;
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-record: %s\n", e.what());
    return 2;
  }
  return 0;
}
