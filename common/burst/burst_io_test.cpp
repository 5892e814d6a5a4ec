#include "common/burst/burst_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>

namespace d3d {
namespace {

namespace fs = std::filesystem;

Burst MakeBurst() {
  Burst b;
  b.sequence = 17;
  for (int i = 0; i < 5; ++i) {
    BurstFrame f;
    f.pattern = i < 4 ? "phase4-marker/" + std::to_string(i) : "texture";
    f.image = cv::Mat(12, 16, CV_8U, cv::Scalar(10 * i));
    f.image.at<uint8_t>(3, 4) = 200;
    f.timestamp_ns = 1'000'000'000 + i * 2'500'000;
    f.truth.world_from_probe = RigidFromQuaternion(
        Eigen::Quaterniond(Eigen::AngleAxisd(0.1 * i, Eigen::Vector3d::UnitX())),
        Eigen::Vector3d(1, 2, 3 + i));
    b.frames.push_back(f);
  }
  FrameTruth& t = b.frames[0].truth;
  t.depth_mm = cv::Mat(12, 16, CV_32F, cv::Scalar(50.25f));
  t.depth_mm.at<float>(0, 0) = std::numeric_limits<float>::quiet_NaN();
  t.points_in_cam = cv::Mat(12, 16, CV_32FC3, cv::Scalar(1, 2, 50.25f));
  t.projector_uv = cv::Mat(12, 16, CV_32FC2, cv::Scalar(400.5f, 600.25f));
  t.visibility = cv::Mat(12, 16, CV_8U, cv::Scalar(2));
  t.label = cv::Mat(12, 16, CV_8U, cv::Scalar(2));
  t.face_index = cv::Mat(12, 16, CV_32S, cv::Scalar(1234));
  b.reference_ns = 1'000'003'750;
  b.reference_truth = t;
  b.reference_truth.depth_mm = cv::Mat(12, 16, CV_32F, cv::Scalar(49.5f));
  return b;
}

fs::path TempDir(const std::string& name) {
  const fs::path p = fs::temp_directory_path() / ("d3d_burst_test_" + name);
  fs::remove_all(p);
  return p;
}

TEST(BurstIo, RoundTripWithTruth) {
  const Burst b = MakeBurst();
  const fs::path dir = TempDir("rt");
  ASSERT_TRUE(WriteBurstDir(dir.string(), b, {0}).ok());
  Burst back;
  ASSERT_TRUE(ReadBurstDir(dir.string(), true, &back).ok());
  ASSERT_EQ(back.frames.size(), 5u);
  EXPECT_EQ(back.sequence, 17u);
  for (size_t i = 0; i < 5; ++i) {
    EXPECT_EQ(back.frames[i].pattern, b.frames[i].pattern);
    EXPECT_EQ(back.frames[i].timestamp_ns, b.frames[i].timestamp_ns);
    EXPECT_EQ(cv::norm(back.frames[i].image, b.frames[i].image, cv::NORM_INF), 0.0);
    EXPECT_TRUE(
        back.frames[i].truth.world_from_probe.isApprox(b.frames[i].truth.world_from_probe, 1e-12));
  }
  const FrameTruth& t = back.frames[0].truth;
  ASSERT_TRUE(t.has_maps());
  EXPECT_TRUE(std::isnan(t.depth_mm.at<float>(0, 0)));
  EXPECT_EQ(t.depth_mm.at<float>(5, 5), 50.25f);
  EXPECT_EQ(t.projector_uv.at<cv::Vec2f>(2, 3)[1], 600.25f);
  EXPECT_EQ(t.face_index.at<int>(11, 15), 1234);
  EXPECT_FALSE(back.frames[1].truth.has_maps());
  EXPECT_EQ(back.reference_ns, 1'000'003'750);
  ASSERT_TRUE(back.reference_truth.has_maps());
  EXPECT_EQ(back.reference_truth.depth_mm.at<float>(3, 3), 49.5f);
}

// A burst whose poses are not known (exported from a recording) says so: no world_from_probe in
// burst.json, read back as unknown; a simulated burst's poses still are.
TEST(BurstIo, UnknownPosesAreLeftOutNotWrittenAsIdentity) {
  Burst b = MakeBurst();
  b.reference_truth = FrameTruth{};
  for (BurstFrame& f : b.frames) f.truth = FrameTruth{};
  b.poses_known = false;
  const fs::path dir = TempDir("no_poses");
  ASSERT_TRUE(WriteBurstDir(dir.string(), b, {}).ok());
  std::ifstream f(dir / "burst.json");
  const std::string json((std::istreambuf_iterator<char>(f)), {});
  EXPECT_EQ(json.find("world_from_probe"), std::string::npos) << json;
  Burst back;
  ASSERT_TRUE(ReadBurstDir(dir.string(), true, &back).ok());
  EXPECT_FALSE(back.poses_known);
  ASSERT_EQ(back.frames.size(), 5u);
  EXPECT_EQ(back.frames[4].pattern, "texture");
  const fs::path with = TempDir("with_poses");
  ASSERT_TRUE(WriteBurstDir(with.string(), MakeBurst(), {}).ok());
  ASSERT_TRUE(ReadBurstDir(with.string(), true, &back).ok());
  EXPECT_TRUE(back.poses_known);
}

TEST(BurstIo, ClearErrorsForBrokenFolders) {
  Burst out;
  EXPECT_EQ(ReadBurstDir(TempDir("none").string(), false, &out).code(), StatusCode::kNotFound);
  const fs::path dir = TempDir("broken");
  ASSERT_TRUE(WriteBurstDir(dir.string(), MakeBurst(), {}).ok());
  // A frame of another size.
  cv::imwrite((dir / "frame_2.png").string(), cv::Mat(10, 10, CV_8U, cv::Scalar(1)));
  Status s = ReadBurstDir(dir.string(), false, &out);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("differ"), std::string::npos) << s.ToString();
  // A missing frame.
  fs::remove(dir / "frame_2.png");
  EXPECT_EQ(ReadBurstDir(dir.string(), false, &out).code(), StatusCode::kNotFound);
  // Malformed json.
  std::ofstream(dir / "burst.json") << "{\"format\": \"d3dscan.burst\", ";
  EXPECT_EQ(ReadBurstDir(dir.string(), false, &out).code(), StatusCode::kParseError);
  EXPECT_EQ(WriteBurstDir(dir.string(), Burst{}, {}).code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace d3d
