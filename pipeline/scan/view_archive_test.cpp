#include "pipeline/scan/view_archive.h"

#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include <random>

namespace d3d {
namespace {

std::vector<cv::Mat> RandomFrames(int n, int rows, int cols, int type, uint32_t seed) {
  cv::RNG rng(seed);
  std::vector<cv::Mat> frames(static_cast<size_t>(n));
  for (cv::Mat& f : frames) {
    f.create(rows, cols, type);
    rng.fill(f, cv::RNG::UNIFORM, 0, type == CV_8UC1 ? 256 : 65536);
  }
  return frames;
}

bool Same(const std::vector<cv::Mat>& a, const std::vector<cv::Mat>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    if (a[i].size() != b[i].size() || a[i].type() != b[i].type() || cv::norm(a[i], b[i], cv::NORM_INF) != 0) return false;
  return true;
}

TEST(ViewArchive, PackedFramesComeBackBitForBit) {
  FramePacker packer;
  std::string blob;
  for (const int type : {CV_8UC1, CV_16UC1}) {
    const std::vector<cv::Mat> frames = RandomFrames(4, 48, 64, type, 7);
    ASSERT_TRUE(packer.Pack(frames, &blob).ok());
    std::vector<cv::Mat> back;
    ASSERT_TRUE(UnpackFrames(blob, &back).ok());
    EXPECT_TRUE(Same(frames, back)) << "type " << type;
  }
  // A view into a larger image (not continuous) packs its own pixels only.
  const std::vector<cv::Mat> big = RandomFrames(2, 60, 80, CV_8UC1, 3);
  const std::vector<cv::Mat> rois = {big[0](cv::Rect(5, 7, 40, 30)), big[1](cv::Rect(5, 7, 40, 30))};
  ASSERT_FALSE(rois[0].isContinuous());
  ASSERT_TRUE(packer.Pack(rois, &blob).ok());
  std::vector<cv::Mat> back;
  ASSERT_TRUE(UnpackFrames(blob, &back).ok());
  EXPECT_TRUE(Same(rois, back));
}

TEST(ViewArchive, RefusesBadFramesAndDamagedBlobs) {
  FramePacker packer;
  std::string blob;
  EXPECT_EQ(packer.Pack({}, &blob).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(packer.Pack({cv::Mat(4, 4, CV_32F, 0.0f)}, &blob).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(packer.Pack({cv::Mat(4, 4, CV_8U, 0.0), cv::Mat(4, 5, CV_8U, 0.0)}, &blob).code(), StatusCode::kInvalidArgument);
  EXPECT_THROW(FramePacker(0), std::invalid_argument);

  const std::vector<cv::Mat> frames = RandomFrames(4, 32, 32, CV_8UC1, 11);
  ASSERT_TRUE(packer.Pack(frames, &blob).ok());
  std::vector<cv::Mat> back;
  // Every cut is refused, and so is every flipped header byte that changes what the header says.
  for (size_t n = 0; n < blob.size(); n += 97) EXPECT_EQ(UnpackFrames(std::string_view(blob).substr(0, n), &back).code(), StatusCode::kCorrupt) << n;
  for (size_t i = 0; i < 16; ++i) {
    std::string bad = blob;
    bad[i] = static_cast<char>(bad[i] ^ 0x40);
    EXPECT_EQ(UnpackFrames(bad, &back).code(), StatusCode::kCorrupt) << "header byte " << i;
    EXPECT_TRUE(back.empty());
  }
  // Damage inside the compressed pixels: refused or (zstd keeps no checksum here) different
  // pixels, never a crash; the seeded positions below are all refused or decoded in full.
  std::mt19937 rng(5);
  for (int t = 0; t < 50; ++t) {
    std::string bad = blob;
    const size_t at = 16 + rng() % (bad.size() - 16);
    bad[at] = static_cast<char>(bad[at] ^ (1 << (rng() % 8)));
    const Status s = UnpackFrames(bad, &back);
    if (s.ok()) EXPECT_EQ(back.size(), frames.size());
    else EXPECT_EQ(s.code(), StatusCode::kCorrupt);
  }
}

TEST(ViewArchive, FindsEachBurstAndSaysWhichIsMissing) {
  FramePacker packer;
  ViewArchive archive;
  std::string blob;
  std::vector<std::vector<cv::Mat>> kept;
  for (uint64_t seq : {3u, 4u, 9u, 12u}) {
    kept.push_back(RandomFrames(4, 16, 24, CV_8UC1, static_cast<uint32_t>(seq)));
    ASSERT_TRUE(packer.Pack(kept.back(), &blob).ok());
    archive.Add(seq, blob);
  }
  EXPECT_EQ(archive.size(), 4u);
  EXPECT_GT(archive.bytes(), 0);
  std::vector<cv::Mat> back;
  EXPECT_TRUE(archive.Get(9, &back).ok());
  EXPECT_TRUE(Same(kept[2], back));
  EXPECT_TRUE(archive.Get(3, &back).ok());
  EXPECT_TRUE(Same(kept[0], back));
  EXPECT_EQ(archive.Get(5, &back).code(), StatusCode::kNotFound);
  // A probe that restarted its numbering: the latest entry of a number is found.
  const std::vector<cv::Mat> again = RandomFrames(4, 16, 24, CV_8UC1, 99);
  ASSERT_TRUE(packer.Pack(again, &blob).ok());
  archive.Add(4, blob);
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
}

}  // namespace
}  // namespace d3d
