// d3d-replay: publishes a recording (d3d-record) back onto DDS, with its original timing
// (--rate 1.0, or a multiple) or as fast as the readers take it (--rate max); --info prints its
// summary instead. Damaged recordings: every intact chunk is replayed; what was lost is reported.
//
// Exit codes: 0 fine, 1 DDS/publish failure, 2 usage or unreadable file (wrong magic, newer
// version, damaged header), 3 a damaged file was read (every finding: damaged or cut-off chunks, a
// file that ends before its index, a damaged index or footer, bytes after the end; the rest was
// used), with what was lost on stderr: chunks and messages, and bursts (from the sequence numbers:
// exact across lost chunks between bursts, a range before the first or after the last burst read,
// unknown after the last chunk of a file that ends before its index).
#include <CLI/CLI.hpp>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <thread>

#include "common/core/progress.h"
#include "common/recording/recording.h"
#include "host/receiver/receiver.h"
#include "protocol/codec.h"
#include "protocol/protocol.h"
#include "tools/dds/tool_dds.h"

using namespace d3d;

namespace {
volatile std::sig_atomic_t g_stop = 0;
void OnSignal(int) { g_stop = 1; }

struct Summary {
  int64_t messages = 0, bursts = 0, infos = 0, statuses = 0, undecodable = 0;
  int64_t first_ns = 0, last_ns = 0;
  uint64_t pixel_bytes = 0;
  std::map<std::string, int64_t> sizes;  // "640x480x8 4 frames" -> bursts
};

// What a damaged recording lost, on stderr (the file named): each finding, then the totals.
void ReportDamage(const RecordingReader& r, const std::string& path, const SequenceLossCounter* bursts) {
  for (const auto& p : r.diagnostics().problems) std::fprintf(stderr, "d3d-replay: %s: damaged: %s\n", path.c_str(), p.c_str());
  std::fprintf(stderr, "d3d-replay: %s is damaged; every intact chunk was read; lost: %s%s%s (exit 3)\n", path.c_str(),
               r.diagnostics().LossSummary().c_str(), bursts != nullptr ? "; bursts lost: " : "",
               bursts != nullptr ? bursts->Describe().c_str() : "");
}

// The summary as text (--info), a field a line.
void PrintInfoText(const RecordingReader& r, const std::string& path, const Summary& s, const SequenceLossCounter& lost) {
  const RecordingHeader& h = r.header();
  const RecordingDiagnostics& d = r.diagnostics();
  std::printf("recording:     %s (format %d.%d, protocol %d.%d)\n", path.c_str(), h.format_major, h.format_minor, h.protocol_version / 100,
              h.protocol_version % 100);
  std::printf("probe:         %s, calibration %s\n", h.probe_serial.empty() ? "(unknown)" : h.probe_serial.c_str(),
              h.calibration_json.empty() ? "absent" : "present");
  std::printf("duration:      %.3f s\n", s.messages > 0 ? static_cast<double>(s.last_ns - s.first_ns) * 1e-9 : 0.0);
  std::printf("chunks:        %zu (%s)\n", r.chunks().size(), d.index_used ? "indexed" : "scanned: no valid index");
  std::printf("messages:      %lld (bursts %lld, ProbeInfo %lld, ProbeStatus %lld)\n", static_cast<long long>(s.messages),
              static_cast<long long>(s.bursts), static_cast<long long>(s.infos), static_cast<long long>(s.statuses));
  for (const auto& [k, n] : s.sizes) std::printf("burst size:    %s: %lld bursts\n", k.c_str(), static_cast<long long>(n));
  std::printf("pixel bytes:   %.1f MB\n", static_cast<double>(s.pixel_bytes) / 1e6);
  std::printf("sequence gaps: %llu in intact data (%llu bursts missing upstream, before the recorder)\n",
              static_cast<unsigned long long>(lost.upstream_gaps()), static_cast<unsigned long long>(lost.missing_upstream()));
  std::printf("lost:          %s\n", d.LossSummary().c_str());
  std::printf("bursts lost:   %s\n", lost.Describe().c_str());
  if (s.undecodable > 0) std::printf("undecodable:   %lld bursts\n", static_cast<long long>(s.undecodable));
}

// The summary as one JSON object (--info --json), the same fields as the text.
void PrintInfoJson(const RecordingReader& r, const std::string& path, const Summary& s, const SequenceLossCounter& lost) {
  const RecordingHeader& h = r.header();
  const RecordingDiagnostics& d = r.diagnostics();
  nlohmann::json sizes = nlohmann::json::object();
  for (const auto& [k, n] : s.sizes) sizes[k] = n;
  const std::optional<uint64_t> lost_max = lost.lost_max();
  const nlohmann::json j = {{"recording", path},
                            {"format", std::to_string(h.format_major) + "." + std::to_string(h.format_minor)},
                            {"protocol", std::to_string(h.protocol_version / 100) + "." + std::to_string(h.protocol_version % 100)},
                            {"probe_serial", h.probe_serial},
                            {"calibration", !h.calibration_json.empty()},
                            {"duration_s", s.messages > 0 ? static_cast<double>(s.last_ns - s.first_ns) * 1e-9 : 0.0},
                            {"chunks", r.chunks().size()},
                            {"indexed", d.index_used},
                            {"messages", s.messages},
                            {"bursts", s.bursts},
                            {"probe_info", s.infos},
                            {"probe_status", s.statuses},
                            {"burst_sizes", sizes},
                            {"pixel_bytes", s.pixel_bytes},
                            {"sequence_gaps", lost.upstream_gaps()},
                            {"bursts_missing_upstream", lost.missing_upstream()},
                            {"damaged", d.damaged()},
                            {"lost", d.LossSummary()},
                            {"bursts_lost", lost.Describe()},
                            {"bursts_lost_min", lost.lost_min()},
                            {"bursts_lost_max", lost_max ? nlohmann::json(*lost_max) : nlohmann::json(nullptr)},  // null: unknown
                            {"undecodable", s.undecodable}};
  std::printf("%s\n", j.dump().c_str());
}

int PrintInfo(RecordingReader* r, const std::string& path, bool json) {
  Summary s;
  const RecordingChannel* cb = r->header().FindTopic(proto::kTopicPhaseBurst);
  const RecordingChannel* ci = r->header().FindTopic(proto::kTopicProbeInfo);
  SequenceLossCounter lost(r);
  std::vector<RecordedMessage> msgs;
  for (size_t c = 0; c < r->chunks().size(); ++c) {
    const bool ok = r->ReadChunk(c, &msgs).ok();
    lost.Chunk(c, ok);
    if (!ok) continue;
    for (const RecordedMessage& m : msgs) {
      ++s.messages;
      if (s.first_ns == 0 || m.log_time_ns < s.first_ns) s.first_ns = m.log_time_ns;
      s.last_ns = std::max(s.last_ns, m.log_time_ns);
      if (cb != nullptr && m.channel == cb->id) {
        proto::BurstMsg b;
        if (!proto::Decode(m.data, &b).ok()) {
          ++s.undecodable;
          continue;
        }
        ++s.bursts;
        s.pixel_bytes += b.PixelBytes();
        s.sizes[std::to_string(b.width) + "x" + std::to_string(b.height) + "x" + std::to_string(b.bit_depth) + " bit, " +
                std::to_string(b.frames.size()) + " frames"]++;
        lost.Message(b.burst_seq, m.data.size());
      } else if (ci != nullptr && m.channel == ci->id) {
        ++s.infos;
      } else {
        ++s.statuses;
      }
    }
  }
  lost.End();
  const RecordingDiagnostics& d = r->diagnostics();
  if (json)
    PrintInfoJson(*r, path, s, lost);
  else
    PrintInfoText(*r, path, s, lost);
  if (d.damaged()) ReportDamage(*r, path, &lost);
  if (s.undecodable > 0)
    std::fprintf(stderr, "d3d-replay: %s: %lld bursts do not decode (exit 3)\n", path.c_str(), static_cast<long long>(s.undecodable));
  return d.damaged() || s.undecodable > 0 ? 3 : 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App cli{"d3d-replay: publish a recording back onto DDS, or print its summary (--info)"};
  std::string path, rate_text = "1.0";
  bool info = false, loop = false, json = false;
  double start_s = 0, wait_timeout_s = 60;
  int64_t frames = 0;
  int domain = 0, wait_subscribers = 1;
  cli.add_option("file", path, "recording written by d3d-record")->required();
  cli.add_flag("--info", info, "print the summary (duration, bursts, sizes, gaps, damage) and exit");
  cli.add_flag("--json", json, "--info: the summary as one JSON object on stdout (damage reports stay on stderr)");
  cli.add_option("--rate", rate_text, "1.0 = original timing (2.0 twice as fast), max = as fast as readers take it")->capture_default_str();
  cli.add_flag("--loop", loop, "repeat until interrupted (burst_seq continues across loops)");
  cli.add_option("--start", start_s, "skip the first S seconds")->capture_default_str();
  cli.add_option("--frames", frames, "publish at most this many bursts (0 = all)")->capture_default_str();
  cli.add_option("--domain", domain, "DDS domain id")->capture_default_str();
  cli.add_option("--wait-subscribers", wait_subscribers, "wait for this many PhaseBurst readers before publishing")->capture_default_str();
  cli.add_option("--wait-timeout", wait_timeout_s, "seconds to wait for them")->capture_default_str();
  CLI11_PARSE(cli, argc, argv);
  double rate = 0;  // 0 = max
  if (rate_text != "max") {
    try {
      rate = std::stod(rate_text);
    } catch (...) {
      rate = -1;
    }
    if (!(rate > 0)) {
      std::fprintf(stderr, "d3d-replay: --rate must be a positive number or 'max'\n");
      return 2;
    }
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);

  std::unique_ptr<RecordingReader> reader;
  if (const Status s = RecordingReader::OpenFile(path, &reader); !s.ok()) {
    std::fprintf(stderr, "d3d-replay: %s: %s\n", path.c_str(), s.message().c_str());
    return 2;
  }
  if (json && !info) {
    std::fprintf(stderr, "d3d-replay: --json goes with --info\n");
    return 2;
  }
  if (info) return PrintInfo(reader.get(), path, json);
  const RecordingHeader& h = reader->header();
  const RecordingChannel* cb = h.FindTopic(proto::kTopicPhaseBurst);
  const RecordingChannel* ci = h.FindTopic(proto::kTopicProbeInfo);
  const RecordingChannel* cs = h.FindTopic(proto::kTopicProbeStatus);
  if (cb == nullptr) {
    std::fprintf(stderr, "d3d-replay: %s has no %s channel\n", path.c_str(), proto::kTopicPhaseBurst);
    return 2;
  }
  int64_t total_bursts = 0;
  for (const ChunkInfo& c : reader->chunks()) total_bursts += c.message_count;  // upper bound for the bar

  proto::DdsParticipant participant;
  if (const Status s = tools::CreateToolParticipant(domain, &participant, "d3d-replay"); !s.ok()) {
    std::fprintf(stderr, "d3d-replay: DDS: %s\n", s.ToString().c_str());
    return 1;
  }
  Status st;
  const dds_entity_t tb = participant.Topic(&d3d_proto_PhaseBurst_desc, proto::kTopicPhaseBurst, &st);
  const dds_entity_t ti = participant.Topic(&d3d_proto_ProbeInfo_desc, proto::kTopicProbeInfo, &st);
  const dds_entity_t ts = participant.Topic(&d3d_proto_ProbeStatus_desc, proto::kTopicProbeStatus, &st);
  using Q = std::unique_ptr<dds_qos_t, proto::QosDeleter>;
  const dds_entity_t wb = dds_create_writer(participant.participant(), tb,
                                            Q(proto::MakeQos(rate > 0 ? proto::QosProfile::kBurstWriter : proto::QosProfile::kBurstReplayWriter)).get(), nullptr);
  const dds_entity_t wi = dds_create_writer(participant.participant(), ti, Q(proto::MakeQos(proto::QosProfile::kInfoWriter)).get(), nullptr);
  const dds_entity_t ws = dds_create_writer(participant.participant(), ts, Q(proto::MakeQos(proto::QosProfile::kStatusWriter)).get(), nullptr);
  if (tb <= 0 || ti <= 0 || ts <= 0 || wb < 0 || wi < 0 || ws < 0) {
    std::fprintf(stderr, "d3d-replay: cannot create DDS writers\n");
    return 1;
  }
  if (!tools::WaitForReaders(wb, wait_subscribers, wait_timeout_s, &g_stop)) {
    std::fprintf(stderr, "d3d-replay: no PhaseBurst reader within %.0f s\n", wait_timeout_s);
    return 1;
  }

  ProgressBar bar("d3d-replay", frames > 0 ? std::min(frames, total_bursts) : total_bursts);
  int64_t published = 0, failures = 0;
  uint64_t seq_offset = 0, max_seq = 0;
  std::vector<d3d_proto_ImageFrame> storage;
  bool info_sent = false, looped = false;
  std::vector<RecordedMessage> msgs;
  SequenceLossCounter lost(reader.get());  // the first pass over the file
  do {
    int64_t t0_file = -1;
    const auto t0_wall = std::chrono::steady_clock::now();
    for (size_t c = 0; c < reader->chunks().size() && !g_stop; ++c) {
      const bool ok = reader->ReadChunk(c, &msgs).ok();
      if (!looped) lost.Chunk(c, ok);
      if (!ok) continue;  // damaged: reported at the end
      for (const RecordedMessage& m : msgs) {
        if (g_stop || (frames > 0 && published >= frames)) break;
        if (t0_file < 0) t0_file = m.log_time_ns + static_cast<int64_t>(start_s * 1e9);
        if (m.log_time_ns < t0_file) continue;  // --start
        if (rate > 0) {
          const auto due = t0_wall + std::chrono::nanoseconds(static_cast<int64_t>(static_cast<double>(m.log_time_ns - t0_file) / rate));
          std::this_thread::sleep_until(due);
        }
        dds_return_t rc = DDS_RETCODE_OK;
        if (m.channel == cb->id) {
          proto::BurstMsg b;
          if (!proto::Decode(m.data, &b).ok()) {
            ++failures;
            continue;
          }
          if (!looped) lost.Message(b.burst_seq, m.data.size());
          max_seq = std::max(max_seq, b.burst_seq);
          b.burst_seq += seq_offset;
          d3d_proto_PhaseBurst s;
          proto::ToDds(b, &s, &storage);
          rc = dds_write(wb, &s);
          if (rc >= 0) bar.Update(++published);
        } else if (ci != nullptr && m.channel == ci->id && !info_sent) {
          proto::InfoMsg i;
          if (proto::Decode(m.data, &i).ok()) {
            d3d_proto_ProbeInfo s;
            proto::ToDds(i, &s);
            rc = dds_write(wi, &s);
            info_sent = true;
          }
        } else if (cs != nullptr && m.channel == cs->id) {
          proto::StatusMsg sm;
          if (proto::Decode(m.data, &sm).ok()) {
            d3d_proto_ProbeStatus s;
            proto::ToDds(sm, &s);
            rc = dds_write(ws, &s);
          }
        }
        if (rc < 0) ++failures;
      }
    }
    if (!looped && !g_stop) lost.End();
    looped = true;
    seq_offset += max_seq + 1;
  } while (loop && !g_stop && !(frames > 0 && published >= frames));
  bar.Finish();
  const dds_return_t acked = dds_wait_for_acks(wb, DDS_SECS(30));
  (void)dds_wait_for_acks(ws, DDS_SECS(2));
  std::printf("d3d-replay: published %lld bursts, %lld failures%s\n", static_cast<long long>(published), static_cast<long long>(failures),
              acked == DDS_RETCODE_OK ? "" : " (readers did not acknowledge everything)");
  if (reader->diagnostics().damaged()) ReportDamage(*reader, path, loop || frames > 0 || start_s > 0 || g_stop ? nullptr : &lost);
  if (failures > 0 || acked != DDS_RETCODE_OK) return 1;
  return reader->diagnostics().damaged() ? 3 : 0;
}
