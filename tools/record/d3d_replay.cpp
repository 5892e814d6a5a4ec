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
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <thread>

#include "common/core/progress.h"
#include "common/options/option_registry.h"
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
void ReportDamage(const RecordingReader& r, const std::string& path,
                  const SequenceLossCounter* bursts) {
  for (const auto& p : r.diagnostics().problems)
    std::fprintf(stderr, "d3d-replay: %s: damaged: %s\n", path.c_str(), p.c_str());
  std::fprintf(stderr,
               "d3d-replay: %s is damaged; every intact chunk was read; lost: %s%s%s (exit 3)\n",
               path.c_str(), r.diagnostics().LossSummary().c_str(),
               bursts != nullptr ? "; bursts lost: " : "",
               bursts != nullptr ? bursts->Describe().c_str() : "");
}

// The summary as text (--info), a field a line.
void PrintInfoText(const RecordingReader& r, const std::string& path, const Summary& s,
                   const SequenceLossCounter& lost) {
  const RecordingHeader& h = r.header();
  const RecordingDiagnostics& d = r.diagnostics();
  std::printf("recording:     %s (format %d.%d, protocol %d.%d)\n", path.c_str(), h.format_major,
              h.format_minor, h.protocol_version / 100, h.protocol_version % 100);
  std::printf("probe:         %s, calibration %s\n",
              h.probe_serial.empty() ? "(unknown)" : h.probe_serial.c_str(),
              h.calibration_json.empty() ? "absent" : "present");
  std::printf("duration:      %.3f s\n",
              s.messages > 0 ? static_cast<double>(s.last_ns - s.first_ns) * 1e-9 : 0.0);
  std::printf("chunks:        %zu (%s)\n", r.chunks().size(),
              d.index_used ? "indexed" : "scanned: no valid index");
  std::printf("messages:      %lld (bursts %lld, ProbeInfo %lld, ProbeStatus %lld)\n",
              static_cast<long long>(s.messages), static_cast<long long>(s.bursts),
              static_cast<long long>(s.infos), static_cast<long long>(s.statuses));
  for (const auto& [k, n] : s.sizes)
    std::printf("burst size:    %s: %lld bursts\n", k.c_str(), static_cast<long long>(n));
  std::printf("pixel bytes:   %.1f MB\n", static_cast<double>(s.pixel_bytes) / 1e6);
  std::printf(
      "sequence gaps: %llu in intact data (%llu bursts missing upstream, before the recorder)\n",
      static_cast<unsigned long long>(lost.upstream_gaps()),
      static_cast<unsigned long long>(lost.missing_upstream()));
  std::printf("lost:          %s\n", d.LossSummary().c_str());
  std::printf("bursts lost:   %s\n", lost.Describe().c_str());
  if (s.undecodable > 0)
    std::printf("undecodable:   %lld bursts\n", static_cast<long long>(s.undecodable));
}

// The summary as one JSON object (--info --json), the same fields as the text.
void PrintInfoJson(const RecordingReader& r, const std::string& path, const Summary& s,
                   const SequenceLossCounter& lost) {
  const RecordingHeader& h = r.header();
  const RecordingDiagnostics& d = r.diagnostics();
  nlohmann::json sizes = nlohmann::json::object();
  for (const auto& [k, n] : s.sizes) sizes[k] = n;
  const std::optional<uint64_t> lost_max = lost.lost_max();
  const nlohmann::json j = {
      {"recording", path},
      {"format", std::to_string(h.format_major) + "." + std::to_string(h.format_minor)},
      {"protocol",
       std::to_string(h.protocol_version / 100) + "." + std::to_string(h.protocol_version % 100)},
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
      {"bursts_lost_max",
       lost_max ? nlohmann::json(*lost_max) : nlohmann::json(nullptr)},  // null: unknown
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
        s.sizes[std::to_string(b.width) + "x" + std::to_string(b.height) + "x" +
                std::to_string(b.bit_depth) + " bit, " + std::to_string(b.frames.size()) +
                " frames"]++;
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
    std::fprintf(stderr, "d3d-replay: %s: %lld bursts do not decode (exit 3)\n", path.c_str(),
                 static_cast<long long>(s.undecodable));
  return d.damaged() || s.undecodable > 0 ? 3 : 0;
}

struct ReplayOptions {
  std::string path, rate_text = "1.0";
  bool info = false, loop = false, json = false;
  double start_s = 0, wait_timeout_s = 60;
  int64_t frames = 0;
  int domain = 0, wait_subscribers = 1;
};

void DeclareOptions(OptionRegistry* r, ReplayOptions* o) {
  r->Add("file", &o->path, "recording written by d3d-record").Required();
  r->Flag("--info", &o->info, "print the summary (duration, bursts, sizes, gaps, damage) and exit");
  r->Flag("--json", &o->json,
          "--info: the summary as one JSON object on stdout (damage reports stay on stderr)");
  r->Add("--rate", &o->rate_text,
         "1.0 = original timing (2.0 twice as fast), max = as fast as readers take it");
  r->Flag("--loop", &o->loop, "repeat until interrupted (burst_seq continues across loops)");
  r->Add("--start", &o->start_s, "skip the first S seconds");
  r->Add("--frames", &o->frames, "publish at most this many bursts (0 = all)");
  r->Add("--domain", &o->domain, "DDS domain id");
  r->Add("--wait-subscribers", &o->wait_subscribers,
         "wait for this many PhaseBurst readers before publishing");
  r->Add("--wait-timeout", &o->wait_timeout_s, "seconds to wait for them");
}

// --rate as a speed factor (0 = max); false (printed) unless a positive number or "max".
bool ParseRate(const std::string& text, double* rate) {
  *rate = 0;
  if (text == "max") return true;
  try {
    *rate = std::stod(text);
  } catch (...) {
    *rate = -1;
  }
  if (*rate > 0) return true;
  std::fprintf(stderr, "d3d-replay: --rate must be a positive number or 'max'\n");
  return false;
}

// The recording's channels (burst required, the others may be absent) and their DDS writers.
struct ReplayChannels {
  const RecordingChannel *burst = nullptr, *info = nullptr, *status = nullptr;
  dds_entity_t burst_writer = -1, info_writer = -1, status_writer = -1;
};

// The writers of the three topics; paced replays use the probe's burst QoS, --rate max the
// flow-controlled replay QoS. False (printed) when DDS refuses one.
bool CreateWriters(proto::DdsParticipant* participant, bool paced, ReplayChannels* c) {
  Status st;
  const dds_entity_t tb =
      participant->Topic(&d3d_proto_PhaseBurst_desc, proto::kTopicPhaseBurst, &st);
  const dds_entity_t ti =
      participant->Topic(&d3d_proto_ProbeInfo_desc, proto::kTopicProbeInfo, &st);
  const dds_entity_t ts =
      participant->Topic(&d3d_proto_ProbeStatus_desc, proto::kTopicProbeStatus, &st);
  using Q = std::unique_ptr<dds_qos_t, proto::QosDeleter>;
  const dds_entity_t pp = participant->participant();
  c->burst_writer =
      dds_create_writer(pp, tb,
                        Q(proto::MakeQos(paced ? proto::QosProfile::kBurstWriter
                                               : proto::QosProfile::kBurstReplayWriter))
                            .get(),
                        nullptr);
  c->info_writer =
      dds_create_writer(pp, ti, Q(proto::MakeQos(proto::QosProfile::kInfoWriter)).get(), nullptr);
  c->status_writer =
      dds_create_writer(pp, ts, Q(proto::MakeQos(proto::QosProfile::kStatusWriter)).get(), nullptr);
  if (tb <= 0 || ti <= 0 || ts <= 0 || c->burst_writer < 0 || c->info_writer < 0 ||
      c->status_writer < 0) {
    std::fprintf(stderr, "d3d-replay: cannot create DDS writers\n");
    return false;
  }
  return true;
}

// Publishes recorded messages: bursts renumbered to continue across loops, the first ProbeInfo
// only, every ProbeStatus.
class Publisher {
 public:
  explicit Publisher(const ReplayChannels& c) : c_(c) {}

  // Publishes `m`; negative when it failed (an undecodable burst counts as a failure).
  // *burst: a burst was published. `lost` (null after the first pass) counts its sequence number.
  dds_return_t Publish(const RecordedMessage& m, SequenceLossCounter* lost, bool* burst) {
    *burst = false;
    if (m.channel == c_.burst->id) {
      proto::BurstMsg b;
      if (!proto::Decode(m.data, &b).ok()) return DDS_RETCODE_ERROR;
      if (lost != nullptr) lost->Message(b.burst_seq, m.data.size());
      max_seq_ = std::max(max_seq_, b.burst_seq);
      b.burst_seq += seq_offset_;
      d3d_proto_PhaseBurst s;
      proto::ToDds(b, &s, &storage_);
      const dds_return_t rc = dds_write(c_.burst_writer, &s);
      *burst = rc >= 0;
      return rc;
    }
    if (c_.info != nullptr && m.channel == c_.info->id && !info_sent_) {
      proto::InfoMsg i;
      if (!proto::Decode(m.data, &i).ok()) return DDS_RETCODE_OK;
      d3d_proto_ProbeInfo s;
      proto::ToDds(i, &s);
      info_sent_ = true;
      return dds_write(c_.info_writer, &s);
    }
    if (c_.status != nullptr && m.channel == c_.status->id) {
      proto::StatusMsg sm;
      if (!proto::Decode(m.data, &sm).ok()) return DDS_RETCODE_OK;
      d3d_proto_ProbeStatus s;
      proto::ToDds(sm, &s);
      return dds_write(c_.status_writer, &s);
    }
    return DDS_RETCODE_OK;
  }

  // After a pass over the file: the next pass's burst numbers follow this one's.
  void EndPass() { seq_offset_ += max_seq_ + 1; }

 private:
  const ReplayChannels& c_;
  std::vector<d3d_proto_ImageFrame> storage_;
  uint64_t seq_offset_ = 0, max_seq_ = 0;
  bool info_sent_ = false;
};

// Publishes the recording (once, or until a signal with --loop; at most --frames bursts, from
// --start) at `rate` (0 = max); the first pass counts the lost bursts into `lost`.
void PublishPasses(RecordingReader* reader, const ReplayOptions& o, double rate,
                   const ReplayChannels& c, ProgressBar* bar, SequenceLossCounter* lost,
                   int64_t* published, int64_t* failures) {
  Publisher publisher(c);
  std::vector<RecordedMessage> msgs;
  bool looped = false;
  do {
    int64_t t0_file = -1;
    const auto t0_wall = std::chrono::steady_clock::now();
    for (size_t ch = 0; ch < reader->chunks().size() && !g_stop; ++ch) {
      const bool ok = reader->ReadChunk(ch, &msgs).ok();
      if (!looped) lost->Chunk(ch, ok);
      if (!ok) continue;  // damaged: reported at the end
      for (const RecordedMessage& m : msgs) {
        if (g_stop || (o.frames > 0 && *published >= o.frames)) break;
        if (t0_file < 0) t0_file = m.log_time_ns + static_cast<int64_t>(o.start_s * 1e9);
        if (m.log_time_ns < t0_file) continue;  // --start
        if (rate > 0) {
          const auto due = t0_wall + std::chrono::nanoseconds(static_cast<int64_t>(
                                         static_cast<double>(m.log_time_ns - t0_file) / rate));
          std::this_thread::sleep_until(due);
        }
        bool burst = false;
        if (publisher.Publish(m, looped ? nullptr : lost, &burst) < 0) ++*failures;
        if (burst) bar->Update(++*published);
      }
    }
    if (!looped && !g_stop) lost->End();
    looped = true;
    publisher.EndPass();
  } while (o.loop && !g_stop && !(o.frames > 0 && *published >= o.frames));
}

// Publishes the recording onto DDS once readers are there, then reports; the exit code (0 fine,
// 1 DDS or publish failure, 2 no burst channel, 3 a damaged file was read).
int Replay(RecordingReader* reader, const ReplayOptions& o, double rate) {
  ReplayChannels c;
  c.burst = reader->header().FindTopic(proto::kTopicPhaseBurst);
  c.info = reader->header().FindTopic(proto::kTopicProbeInfo);
  c.status = reader->header().FindTopic(proto::kTopicProbeStatus);
  if (c.burst == nullptr) {
    std::fprintf(stderr, "d3d-replay: %s has no %s channel\n", o.path.c_str(),
                 proto::kTopicPhaseBurst);
    return 2;
  }
  int64_t total_bursts = 0;
  for (const ChunkInfo& ci : reader->chunks())
    total_bursts += ci.message_count;  // upper bound for the bar

  proto::DdsParticipant participant;
  if (const Status s = tools::CreateToolParticipant(o.domain, &participant, "d3d-replay");
      !s.ok()) {
    std::fprintf(stderr, "d3d-replay: DDS: %s\n", s.ToString().c_str());
    return 1;
  }
  if (!CreateWriters(&participant, rate > 0, &c)) return 1;
  if (!tools::WaitForReaders(c.burst_writer, o.wait_subscribers, o.wait_timeout_s, &g_stop)) {
    std::fprintf(stderr, "d3d-replay: no PhaseBurst reader within %.0f s\n", o.wait_timeout_s);
    return 1;
  }

  ProgressBar bar("d3d-replay", o.frames > 0 ? std::min(o.frames, total_bursts) : total_bursts);
  int64_t published = 0, failures = 0;
  SequenceLossCounter lost(reader);  // the first pass over the file
  PublishPasses(reader, o, rate, c, &bar, &lost, &published, &failures);
  bar.Finish();
  const dds_return_t acked = dds_wait_for_acks(c.burst_writer, DDS_SECS(30));
  (void)dds_wait_for_acks(c.status_writer, DDS_SECS(2));
  std::printf("d3d-replay: published %lld bursts, %lld failures%s\n",
              static_cast<long long>(published), static_cast<long long>(failures),
              acked == DDS_RETCODE_OK ? "" : " (readers did not acknowledge everything)");
  // Bursts lost are known only when the whole file was replayed once.
  const bool whole_pass = !(o.loop || o.frames > 0 || o.start_s > 0 || g_stop);
  if (reader->diagnostics().damaged()) ReportDamage(*reader, o.path, whole_pass ? &lost : nullptr);
  if (failures > 0 || acked != DDS_RETCODE_OK) return 1;
  return reader->diagnostics().damaged() ? 3 : 0;
}

}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options(
      "d3d-replay: publish a recording back onto DDS, or print its summary (--info)");
  ReplayOptions o;
  DeclareOptions(&options, &o);
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;
  double rate = 0;  // 0 = max
  if (!ParseRate(o.rate_text, &rate)) return 2;
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);

  std::unique_ptr<RecordingReader> reader;
  if (const Status s = RecordingReader::OpenFile(o.path, &reader); !s.ok()) {
    std::fprintf(stderr, "d3d-replay: %s: %s\n", o.path.c_str(), s.message().c_str());
    return 2;
  }
  if (o.json && !o.info) {
    std::fprintf(stderr, "d3d-replay: --json goes with --info\n");
    return 2;
  }
  if (o.info) return PrintInfo(reader.get(), o.path, o.json);
  return Replay(reader.get(), o, rate);
}
