// One fuzz iteration over the recording reader and the protocol codec: the first byte picks the
// parser, the rest is its input.
//   0: RecordingReader (common/recording) on the bytes as a file, then every chunk read
//   1: proto::Decode BurstMsg   2: Decode InfoMsg   3: Decode StatusMsg   (protocol/codec.h)
// Never crashes or throws for any input; what parses is checked for consistency (aborts otherwise).
#pragma once

#include <cstddef>
#include <cstdint>

namespace d3d {
void FuzzRecordingOnce(const uint8_t* data, size_t size);
}  // namespace d3d
