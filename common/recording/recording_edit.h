// Editing recordings (d3d record trim | merge | recover): the messages of one or more recordings
// copied into a new one, chunk by chunk, each message's channel, log time and bytes unchanged. A
// damaged input is read as RecordingReader reads it: every intact chunk is copied, and its
// diagnostics() say what was lost; the output is a clean file (index and footer), which is how
// `recover` rewrites a damaged recording.
//
// Threads: one thread per call; the readers and the writer are used by it alone meanwhile.
#pragma once

#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "common/core/status.h"
#include "common/recording/recording.h"

namespace d3d {

// A half-open range of log times [from_ns, to_ns) (Unix epoch ns).
struct LogTimeRange {
  int64_t from_ns = std::numeric_limits<int64_t>::min();
  int64_t to_ns = std::numeric_limits<int64_t>::max();
  bool Contains(int64_t t_ns) const { return t_ns >= from_ns && t_ns < to_ns; }
};

struct RecordingCopyCounts {
  uint64_t messages_read = 0;     // of the intact chunks
  uint64_t messages_written = 0;  // those kept
};

// Copies the messages of `in` (every intact chunk, in file order) for which `keep` returns true
// into `out` (open, with a header whose channels hold every kept message's channel). IO_ERROR or
// INVALID_ARGUMENT from the writer; a chunk that does not read is skipped (in->diagnostics()).
[[nodiscard]] Status CopyMessages(RecordingReader* in,
                                  const std::function<bool(const RecordedMessage&)>& keep,
                                  RecordingWriter* out, RecordingCopyCounts* counts);

// Whether recordings can be merged into one: the same channels (id, topic, schema), protocol
// version, probe serial and calibration. False with *why naming the first input (by index) that
// differs from the first and in what, and *differs (when given) its index in `headers`.
bool SameStream(const std::vector<const RecordingHeader*>& headers, std::string* why,
                size_t* differs = nullptr);

// Merges the messages of `in` (intact chunks) into `out` in log-time order; equal times keep the
// inputs' order. Messages are read a chunk at a time per input (memory: one chunk per input).
// INVALID_ARGUMENT when the inputs are not SameStream; IO_ERROR from the writer.
[[nodiscard]] Status MergeRecordings(const std::vector<RecordingReader*>& in, RecordingWriter* out,
                                     RecordingCopyCounts* counts);

}  // namespace d3d
