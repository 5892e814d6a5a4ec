// One fuzz iteration over our small parsers: the first byte picks the parser, the rest is its
// input.
//   0: ParseNpy (common/core/npy_io.h)   1: ProbeCalibration::FromJson (calib/model)
// Never crashes or throws for any input; a successful parse is checked for consistency.
#pragma once

#include <cstddef>
#include <cstdint>

namespace d3d {
void FuzzFormatsOnce(const uint8_t* data, size_t size);
}  // namespace d3d
