#include "common/mesh/point_cloud_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

#include "common/mesh/mesh_io.h"

namespace d3d {
namespace {

TEST(PointCloudPly, WritesFinitePointsThatTheMeshReaderReadsBack) {
  cv::Mat points(4, 5, CV_32FC3, cv::Scalar(1.5f, -2.0f, 50.25f)),
      normals(4, 5, CV_32FC3, cv::Scalar(0, 0, -1));
  cv::Mat grey(4, 5, CV_8U, cv::Scalar(200)), quality(4, 5, CV_32F, cv::Scalar(0.5f));
  points.at<cv::Vec3f>(1, 1) = cv::Vec3f(std::nanf(""), 0, 0);
  const std::string path = (std::filesystem::temp_directory_path() / "d3d_cloud.ply").string();
  int64_t n = 0;
  ASSERT_TRUE(SavePointCloudPly(path, points, normals, grey, quality, &n).ok());
  EXPECT_EQ(n, 19);
  // The mesh loader refuses a file without faces, naming the reason: the header is parsed fine.
  TriangleMesh mesh;
  const Status s = LoadMesh(path, &mesh);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message().find("face"), std::string::npos) << s.ToString();
  EXPECT_EQ(std::filesystem::file_size(path) > 19u * (12 + 12 + 1 + 4), true);
  EXPECT_EQ(SavePointCloudPly(path, points, cv::Mat(3, 3, CV_32FC3), grey, quality).code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(SavePointCloudPly("/nonexistent/dir/x.ply", points, normals, grey, quality).code(),
            StatusCode::kIoError);
}

}  // namespace
}  // namespace d3d
