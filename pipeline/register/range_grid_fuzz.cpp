// libFuzzer target for ParseRangeGridPly (built with -DD3D_FUZZ=ON and clang; run by
// tools/test.sh).
#include <cstddef>
#include <cstdint>
#include <string>

#include "pipeline/register/range_grid_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  cv::Mat points;
  const d3d::Status s = d3d::ParseRangeGridPly(
      std::string(reinterpret_cast<const char*>(data), size), 1000.0, &points);
  if (s.ok() && points.type() != CV_32FC3) __builtin_trap();
  return 0;
}
