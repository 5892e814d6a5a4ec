#include "common/recording/recording_edit.h"

#include <queue>
#include <tuple>

namespace d3d {

Status CopyMessages(RecordingReader* in, const std::function<bool(const RecordedMessage&)>& keep,
                    RecordingWriter* out, RecordingCopyCounts* counts) {
  Status failure;
  in->ForEach([&](const RecordedMessage& m) {
    ++counts->messages_read;
    if (!keep(m)) return true;
    failure = out->Add(m.channel, m.log_time_ns, m.data);
    if (!failure.ok()) return false;
    ++counts->messages_written;
    return true;
  });
  return failure;
}

bool SameStream(const std::vector<const RecordingHeader*>& headers, std::string* why,
                size_t* differs) {
  if (headers.empty()) return true;
  const RecordingHeader& a = *headers.front();
  for (size_t i = 1; i < headers.size(); ++i) {
    const RecordingHeader& b = *headers[i];
    const std::string which = "input " + std::to_string(i + 1);
    if (differs != nullptr) *differs = i;
    if (b.protocol_version != a.protocol_version) {
      *why = which + " has protocol version " + std::to_string(b.protocol_version) +
             ", the first " + std::to_string(a.protocol_version);
      return false;
    }
    if (b.probe_serial != a.probe_serial) {
      *why = which + " was recorded from probe '" + b.probe_serial + "', the first from '" +
             a.probe_serial + "'";
      return false;
    }
    if (b.calibration_json != a.calibration_json) {
      *why = which + " carries another calibration than the first";
      return false;
    }
    bool same = b.channels.size() == a.channels.size();
    for (size_t c = 0; same && c < a.channels.size(); ++c)
      same = a.channels[c].id == b.channels[c].id && a.channels[c].topic == b.channels[c].topic &&
             a.channels[c].schema == b.channels[c].schema;
    if (!same) {
      *why = which + " has other channels (topics or schemas) than the first";
      return false;
    }
  }
  return true;
}

namespace {

// One input's read position: its chunks in file order, a chunk's messages at a time.
struct Cursor {
  RecordingReader* reader = nullptr;
  size_t next_chunk = 0;
  std::vector<RecordedMessage> messages;
  size_t at = 0;
  // The next message, reading chunks as needed (a chunk that does not read is skipped: the
  // reader's diagnostics record it); null at the end.
  const RecordedMessage* Peek(uint64_t* read) {
    while (at >= messages.size()) {
      if (next_chunk >= reader->chunks().size()) return nullptr;
      messages.clear();
      at = 0;
      if (!reader->ReadChunk(next_chunk++, &messages).ok()) messages.clear();
      *read += messages.size();
    }
    return &messages[at];
  }
};

}  // namespace

Status MergeRecordings(const std::vector<RecordingReader*>& in, RecordingWriter* out,
                       RecordingCopyCounts* counts) {
  std::vector<const RecordingHeader*> headers;
  for (const RecordingReader* r : in) headers.push_back(&r->header());
  if (std::string why; !SameStream(headers, &why)) return InvalidArgument("cannot merge: " + why);
  std::vector<Cursor> cursors(in.size());
  // (log time, input): the smallest first; equal times in input order.
  using Key = std::tuple<int64_t, size_t>;
  std::priority_queue<Key, std::vector<Key>, std::greater<Key>> heads;
  for (size_t i = 0; i < in.size(); ++i) {
    cursors[i].reader = in[i];
    if (const RecordedMessage* m = cursors[i].Peek(&counts->messages_read))
      heads.emplace(m->log_time_ns, i);
  }
  while (!heads.empty()) {
    const size_t i = std::get<1>(heads.top());
    heads.pop();
    Cursor& c = cursors[i];
    const RecordedMessage& m = c.messages[c.at];
    D3D_RETURN_IF_ERROR(out->Add(m.channel, m.log_time_ns, m.data));
    ++counts->messages_written;
    ++c.at;
    if (const RecordedMessage* next = c.Peek(&counts->messages_read))
      heads.emplace(next->log_time_ns, i);
  }
  return Status::Ok();
}

}  // namespace d3d
