#include "pipeline/chain/view_archive.h"

#include <gtest/gtest.h>
#include <sys/resource.h>

#include <csignal>
#include <filesystem>
#include <opencv2/core.hpp>
#include <random>

#include "common/pack/frame_pack_testing.h"

namespace d3d {
namespace {

using pack_testing::RandomFrames;
using pack_testing::Same;

// The same answers from memory and from a spill file.
class ViewArchiveWhere : public ::testing::TestWithParam<bool> {};

TEST_P(ViewArchiveWhere, FindsEachBurstAndSaysWhichIsMissing) {
  FramePacker packer;
  ViewArchive archive;
  if (GetParam()) {
    ASSERT_TRUE(archive.SpillTo(::testing::TempDir()).ok());
  }
  EXPECT_EQ(archive.spilling(), GetParam());
  std::string blob;
  std::vector<std::vector<cv::Mat>> kept;
  for (uint64_t seq : {3u, 4u, 9u, 12u}) {
    kept.push_back(RandomFrames(4, 16, 24, CV_8UC1, static_cast<uint32_t>(seq)));
    ASSERT_TRUE(packer.Pack(kept.back(), &blob).ok());
    ASSERT_TRUE(archive.Add(seq, blob).ok());
  }
  EXPECT_EQ(archive.size(), 4u);
  EXPECT_GT(archive.bytes(), 0);
  // Spilled, memory holds the index only.
  EXPECT_EQ(archive.spilled_bytes(), GetParam() ? archive.bytes() : 0);
  if (GetParam()) {
    EXPECT_LT(archive.memory_bytes(), 4 * 100);
  } else {
    EXPECT_GE(archive.memory_bytes(), archive.bytes());
  }
  std::vector<cv::Mat> back;
  EXPECT_TRUE(archive.Get(9, &back).ok());
  EXPECT_TRUE(Same(kept[2], back));
  EXPECT_TRUE(archive.Get(3, &back).ok());
  EXPECT_TRUE(Same(kept[0], back));
  EXPECT_EQ(archive.Get(5, &back).code(), StatusCode::kNotFound);
  // A probe that restarted its numbering: the latest entry of a number is found.
  const std::vector<cv::Mat> again = RandomFrames(4, 16, 24, CV_8UC1, 99);
  ASSERT_TRUE(packer.Pack(again, &blob).ok());
  ASSERT_TRUE(archive.Add(4, blob).ok());
  ASSERT_TRUE(archive.Get(4, &back).ok());
  EXPECT_TRUE(Same(again, back));
  ASSERT_TRUE(archive.Get(12, &back).ok());
  EXPECT_TRUE(Same(kept[3], back));
  // An undo drops the newest entry of a number: the older one is found again, then none.
  const int64_t bytes = archive.bytes();
  EXPECT_TRUE(archive.Remove(4));
  EXPECT_EQ(archive.size(), 4u);
  EXPECT_LT(archive.bytes(), bytes);
  ASSERT_TRUE(archive.Get(4, &back).ok());
  EXPECT_TRUE(Same(kept[1], back));
  EXPECT_TRUE(archive.Remove(4));
  EXPECT_EQ(archive.Get(4, &back).code(), StatusCode::kNotFound);
  EXPECT_FALSE(archive.Remove(4));
  EXPECT_TRUE(archive.Remove(12));
  ASSERT_TRUE(archive.Get(9, &back).ok());
  EXPECT_TRUE(Same(kept[2], back));
  archive.Clear();
  EXPECT_EQ(archive.size(), 0u);
  EXPECT_EQ(archive.bytes(), 0);
  EXPECT_EQ(archive.Get(9, &back).code(), StatusCode::kNotFound);
  // After Clear the archive fills again (from the start of its file when spilling).
  ASSERT_TRUE(archive.Add(20, blob).ok());
  ASSERT_TRUE(archive.Get(20, &back).ok());
  EXPECT_TRUE(Same(again, back));
  EXPECT_EQ(archive.spilled_bytes(), GetParam() ? archive.bytes() : 0);
}

INSTANTIATE_TEST_SUITE_P(MemoryAndFile, ViewArchiveWhere, ::testing::Values(false, true),
                         [](const ::testing::TestParamInfo<bool>& i) {
                           return i.param ? "Spilled" : "InMemory";
                         });

TEST(ViewArchive, SpillFileHasNoNameAndNoDirectoryIsRefused) {
  ViewArchive archive;
  const Status bad = archive.SpillTo("/nonexistent-d3d-dir");
  EXPECT_EQ(bad.code(), StatusCode::kIoError) << bad.ToString();
  EXPECT_NE(bad.message().find("/nonexistent-d3d-dir"), std::string::npos);
  EXPECT_FALSE(archive.spilling());
  // A fresh directory: spilling leaves no file in it.
  const std::string dir = ::testing::TempDir() + "/d3d_view_archive_spill";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  ASSERT_TRUE(archive.SpillTo(dir).ok());
  EXPECT_EQ(archive.SpillTo(dir).code(), StatusCode::kInvalidArgument);
  FramePacker packer;
  std::string blob;
  ASSERT_TRUE(packer.Pack(RandomFrames(4, 16, 24, CV_8UC1, 1), &blob).ok());
  ASSERT_TRUE(archive.Add(1, blob).ok());
  EXPECT_TRUE(std::filesystem::is_empty(dir));
  std::filesystem::remove_all(dir);
}

// A spill write that fails (here: the process's file-size limit, as a full disk would) keeps the
// blob in memory and says so; the views before and after it all come back.
TEST(ViewArchive, AFailedSpillWriteKeepsTheViewInMemory) {
  FramePacker packer;
  ViewArchive archive;
  ASSERT_TRUE(archive.SpillTo(::testing::TempDir()).ok());
  std::vector<std::vector<cv::Mat>> kept;
  std::vector<std::string> blobs;
  for (uint32_t i = 0; i < 3; ++i) {
    kept.push_back(RandomFrames(4, 16, 24, CV_8UC1, 40 + i));
    blobs.emplace_back();
    ASSERT_TRUE(packer.Pack(kept.back(), &blobs.back()).ok());
  }
  ASSERT_TRUE(archive.Add(1, blobs[0]).ok());
  struct rlimit old_limit;
  ASSERT_EQ(getrlimit(RLIMIT_FSIZE, &old_limit), 0);
  const auto old_handler =
      std::signal(SIGXFSZ, SIG_IGN);  // else the write beyond the limit kills us
  struct rlimit small = old_limit;
  small.rlim_cur =
      static_cast<rlim_t>(blobs[0].size());  // the file may not grow beyond its first blob
  ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &small), 0);
  const Status failed = archive.Add(2, blobs[1]);
  ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &old_limit), 0);
  std::signal(SIGXFSZ, old_handler);
  EXPECT_EQ(failed.code(), StatusCode::kIoError) << failed.ToString();
  EXPECT_NE(failed.message().find("kept in memory"), std::string::npos) << failed.message();
  ASSERT_TRUE(archive.Add(3, blobs[2]).ok());
  EXPECT_EQ(archive.size(), 3u);
  EXPECT_EQ(archive.spilled_bytes(), static_cast<int64_t>(blobs[0].size() + blobs[2].size()));
  EXPECT_GE(archive.memory_bytes(), static_cast<int64_t>(blobs[1].size()));
  std::vector<cv::Mat> back;
  for (uint64_t seq = 1; seq <= 3; ++seq) {
    ASSERT_TRUE(archive.Get(seq, &back).ok()) << seq;
    EXPECT_TRUE(Same(kept[seq - 1], back)) << seq;
  }
}

}  // namespace
}  // namespace d3d
