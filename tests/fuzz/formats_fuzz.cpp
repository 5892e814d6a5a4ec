#include "tests/fuzz/formats_fuzz.h"

#include <cstdlib>
#include <string>
#include <string_view>

#include "calib/model/probe_calibration.h"
#include "common/core/npy_io.h"

namespace d3d {

void FuzzFormatsOnce(const uint8_t* data, size_t size) {
  if (size == 0) return;
  const std::string_view bytes(reinterpret_cast<const char*>(data) + 1, size - 1);
  if (data[0] % 2 == 0) {
    NpyArray a;
    if (ParseNpy(bytes, &a).ok() &&
        a.bytes.size() != static_cast<size_t>(a.NumElements()) * NpyArray::ElementSize(a.type)) {
      std::abort();  // a parsed array must hold exactly its shape's bytes
    }
  } else {
    ProbeCalibration c;
    if (ProbeCalibration::FromJson(std::string(bytes), &c).ok())
      c.Check();  // ok ⇒ valid (throws otherwise)
  }
}

}  // namespace d3d

#ifdef D3D_LIBFUZZER_MAIN
extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  d3d::FuzzFormatsOnce(data, size);
  return 0;
}
#endif
