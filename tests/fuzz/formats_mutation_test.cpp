// Deterministic stand-in for the fuzzer that runs in every CTest run (GCC, no libFuzzer): seeded
// mutations of valid .npy and calibration.json inputs must never crash, throw or yield an
// inconsistent result.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>

#include "calib/model/probe_calibration.h"
#include "common/core/npy_io.h"
#include "tests/fuzz/formats_fuzz.h"

namespace d3d {
namespace {

std::string ValidNpy() {
  const float v[6] = {1, 2, 3, 4, 5, 6};
  const auto p = std::filesystem::temp_directory_path() / "d3d_formats_seed.npy";
  EXPECT_TRUE(WriteNpy(p.string(), NpyType::kFloat32, {2, 3}, v).ok());
  std::ifstream f(p, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(f)), {});
}

std::string ValidCalibration() {
  ProbeCalibration c;
  c.camera = {640, 480, 2000, 2000, 319.5, 239.5, -0.05, 0.1, 0, 0, 0};
  c.projector = {912, 1140, 2100, 2100, 455.5, 569.5, 0.03, 0, 0, 0, 0};
  c.cam_from_proj.translation() = Eigen::Vector3d(10.6, 0, 0);
  c.depth_min_mm = 42;
  c.depth_max_mm = 58;
  return c.ToJson();
}

TEST(FormatsFuzz, SeedInputsParse) {
  NpyArray a;
  ASSERT_TRUE(ParseNpy(ValidNpy(), &a).ok());
  EXPECT_EQ(a.shape, (std::vector<int64_t>{2, 3}));
  ProbeCalibration c;
  ASSERT_TRUE(ProbeCalibration::FromJson(ValidCalibration(), &c).ok());
}

TEST(FormatsFuzz, SeededMutationsNeverCrash) {
  // Selector byte + input (built with append: GCC 12 warns falsely on operator+ here, PR105651).
  std::string seeds[2];
  seeds[0].push_back('\0');
  seeds[0].append(ValidNpy());
  seeds[1].push_back('\1');
  seeds[1].append(ValidCalibration());
  std::mt19937 rng(20261121);
  int parsed = 0;
  for (int i = 0; i < 4000; ++i) {
    std::string s = seeds[i % 2];
    const int edits = 1 + static_cast<int>(rng() % 8);
    for (int e = 0; e < edits && s.size() > 1; ++e) {
      const size_t pos = 1 + rng() % (s.size() - 1);
      switch (rng() % 4) {
        case 0:
          s[pos] = static_cast<char>(s[pos] ^ (1 << (rng() % 8)));
          break;  // bit flip
        case 1:
          s.resize(pos);
          break;  // truncation
        case 2:
          s = s.substr(0, pos) + std::string(1 + rng() % 4, static_cast<char>(rng())) +
              s.substr(pos);
          break;
        default:
          s[pos] = "0123456789-.eE,:{}[]\"() "[rng() % 24];
          break;  // plausible token
      }
    }
    EXPECT_NO_THROW(FuzzFormatsOnce(reinterpret_cast<const uint8_t*>(s.data()), s.size())) << i;
    NpyArray a;
    parsed += (i % 2 == 0) && ParseNpy(std::string_view(s).substr(1), &a).ok();
  }
  EXPECT_GT(parsed, 0) << "some mutations keep a valid file";
}

}  // namespace
}  // namespace d3d
