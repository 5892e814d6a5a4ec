#include "tests/fuzz/recording_fuzz.h"

#include <cstdlib>
#include <string>
#include <string_view>

#include "common/recording/recording.h"
#include "protocol/codec.h"

namespace d3d {

void FuzzRecordingOnce(const uint8_t* data, size_t size) {
  if (size == 0) return;
  const std::string_view bytes(reinterpret_cast<const char*>(data) + 1, size - 1);
  switch (data[0] % 4) {
    case 0: {
      std::unique_ptr<RecordingReader> r;
      if (!RecordingReader::Open(MemorySource(std::string(bytes)), &r).ok()) return;
      uint64_t total = 0;
      for (const ChunkInfo& c : r->chunks()) {
        if (c.offset + 40 + c.compressed_size > bytes.size())
          std::abort();  // a chunk lies inside the file
        total += c.compressed_size;
      }
      if (total > bytes.size()) std::abort();
      std::vector<RecordedMessage> msgs;
      SequenceLossCounter lost(
          r.get());  // channel 0's messages numbered by their place in the file
      uint64_t seq = 0;
      for (size_t i = 0; i < r->chunks().size(); ++i) {
        const bool ok = r->ReadChunk(i, &msgs).ok();
        if (ok && msgs.size() != r->chunks()[i].message_count) std::abort();
        if (!ok && !msgs.empty()) std::abort();
        if (!ok && !r->diagnostics().damaged())
          std::abort();  // a lost chunk makes the file damaged
        lost.Chunk(i, ok);
        for (const RecordedMessage& m : msgs)
          if (m.channel == 0) lost.Message(seq++, m.data.size());
      }
      lost.End();
      if (lost.lost_max() && *lost.lost_max() < lost.lost_min()) std::abort();
      if (r->diagnostics().LossSummary().empty() || lost.Describe().empty()) std::abort();
      break;
    }
    case 1: {
      proto::BurstMsg m;
      if (proto::Decode(bytes, &m).ok()) {
        for (const auto& f : m.frames)
          if (f.pixels.size() != m.BytesPerFrame()) std::abort();
        std::string again;
        proto::Encode(m, &again);
        if (again != bytes) std::abort();  // decode ∘ encode is the identity on valid input
      }
      break;
    }
    case 2: {
      proto::InfoMsg m;
      if (proto::Decode(bytes, &m).ok()) {
        std::string again;
        proto::Encode(m, &again);
        if (again != bytes) std::abort();
      }
      break;
    }
    default: {
      proto::StatusMsg m;
      if (proto::Decode(bytes, &m).ok()) {
        std::string again;
        proto::Encode(m, &again);
        if (again != bytes) std::abort();
      }
      break;
    }
  }
}

}  // namespace d3d

#ifdef D3D_LIBFUZZER_MAIN
extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  d3d::FuzzRecordingOnce(data, size);
  return 0;
}
#endif
