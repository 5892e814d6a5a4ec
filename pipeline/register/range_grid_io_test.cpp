#include "pipeline/register/range_grid_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>

namespace d3d {
namespace {

const char* kHeader =
    "ply\nformat ascii 1.0\nobj_info num_cols 3\nobj_info num_rows 2\nelement vertex 2\nproperty "
    "float x\n"
    "property float y\nproperty float z\nelement range_grid 6\nproperty list uchar int "
    "vertex_indices\nend_header\n";

TEST(RangeGridIo, ReadsAGrid) {
  const std::string text =
      std::string(kHeader) + "0.001 0.002 0.003\n0.004 0.005 0.006\n0\n1 0\n0\n0\n0\n1 1\n";
  cv::Mat P;
  ASSERT_TRUE(ParseRangeGridPly(text, 1000.0, &P).ok());
  ASSERT_EQ(P.rows, 2);
  ASSERT_EQ(P.cols, 3);
  EXPECT_FLOAT_EQ(P.at<cv::Vec3f>(0, 1)[2], 3.0f);
  EXPECT_FLOAT_EQ(P.at<cv::Vec3f>(1, 2)[0], 4.0f);
  EXPECT_TRUE(std::isnan(P.at<cv::Vec3f>(0, 0)[0]));
}

TEST(RangeGridIo, RefusesBadInputWithAReason) {
  cv::Mat P;
  EXPECT_EQ(ParseRangeGridPly("", 1, &P).code(), StatusCode::kParseError);
  EXPECT_EQ(ParseRangeGridPly("ply\nformat ascii 1.0\n", 1, &P).code(), StatusCode::kParseError);
  const std::string h(kHeader);
  EXPECT_EQ(ParseRangeGridPly(h + "1 2 3\n", 1, &P).code(), StatusCode::kParseError);  // truncated
  EXPECT_EQ(ParseRangeGridPly(h + "1 2 3\n4 5 6\n1 7\n0\n0\n0\n0\n0\n", 1, &P).code(),
            StatusCode::kCorrupt);  // index
  EXPECT_FALSE(
      ParseRangeGridPly(h + "1 2 nan\n4 5 6\n0\n0\n0\n0\n0\n0\n", 1, &P).ok());  // not a number
  EXPECT_EQ(LoadRangeGridPly("/nonexistent/x.ply", 1, &P).code(), StatusCode::kNotFound);
  EXPECT_FALSE(ParseRangeGridPly(h, 1, nullptr).ok());
}

TEST(RangeGridIo, ScanPosesOfAConfFile) {
  const std::string path =
      (std::filesystem::temp_directory_path() / "d3d_range_scan_poses.conf").string();
  std::map<std::string, Rigid3d> poses;
  std::ofstream(path) << "camera 0 0 1 0 0 0 1\nbmesh a.ply 0.001 0 0 0 0 0 1\nbmesh b.ply 0 0 0 0 "
                         "0.3826834 0 0.9238795\n";
  ASSERT_TRUE(LoadRangeScanPoses(path, &poses).ok());
  ASSERT_EQ(poses.size(), 2u);
  EXPECT_NEAR(poses.at("a").translation().x(), 1.0, 1e-12) << "metres → mm";
  // 45° about y, stored transposed (the data set's convention): x maps to (cos, 0, +sin).
  const Eigen::Vector3d x = poses.at("b").linear() * Eigen::Vector3d::UnitX();
  EXPECT_NEAR(x.x(), std::sqrt(0.5), 1e-6);
  EXPECT_NEAR(x.z(), std::sqrt(0.5), 1e-6);
  std::ofstream(path) << "camera 0 0 1 0 0 0 1\n";
  EXPECT_EQ(LoadRangeScanPoses(path, &poses).code(), StatusCode::kParseError);
  std::filesystem::remove(path);
  EXPECT_EQ(LoadRangeScanPoses(path, &poses).code(), StatusCode::kNotFound);
}

}  // namespace
}  // namespace d3d
