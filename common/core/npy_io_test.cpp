#include "common/core/npy_io.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>

namespace d3d {
namespace {

std::string TempPath(const std::string& name) {
  return (std::filesystem::temp_directory_path() / ("d3d_npy_" + name)).string();
}

TEST(Npy, RoundTripFloatMap) {
  std::vector<float> v(4 * 3 * 2);
  for (size_t i = 0; i < v.size(); ++i) v[i] = 0.5f * static_cast<float>(i) - 3.f;
  const std::string p = TempPath("f.npy");
  ASSERT_TRUE(WriteNpy(p, NpyType::kFloat32, {4, 3, 2}, v.data()).ok());
  NpyArray a;
  ASSERT_TRUE(ReadNpy(p, &a).ok());
  EXPECT_EQ(a.shape, (std::vector<int64_t>{4, 3, 2}));
  ASSERT_EQ(a.bytes.size(), v.size() * 4);
  EXPECT_EQ(0, std::memcmp(a.bytes.data(), v.data(), a.bytes.size()));
  // The header + data is 64-byte aligned as numpy requires.
  EXPECT_EQ((std::filesystem::file_size(p) - v.size() * 4) % 64, 0u);
}

TEST(Npy, OneDimensionalShapeHasTrailingComma) {
  const uint8_t v[3] = {1, 2, 3};
  const std::string p = TempPath("u8.npy");
  ASSERT_TRUE(WriteNpy(p, NpyType::kUint8, {3}, v).ok());
  std::ifstream f(p, std::ios::binary);
  std::string all((std::istreambuf_iterator<char>(f)), {});
  EXPECT_NE(all.find("'shape': (3,)"), std::string::npos);
  NpyArray a;
  ASSERT_TRUE(ReadNpy(p, &a).ok());
  EXPECT_EQ(a.shape, std::vector<int64_t>{3});
}

TEST(Npy, TruncatedAndWrongMagicAreReported) {
  const float v[4] = {1, 2, 3, 4};
  const std::string p = TempPath("t.npy");
  ASSERT_TRUE(WriteNpy(p, NpyType::kFloat32, {4}, v).ok());
  std::filesystem::resize_file(p, std::filesystem::file_size(p) - 3);
  NpyArray a;
  EXPECT_EQ(ReadNpy(p, &a).code(), StatusCode::kCorrupt);
  {
    std::ofstream f(p, std::ios::binary | std::ios::trunc);
    f << "not an npy file at all";
  }
  EXPECT_EQ(ReadNpy(p, &a).code(), StatusCode::kParseError);
  EXPECT_EQ(ReadNpy(TempPath("missing.npy"), &a).code(), StatusCode::kNotFound);
}

}  // namespace
}  // namespace d3d
