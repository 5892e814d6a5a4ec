// d3d-record: writes every PhaseBurst, ProbeInfo and ProbeStatus sample seen on DDS to a recording
// (common/recording: chunked, zstd, CRC per chunk, index). The header carries the protocol version
// and the probe's calibration from its ProbeInfo, so recording waits (up to --info-timeout,
// buffering samples) for a ProbeInfo before it opens the file. Killed at any moment, the file is
// readable up to its last complete chunk. `d3d-record trim | merge | recover | cat | export ...`
// edits recordings instead (record_edit.h).
//
// Threads: the receiver's DDS listener copies samples into its queue; this tool's main thread pops,
// encodes (protocol/codec.h) and writes them.
#include <chrono>
#include <csignal>
#include <cstdio>
#include <deque>

#include "common/options/option_registry.h"
#include "common/recording/recording.h"
#include "host/receiver/receiver.h"
#include "protocol/codec.h"
#include "protocol/protocol.h"
#include "tools/dds/tool_dds.h"
#include "tools/record/record_edit.h"

using namespace d3d;

namespace {
volatile std::sig_atomic_t g_stop = 0;
void OnSignal(int) { g_stop = 1; }
int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}
enum Channel : uint16_t { kBurst = 0, kInfo = 1, kStatus = 2 };

struct RecordOptions {
  std::string out, serial;
  double duration_s = 0, info_timeout_s = 30;
  int64_t frames = 0;
  int domain = 0;
  RecordingWriterOptions writer;
  uint64_t queue = 256;
};

void DeclareOptions(OptionRegistry* r, RecordOptions* o) {
  r->Add("--out", &o->out, "recording file to write").Required();
  r->Add("--duration", &o->duration_s, "stop after this many seconds (0 = no limit)");
  r->Add("--frames", &o->frames, "stop after this many bursts (0 = no limit)");
  r->Add("--domain", &o->domain, "DDS domain id");
  r->Add("--serial", &o->serial, "record only this probe (default: any)");
  r->Add("--info-timeout", &o->info_timeout_s,
         "seconds to wait for ProbeInfo (calibration) before writing without it");
  r->Add("--zstd-level", &o->writer.zstd_level, "zstd level 1..19");
  r->Add("--queue", &o->queue, "samples buffered between the DDS thread and the writer");
}

// The recording file: opened with its header once the calibration is known (or given up on), then
// each sample encoded onto its channel, with the counts of what was written.
class RecordingSink {
 public:
  explicit RecordingSink(const RecordOptions& options) : options_(options) {}

  bool is_open() const { return writer_.is_open(); }
  // Whether --frames bursts were written.
  bool done() const { return options_.frames > 0 && bursts_ >= options_.frames; }

  // The header: protocol version, the three channels and, from `info` (may be null), the probe's
  // serial and calibration.
  Status Open(const proto::InfoMsg* info) {
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
    h.metadata["domain"] = std::to_string(options_.domain);
    return writer_.Open(options_.out, h, options_.writer);
  }

  Status Write(const ReceivedSample& r) {
    bytes_.clear();
    uint16_t ch;
    if (const auto* b = std::get_if<proto::BurstMsg>(&r.msg)) {
      proto::Encode(*b, &bytes_);
      ch = kBurst;
      ++bursts_;
      if (first_ns_ == 0) first_ns_ = r.receive_ns;
      last_ns_ = r.receive_ns;
    } else if (const auto* i = std::get_if<proto::InfoMsg>(&r.msg)) {
      proto::Encode(*i, &bytes_);
      ch = kInfo;
      ++infos_;
    } else {
      proto::Encode(std::get<proto::StatusMsg>(r.msg), &bytes_);
      ch = kStatus;
      ++statuses_;
    }
    return writer_.Add(ch, r.receive_ns, bytes_);
  }

  Status Close() { return writer_.Close(); }

  void PrintSummary(const ReceiverCounters& c) const {
    std::printf(
        "d3d-record: %s: %lld bursts, %lld ProbeInfo, %lld ProbeStatus, %.1f MB in %.2f s; "
        "sequence gaps %llu (%llu bursts missing), "
        "dropped %llu\n",
        options_.out.c_str(), static_cast<long long>(bursts_), static_cast<long long>(infos_),
        static_cast<long long>(statuses_), static_cast<double>(writer_.bytes_written()) / 1e6,
        static_cast<double>(last_ns_ - first_ns_) * 1e-9,
        static_cast<unsigned long long>(c.sequence_gaps),
        static_cast<unsigned long long>(c.bursts_missing),
        static_cast<unsigned long long>(c.dropped_total()));
  }

 private:
  const RecordOptions& options_;
  RecordingWriter writer_;
  int64_t bursts_ = 0, infos_ = 0, statuses_ = 0, first_ns_ = 0, last_ns_ = 0;
  std::string bytes_;
};

// Before the file is open: buffers `r` (if `got`) and opens the file once a ProbeInfo came or
// --info-timeout passed, then writes the buffered samples in arrival order (up to --frames).
Status BufferUntilInfo(const RecordOptions& o, int64_t start_ns, bool got, ReceivedSample* r,
                       std::deque<ReceivedSample>* pending, RecordingSink* sink) {
  const proto::InfoMsg* info = got ? std::get_if<proto::InfoMsg>(&r->msg) : nullptr;
  if (got) pending->push_back(std::move(*r));
  const bool timed_out =
      static_cast<double>(NowNs() - start_ns) * 1e-9 >= o.info_timeout_s && !pending->empty();
  if (info == nullptr && !timed_out) return Status();
  if (info == nullptr)
    std::fprintf(stderr,
                 "d3d-record: warning: no ProbeInfo within %.0f s: header without calibration\n",
                 o.info_timeout_s);
  Status failure =
      sink->Open(info != nullptr ? &std::get<proto::InfoMsg>(pending->back().msg) : nullptr);
  if (!failure.ok()) return failure;
  for (auto& p : *pending) {
    if (sink->done() && std::holds_alternative<proto::BurstMsg>(p.msg)) continue;
    if (!(failure = sink->Write(p)).ok()) break;
  }
  pending->clear();
  return failure;
}

// Records until --frames, --duration or a signal, then closes the file (opening it without
// calibration if samples are still buffered); the first failure.
Status Record(const RecordOptions& o, BurstReceiver* rx, RecordingSink* sink) {
  std::deque<ReceivedSample> pending;  // until the header (with the calibration) can be written
  const int64_t start = NowNs();
  Status failure;
  while (!g_stop) {
    if (sink->done()) break;
    if (o.duration_s > 0 && static_cast<double>(NowNs() - start) * 1e-9 >= o.duration_s) break;
    ReceivedSample r;
    const bool got = rx->Pop(&r, 100'000'000);
    if (!sink->is_open()) {
      if (!(failure = BufferUntilInfo(o, start, got, &r, &pending, sink)).ok()) break;
      continue;
    }
    if (!got) continue;
    if (!(failure = sink->Write(r)).ok()) break;
    rx->Recycle(std::move(r));
  }
  rx->Stop();
  if (!sink->is_open() && failure.ok() && !pending.empty()) {
    failure = sink->Open(nullptr);
    for (auto& p : pending)
      if (failure.ok()) failure = sink->Write(p);
  }
  const Status closed = sink->Close();
  if (failure.ok()) failure = closed;
  return failure;
}

// Joins the DDS domain, records, prints the summary; the exit code (1 a write failed, 3 DDS).
int RunRecorder(const RecordOptions& o) {
  proto::DdsParticipant participant;
  if (const Status s = tools::CreateToolParticipant(o.domain, &participant, "d3d-record");
      !s.ok()) {
    std::fprintf(stderr, "d3d-record: DDS: %s\n", s.ToString().c_str());
    return 3;
  }
  ReceiverOptions ro;
  ro.serial = o.serial;
  ro.queue_capacity = o.queue;
  ro.log = [](const std::string& m) { std::fprintf(stderr, "d3d-record: %s\n", m.c_str()); };
  BurstReceiver rx(ro);
  if (const Status s = rx.Start(&participant); !s.ok()) {
    std::fprintf(stderr, "d3d-record: %s\n", s.ToString().c_str());
    return 3;
  }
  std::fprintf(stderr, "d3d-record: listening on domain %d\n", o.domain);
  RecordingSink sink(o);
  const Status failure = Record(o, &rx, &sink);
  sink.PrintSummary(rx.counters());
  if (!failure.ok()) {
    std::fprintf(stderr, "d3d-record: %s\n", failure.ToString().c_str());
    return 1;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc >= 2 && IsRecordEditVerb(argv[1])) return RunRecordEdit(argc, argv);
  OptionRegistry options(
      "d3d-record: record PhaseBurst, ProbeInfo and ProbeStatus samples to a chunked, compressed, "
      "indexed file.\nEdit recordings: d3d-record trim | merge | recover | cat | export ... (each "
      "with "
      "--help)");
  RecordOptions o;
  DeclareOptions(&options, &o);
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  try {
    return RunRecorder(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-record: %s\n", e.what());
    return 2;
  }
}
