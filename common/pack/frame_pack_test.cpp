#include "common/pack/frame_pack.h"

#include <gtest/gtest.h>

#include <cstring>
#include <limits>
#include <opencv2/core.hpp>
#include <random>

#include "common/pack/frame_pack_testing.h"

namespace d3d {
namespace {

using pack_testing::RandomFrames;
using pack_testing::Same;

TEST(FramePack, FramesComeBackBitForBit) {
  FramePacker packer;
  std::string blob;
  for (const int type : {CV_8UC1, CV_16UC1}) {
    const std::vector<cv::Mat> frames = RandomFrames(4, 48, 64, type, 7);
    ASSERT_TRUE(packer.Pack(frames, &blob).ok());
    std::vector<cv::Mat> back;
    ASSERT_TRUE(UnpackFrames(blob, &back).ok());
    EXPECT_TRUE(Same(frames, back)) << "type " << type;
  }
  // Organised points (CV_32FC3, NaN where none) come back bit for bit, NaNs included.
  cv::Mat points(30, 40, CV_32FC3);
  cv::RNG rng(9);
  rng.fill(points, cv::RNG::UNIFORM, -20.0, 20.0);
  for (int y = 0; y < points.rows; y += 3)
    points.row(y).setTo(cv::Scalar::all(std::numeric_limits<float>::quiet_NaN()));
  ASSERT_TRUE(packer.Pack({points}, &blob).ok());
  std::vector<cv::Mat> back_points;
  ASSERT_TRUE(UnpackFrames(blob, &back_points).ok());
  ASSERT_EQ(back_points.size(), 1u);
  ASSERT_EQ(back_points[0].type(), CV_32FC3);
  ASSERT_EQ(back_points[0].size(), points.size());
  EXPECT_EQ(std::memcmp(back_points[0].data, points.data, points.total() * points.elemSize()), 0);
  // A view into a larger image (not continuous) packs its own pixels only.
  const std::vector<cv::Mat> big = RandomFrames(2, 60, 80, CV_8UC1, 3);
  const std::vector<cv::Mat> rois = {big[0](cv::Rect(5, 7, 40, 30)),
                                     big[1](cv::Rect(5, 7, 40, 30))};
  ASSERT_FALSE(rois[0].isContinuous());
  ASSERT_TRUE(packer.Pack(rois, &blob).ok());
  std::vector<cv::Mat> back;
  ASSERT_TRUE(UnpackFrames(blob, &back).ok());
  EXPECT_TRUE(Same(rois, back));
}

TEST(FramePack, RefusesBadFramesAndDamagedBlobs) {
  FramePacker packer;
  std::string blob;
  EXPECT_EQ(packer.Pack({}, &blob).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(packer.Pack({cv::Mat(4, 4, CV_64F, 0.0)}, &blob).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(packer.Pack({cv::Mat(4, 4, CV_8SC1, 0.0)}, &blob).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(packer.Pack({cv::Mat(4, 4, CV_8U, 0.0), cv::Mat(4, 5, CV_8U, 0.0)}, &blob).code(),
            StatusCode::kInvalidArgument);
  EXPECT_THROW(FramePacker(0), std::invalid_argument);

  const std::vector<cv::Mat> frames = RandomFrames(4, 32, 32, CV_8UC1, 11);
  ASSERT_TRUE(packer.Pack(frames, &blob).ok());
  std::vector<cv::Mat> back;
  // Every cut is refused, and so is every flipped header byte that changes what the header says.
  for (size_t n = 0; n < blob.size(); n += 97)
    EXPECT_EQ(UnpackFrames(std::string_view(blob).substr(0, n), &back).code(), StatusCode::kCorrupt)
        << n;
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
    if (s.ok())
      EXPECT_EQ(back.size(), frames.size());
    else
      EXPECT_EQ(s.code(), StatusCode::kCorrupt);
  }
}

}  // namespace
}  // namespace d3d
