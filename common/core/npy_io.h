// NumPy .npy (format 1.0) reading and writing of dense float/uint8 arrays, so ground-truth maps
// open directly in Python (numpy.load) and in our tools. Little-endian, C order.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "common/core/status.h"

namespace d3d {

enum class NpyType { kFloat32, kFloat64, kUint8, kUint16, kInt32 };

// A dense array: shape (e.g. {H, W} or {H, W, 3}) and raw little-endian bytes.
struct NpyArray {
  NpyType type = NpyType::kFloat32;
  std::vector<int64_t> shape;
  std::vector<uint8_t> bytes;

  int64_t NumElements() const;
  static int ElementSize(NpyType type);
};

// Writes `data` (NumElements * ElementSize bytes) with the given shape. IO_ERROR on failure.
[[nodiscard]] Status WriteNpy(const std::string& path, NpyType type,
                              const std::vector<int64_t>& shape, const void* data);
// Reads an .npy written by WriteNpy or numpy.save (v1.0/2.0 header, little-endian, C order).
// PARSE_ERROR for a bad magic/header, UNSUPPORTED for big-endian/Fortran order/other dtypes,
// CORRUPT when the file is shorter than its header says.
[[nodiscard]] Status ReadNpy(const std::string& path, NpyArray* out);
// The same on the bytes of a whole .npy file.
[[nodiscard]] Status ParseNpy(std::string_view bytes, NpyArray* out);

}  // namespace d3d
