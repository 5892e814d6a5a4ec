#include "tools/record/record_edit.h"

#include <algorithm>
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <vector>

#include "common/burst/burst_io.h"
#include "common/options/option_registry.h"
#include "common/recording/recording.h"
#include "common/recording/recording_edit.h"
#include "protocol/codec.h"
#include "protocol/protocol.h"

namespace fs = std::filesystem;

namespace d3d {
namespace {

constexpr int kDamaged = 3;

// argv for a verb's own registry: "d3d-record VERB" then its options.
struct VerbArgs {
  std::string name;
  std::vector<char*> argv;
  VerbArgs(int argc, char** argv_in) : name(std::string("d3d-record ") + argv_in[1]) {
    argv.push_back(name.data());
    for (int i = 2; i < argc; ++i) argv.push_back(argv_in[i]);
  }
  int argc() const { return static_cast<int>(argv.size()); }
};

int Fail(const std::string& verb, const std::string& what, int code) {
  std::fprintf(stderr, "d3d-record %s: %s\n", verb.c_str(), what.c_str());
  return code;
}

// Opens an input: 2 with the reason when it is no readable recording.
int OpenInput(const std::string& verb, const std::string& path,
              std::unique_ptr<RecordingReader>* out) {
  if (const Status s = RecordingReader::OpenFile(path, out); !s.ok())
    return Fail(verb, path + ": " + s.message(), 2);
  return 0;
}

// A verb's options parsed (the help or a usage error end it: *exit gets the code), then its input
// opened (or *exit gets 2). True to go on.
bool ParseAndOpen(OptionRegistry* r, VerbArgs* a, const std::string& verb, const std::string& in,
                  std::unique_ptr<RecordingReader>* reader, int* exit) {
  if (!r->Parse(a->argc(), a->argv.data(), exit)) return false;
  *exit = OpenInput(verb, in, reader);
  return *exit == 0;
}

// An output must not be an input: opening it would truncate what is about to be read.
int CheckOutput(const std::string& verb, const std::string& out,
                const std::vector<std::string>& inputs) {
  std::error_code ec;
  for (const std::string& in : inputs)
    if (fs::equivalent(in, out, ec))
      return Fail(verb, "the output '" + out + "' is the input '" + in + "'", 2);
  return 0;
}

// What a damaged input lost, on stderr; true when it was damaged.
bool ReportDamage(const std::string& verb, const std::string& path, const RecordingReader& r) {
  if (!r.diagnostics().damaged()) return false;
  for (const std::string& p : r.diagnostics().problems)
    std::fprintf(stderr, "d3d-record %s: %s: damaged: %s\n", verb.c_str(), path.c_str(), p.c_str());
  std::fprintf(stderr, "d3d-record %s: %s is damaged; every intact chunk was used; lost: %s\n",
               verb.c_str(), path.c_str(), r.diagnostics().LossSummary().c_str());
  return true;
}

// The output's header: the input's, marked with what made it.
RecordingHeader EditedHeader(const RecordingHeader& in, const std::string& edit) {
  RecordingHeader h = in;
  h.metadata["d3d.edit"] = edit;
  return h;
}

// Writes `out_path` with `header` (the input's, marked with `edit`) and the messages `fill` adds,
// then closes it; 0, or 1 after saying why it could not be written.
int WriteRecording(const std::string& verb, const std::string& out_path,
                   const RecordingHeader& header, const std::string& edit,
                   const std::function<Status(RecordingWriter*)>& fill) {
  RecordingWriter w;
  if (const Status s = w.Open(out_path, EditedHeader(header, edit)); !s.ok())
    return Fail(verb, out_path + ": " + s.message(), 1);
  Status s = fill(&w);
  const Status closed = w.Close();
  if (s.ok()) s = closed;
  return s.ok() ? 0 : Fail(verb, out_path + ": " + s.message(), 1);
}

// Copies `in` into `out_path` keeping what `keep` keeps; the exit code.
int CopyInto(const std::string& verb, const std::string& in_path, RecordingReader* in,
             const std::string& out_path, const std::string& edit,
             const std::function<bool(const RecordedMessage&)>& keep) {
  RecordingCopyCounts counts;
  if (const int c = WriteRecording(verb, out_path, in->header(), edit, [&](RecordingWriter* w) {
        return CopyMessages(in, keep, w, &counts);
      }))
    return c;
  std::fprintf(stderr, "d3d-record %s: %s: %" PRIu64 " of %" PRIu64 " messages written\n",
               verb.c_str(), out_path.c_str(), counts.messages_written, counts.messages_read);
  return ReportDamage(verb, in_path, *in) ? kDamaged : 0;
}

int Trim(int argc, char** argv) {
  VerbArgs a(argc, argv);
  OptionRegistry r(
      "d3d-record trim: a stretch of a recording into a new one: by seconds from its first message "
      "(--from, --to) or by bursts in file order (--bursts A:B: bursts A to B - 1, counted from 0, "
      "and the ProbeStatus samples within their time span). ProbeInfo samples are kept whatever "
      "the range (the probe's description, which a replayed host waits for).");
  std::string in, out, bursts;
  double from_s = 0, to_s = -1;
  r.Add("input", &in, "the recording to trim").Required();
  r.Add("--out", &out, "the recording to write").Required();
  r.Add("--from", &from_s, "start, seconds after the first message (default 0)").NonNegative();
  r.Add("--to", &to_s, "end (excluded), seconds after the first message (default: the end)")
      .NonNegative();
  r.Add("--bursts", &bursts, "A:B: bursts A to B − 1, counted from 0 in file order");
  if (int code = 0; !r.Parse(a.argc(), a.argv.data(), &code)) return code;
  if (!bursts.empty() && (from_s != 0 || to_s >= 0))
    return Fail("trim", "--bursts and --from/--to select differently: give one", 2);
  long long b0 = 0, b1 = 0;
  char rest = 0;
  if (!bursts.empty() &&
      (std::sscanf(bursts.c_str(), "%lld:%lld%c", &b0, &b1, &rest) != 2 || b0 < 0 || b1 <= b0))
    return Fail("trim", "--bursts must be A:B with 0 <= A < B, got '" + bursts + "'", 2);
  if (to_s >= 0 && to_s <= from_s) return Fail("trim", "--to must be after --from", 2);
  if (const int c = CheckOutput("trim", out, {in})) return c;
  std::unique_ptr<RecordingReader> reader;
  if (const int c = OpenInput("trim", in, &reader)) return c;
  const RecordingChannel* burst_ch = reader->header().FindTopic(proto::kTopicPhaseBurst);
  const RecordingChannel* info_ch = reader->header().FindTopic(proto::kTopicProbeInfo);
  // The range of log times kept: from the first message, or the chosen bursts' span (one pass
  // over the file to find it).
  LogTimeRange range;
  int64_t first_ns = 0;
  bool have_first = false;
  std::vector<int64_t> burst_ns;
  reader->ForEach([&](const RecordedMessage& m) {
    if (!have_first) first_ns = m.log_time_ns, have_first = true;
    if (burst_ch != nullptr && m.channel == burst_ch->id) burst_ns.push_back(m.log_time_ns);
    return true;
  });
  if (!bursts.empty()) {
    if (burst_ch == nullptr || static_cast<long long>(burst_ns.size()) <= b0)
      return Fail("trim",
                  in + " holds " + std::to_string(burst_ns.size()) + " bursts: none from " +
                      std::to_string(b0),
                  2);
    const size_t last = static_cast<size_t>(std::min<long long>(b1, burst_ns.size()) - 1);
    range = {burst_ns[static_cast<size_t>(b0)], burst_ns[last] + 1};
  } else {
    range.from_ns = first_ns + static_cast<int64_t>(from_s * 1e9);
    if (to_s >= 0) range.to_ns = first_ns + static_cast<int64_t>(to_s * 1e9);
    if (std::none_of(burst_ns.begin(), burst_ns.end(),
                     [&](int64_t t) { return range.Contains(t); }))
      return Fail(
          "trim",
          in + " has no burst in that stretch (its bursts span " +
              (burst_ns.empty() ? std::string("nothing")
                                : std::to_string((burst_ns.front() - first_ns) * 1e-9) + " to " +
                                      std::to_string((burst_ns.back() - first_ns) * 1e-9) + " s") +
              ")",
          2);
  }
  // Bursts by their order (an equal log time is no reason to keep a burst outside A:B).
  int64_t burst_index = -1;
  const bool by_bursts = !bursts.empty();
  auto keep = [&](const RecordedMessage& m) {
    if (info_ch != nullptr && m.channel == info_ch->id) return true;
    if (burst_ch != nullptr && m.channel == burst_ch->id) {
      ++burst_index;
      if (by_bursts) return burst_index >= b0 && burst_index < b1;
    }
    return range.Contains(m.log_time_ns);
  };
  // The copy reads the file again; its reader's diagnostics are the ones reported.
  std::unique_ptr<RecordingReader> again;
  if (const int c = OpenInput("trim", in, &again)) return c;
  const std::string edit = by_bursts ? "trim --bursts " + bursts
                                     : "trim --from " + std::to_string(from_s) +
                                           (to_s >= 0 ? " --to " + std::to_string(to_s) : "");
  return CopyInto("trim", in, again.get(), out, edit, keep);
}

int Recover(int argc, char** argv) {
  VerbArgs a(argc, argv);
  OptionRegistry r(
      "d3d-record recover: the intact chunks of a damaged recording (a killed recorder, a cut-off "
      "copy, damaged chunks) rewritten into a clean one, with its index; what was lost on stderr "
      "and exit 3. A recording that is not damaged is copied and exits 0.");
  std::string in, out;
  r.Add("input", &in, "the damaged recording").Required();
  r.Add("--out", &out, "the clean recording to write").Required();
  std::unique_ptr<RecordingReader> reader;
  if (int exit = 0; !ParseAndOpen(&r, &a, "recover", in, &reader, &exit)) return exit;
  if (const int c = CheckOutput("recover", out, {in})) return c;
  return CopyInto("recover", in, reader.get(), out, "recover",
                  [](const RecordedMessage&) { return true; });
}

int Merge(int argc, char** argv) {
  VerbArgs a(argc, argv);
  OptionRegistry r(
      "d3d-record merge: recordings of one probe (the same serial, calibration, protocol and "
      "channels) merged into one, every message in log-time order.");
  std::vector<std::string> in;
  std::string out;
  r.Add("inputs", &in, "the recordings to merge (two or more)").Required();
  r.Add("--out", &out, "the recording to write").Required();
  if (int code = 0; !r.Parse(a.argc(), a.argv.data(), &code)) return code;
  if (in.size() < 2) return Fail("merge", "give two or more recordings to merge", 2);
  if (const int c = CheckOutput("merge", out, in)) return c;
  std::vector<std::unique_ptr<RecordingReader>> readers(in.size());
  std::vector<RecordingReader*> raw;
  for (size_t i = 0; i < in.size(); ++i) {
    if (const int c = OpenInput("merge", in[i], &readers[i])) return c;
    raw.push_back(readers[i].get());
  }
  // Refused before the output is created (MergeRecordings checks the same).
  std::vector<const RecordingHeader*> headers;
  for (const auto& rd : readers) headers.push_back(&rd->header());
  size_t differs = 0;
  if (std::string why; !SameStream(headers, &why, &differs))
    return Fail("merge", "cannot merge: " + why + " (" + in[differs] + ")", 2);
  RecordingCopyCounts counts;
  if (const int c =
          WriteRecording("merge", out, readers.front()->header(), "merge",
                         [&](RecordingWriter* w) { return MergeRecordings(raw, w, &counts); }))
    return c;
  std::fprintf(stderr, "d3d-record merge: %s: %" PRIu64 " messages from %zu recordings\n",
               out.c_str(), counts.messages_written, in.size());
  bool damaged = false;
  for (size_t i = 0; i < in.size(); ++i)
    damaged = ReportDamage("merge", in[i], *readers[i]) || damaged;
  return damaged ? kDamaged : 0;
}

// A recorded burst as a burst folder's Burst (frames named PATTERN_SET/INDEX; no truth pose).
Status BurstFromMessage(const proto::BurstMsg& m, Burst* b) {
  if (m.frames.empty() || m.width == 0 || m.height == 0) return InvalidArgument("no frames");
  b->sequence = m.burst_seq;
  b->poses_known = false;
  b->frames.clear();
  const int type = m.bit_depth > 8 ? CV_16U : CV_8U;
  for (const proto::FrameMsg& f : m.frames) {
    if (f.pixels.size() != m.BytesPerFrame())
      return InvalidArgument("frame " + std::to_string(f.pattern_index) + " has " +
                             std::to_string(f.pixels.size()) + " bytes, not " +
                             std::to_string(m.BytesPerFrame()));
    BurstFrame frame;
    frame.pattern = m.pattern_set + "/" + std::to_string(f.pattern_index);
    frame.timestamp_ns = f.timestamp_ns;
    // 9..16-bit pixels are little endian in the message, as in memory here.
    frame.image.create(static_cast<int>(m.height), static_cast<int>(m.width), type);
    std::memcpy(frame.image.data, f.pixels.data(), f.pixels.size());
    b->frames.push_back(std::move(frame));
  }
  return Status::Ok();
}

int Export(int argc, char** argv) {
  VerbArgs a(argc, argv);
  OptionRegistry r(
      "d3d-record export: a recording's bursts as burst folders: DIR/calibration.json (the "
      "probe's, from the recording) and DIR/bursts/NNNNNN/ (frame_K.png, burst.json), NNNNNN the "
      "burst's place in the file; d3d-recon --images and d3d-fuse --bursts read them.");
  std::string in, dir;
  r.Add("input", &in, "the recording").Required();
  r.Add("--bursts-dir", &dir, "the folder to write (created)").Required();
  std::unique_ptr<RecordingReader> reader;
  if (int exit = 0; !ParseAndOpen(&r, &a, "export", in, &reader, &exit)) return exit;
  const RecordingChannel* burst_ch = reader->header().FindTopic(proto::kTopicPhaseBurst);
  if (burst_ch == nullptr)
    return Fail("export", in + " has no " + proto::kTopicPhaseBurst + " channel", 2);
  const RecordingChannel* info_ch = reader->header().FindTopic(proto::kTopicProbeInfo);
  std::error_code ec;
  fs::create_directories(fs::path(dir) / "bursts", ec);
  if (ec) return Fail("export", "cannot create '" + dir + "/bursts'", 1);
  // The probe's calibration: the header's (d3d-record puts the ProbeInfo's there), else the first
  // ProbeInfo sample's.
  std::string calibration = reader->header().calibration_json;
  int64_t written = 0, undecodable = 0;
  Status failure;
  proto::BurstMsg msg;
  Burst burst;
  reader->ForEach([&](const RecordedMessage& m) {
    if (calibration.empty() && info_ch != nullptr && m.channel == info_ch->id) {
      proto::InfoMsg info;
      if (proto::Decode(m.data, &info).ok()) calibration = info.calibration_json;
    }
    if (m.channel != burst_ch->id) return true;
    if (!proto::Decode(m.data, &msg).ok() || !BurstFromMessage(msg, &burst).ok()) {
      ++undecodable;
      return true;
    }
    char name[16];
    std::snprintf(name, sizeof name, "%06" PRId64, written);
    failure = WriteBurstDir((fs::path(dir) / "bursts" / name).string(), burst, {});
    if (!failure.ok()) return false;
    ++written;
    return true;
  });
  if (!failure.ok()) return Fail("export", failure.message(), 1);
  if (!calibration.empty()) {
    std::ofstream f(fs::path(dir) / "calibration.json", std::ios::trunc);
    f << calibration;
    if (!f) return Fail("export", "cannot write '" + dir + "/calibration.json'", 1);
  } else {
    std::fprintf(stderr,
                 "d3d-record export: %s carries no calibration: %s/calibration.json not written\n",
                 in.c_str(), dir.c_str());
  }
  std::fprintf(stderr, "d3d-record export: %" PRId64 " bursts written to %s/bursts\n", written,
               dir.c_str());
  if (undecodable > 0)
    std::fprintf(stderr,
                 "d3d-record export: %" PRId64 " burst messages could not be decoded: left out\n",
                 undecodable);
  const bool damaged = ReportDamage("export", in, *reader);
  return damaged || undecodable > 0 ? kDamaged : 0;
}

// One line per message of `in`, in file order: seconds from the first message, topic, bytes, and
// what it says (a burst's sequence number and size; a status's state and counters; the probe).
int Cat(int argc, char** argv) {
  VerbArgs a(argc, argv);
  OptionRegistry r(
      "d3d-record cat: every message of a recording, one line each in file order: seconds from "
      "the first message, topic, bytes, and what it holds (a burst's sequence number, size and "
      "frames; a ProbeStatus's state and counters; a ProbeInfo's probe).");
  std::string in;
  r.Add("input", &in, "the recording").Required();
  std::unique_ptr<RecordingReader> reader;
  if (int exit = 0; !ParseAndOpen(&r, &a, "cat", in, &reader, &exit)) return exit;
  const RecordingHeader& h = reader->header();
  const RecordingChannel* burst_ch = h.FindTopic(proto::kTopicPhaseBurst);
  const RecordingChannel* info_ch = h.FindTopic(proto::kTopicProbeInfo);
  const RecordingChannel* status_ch = h.FindTopic(proto::kTopicProbeStatus);
  int64_t first_ns = 0;
  bool have_first = false;
  proto::BurstMsg burst;
  reader->ForEach([&](const RecordedMessage& m) {
    if (!have_first) first_ns = m.log_time_ns, have_first = true;
    std::string topic = "channel " + std::to_string(m.channel);
    for (const RecordingChannel& c : h.channels)
      if (c.id == m.channel) topic = c.topic;
    std::string what;
    if (burst_ch != nullptr && m.channel == burst_ch->id) {
      what = proto::Decode(m.data, &burst).ok()
                 ? "burst " + std::to_string(burst.burst_seq) + ", " + std::to_string(burst.width) +
                       "x" + std::to_string(burst.height) + "x" + std::to_string(burst.bit_depth) +
                       " bit, " + std::to_string(burst.frames.size()) + " frames"
                 : "undecodable";
    } else if (status_ch != nullptr && m.channel == status_ch->id) {
      proto::StatusMsg st;
      what = proto::Decode(m.data, &st).ok()
                 ? std::string("state ") + proto::ProbeStateName(st.state) + ", bursts published " +
                       std::to_string(st.bursts_published) + ", dropped " +
                       std::to_string(st.bursts_dropped_sync) +
                       (st.last_error.empty() ? "" : ", error: " + st.last_error)
                 : "undecodable";
    } else if (info_ch != nullptr && m.channel == info_ch->id) {
      proto::InfoMsg info;
      what = proto::Decode(m.data, &info).ok()
                 ? "probe " + info.serial + ", firmware " + info.firmware_version + ", " +
                       (info.calibration_json.empty() ? "no calibration" : "calibration")
                 : "undecodable";
    }
    std::printf("%.6f %s %zu %s\n", static_cast<double>(m.log_time_ns - first_ns) * 1e-9,
                topic.c_str(), m.data.size(), what.c_str());
    return true;
  });
  return ReportDamage("cat", in, *reader) ? kDamaged : 0;
}

}  // namespace

bool IsRecordEditVerb(const std::string& word) {
  return word == "trim" || word == "merge" || word == "recover" || word == "export" ||
         word == "cat";
}

int RunRecordEdit(int argc, char** argv) {
  const std::string verb = argv[1];
  if (verb == "trim") return Trim(argc, argv);
  if (verb == "merge") return Merge(argc, argv);
  if (verb == "recover") return Recover(argc, argv);
  if (verb == "cat") return Cat(argc, argv);
  return Export(argc, argv);
}

}  // namespace d3d
