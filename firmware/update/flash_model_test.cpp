#include "firmware/update/flash_model.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>

namespace d3d::fw {
namespace {

FlashGeometry Small() {
  FlashGeometry g;
  g.erase_block_bytes = 4096;
  g.page_bytes = 256;
  g.size_bytes = 4 * 4096;
  return g;
}

TEST(Flash, StartsErasedProgramsOnlyErasedBytesAndErasesBlocks) {
  auto f = Flash::InMemory(Small());
  std::vector<uint8_t> b(300);
  ASSERT_TRUE(f->Read(100, b).ok());
  for (uint8_t x : b) ASSERT_EQ(x, 0xFF);
  std::vector<uint8_t> data(300, 0x5A);
  ASSERT_TRUE(f->Program(4096, data).ok());
  EXPECT_EQ(f->stats().page_programs, 2);  // 300 bytes = one full page + a partial one
  const Status again = f->Program(4096, data);
  EXPECT_EQ(again.code(), StatusCode::kCorrupt) << again.ToString();  // not erased
  ASSERT_TRUE(f->EraseBlock(4096).ok());
  ASSERT_TRUE(f->Program(4096, data).ok());
  ASSERT_TRUE(f->Read(4096, b).ok());
  EXPECT_EQ(b, data);
}

TEST(Flash, RefusesMisalignedAndOutOfRangeOperations) {
  auto f = Flash::InMemory(Small());
  std::vector<uint8_t> d(16, 0);
  EXPECT_EQ(f->Program(10, d).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(f->EraseBlock(100).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(f->EraseBlock(4 * 4096).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(f->Program(4 * 4096 - 8, d).code(), StatusCode::kInvalidArgument);
  std::vector<uint8_t> r(8);
  EXPECT_EQ(f->Read(4 * 4096 - 4, r).code(), StatusCode::kInvalidArgument);
  FlashGeometry bad = Small();
  bad.size_bytes = 5000;
  EXPECT_THROW(bad.Check(), std::invalid_argument);
}

TEST(Flash, PowerCutTearsTheOperationAndKillsTheRest) {
  auto f = Flash::InMemory(Small());
  f->CutPowerAfterOps(1);  // op 0 succeeds, op 1 is torn
  std::vector<uint8_t> data(512, 0x00);
  const Status s = f->Program(0, data);
  EXPECT_EQ(s.code(), StatusCode::kUnavailable);
  EXPECT_TRUE(f->power_cut());
  f->PowerCycle();
  std::vector<uint8_t> r(512);
  ASSERT_TRUE(f->Read(0, r).ok());
  for (int i = 0; i < 256; ++i) ASSERT_EQ(r[i], 0x00);    // first page programmed
  for (int i = 256; i < 384; ++i) ASSERT_EQ(r[i], 0x00);  // torn page: half written
  for (int i = 384; i < 512; ++i) ASSERT_EQ(r[i], 0xFF);
}

TEST(Flash, FileBackedContentSurvivesReopening) {
  const std::string path =
      (std::filesystem::temp_directory_path() / ("d3d_flash_" + std::to_string(::getpid())))
          .string();
  std::filesystem::remove(path);
  {
    std::unique_ptr<Flash> f;
    ASSERT_TRUE(Flash::OpenFile(path, Small(), &f).ok());
    std::vector<uint8_t> d(256, 0x11);
    ASSERT_TRUE(f->Program(8192, d).ok());
  }
  std::unique_ptr<Flash> f;
  ASSERT_TRUE(Flash::OpenFile(path, Small(), &f).ok());
  std::vector<uint8_t> r(256);
  ASSERT_TRUE(f->Read(8192, r).ok());
  EXPECT_EQ(r, std::vector<uint8_t>(256, 0x11));
  FlashGeometry other = Small();
  other.size_bytes *= 2;
  EXPECT_EQ(Flash::OpenFile(path, other, &f).code(), StatusCode::kInvalidArgument);
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace d3d::fw
