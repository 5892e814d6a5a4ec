#include "common/mesh/point_cloud_io.h"

#include <cmath>
#include <cstring>
#include <fstream>
#include <vector>

namespace d3d {

Status SavePointCloudPly(const std::string& path, const cv::Mat& points, const cv::Mat& normals,
                         const cv::Mat& grey, const cv::Mat& quality, int64_t* written) {
  if (points.type() != CV_32FC3) return InvalidArgument("point cloud: points must be CV_32FC3");
  auto same = [&](const cv::Mat& m, int type) {
    return m.empty() || (m.size() == points.size() && m.type() == type);
  };
  if (!same(normals, CV_32FC3) || !same(grey, CV_8U) || !same(quality, CV_32F)) {
    return InvalidArgument(
        "point cloud: normals/grey/quality must match the points' size (CV_32FC3/CV_8U/CV_32F)");
  }
  std::vector<char> body;
  int64_t n = 0;
  auto put = [&](const void* p, size_t bytes) {
    body.insert(body.end(), static_cast<const char*>(p), static_cast<const char*>(p) + bytes);
  };
  for (int r = 0; r < points.rows; ++r)
    for (int c = 0; c < points.cols; ++c) {
      const cv::Vec3f& p = points.at<cv::Vec3f>(r, c);
      if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) continue;
      put(&p, sizeof(p));
      if (!normals.empty()) {
        cv::Vec3f nv = normals.at<cv::Vec3f>(r, c);
        if (!std::isfinite(nv[0])) nv = cv::Vec3f(0, 0, 0);
        put(&nv, sizeof(nv));
      }
      if (!grey.empty()) put(&grey.at<uint8_t>(r, c), 1);
      if (!quality.empty()) put(&quality.at<float>(r, c), 4);
      ++n;
    }
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) return IoError("cannot write '" + path + "'");
  f << "ply\nformat binary_little_endian 1.0\ncomment d3dscan point cloud, mm\nelement vertex " << n
    << "\nproperty float x\nproperty float y\nproperty float z\n";
  if (!normals.empty()) f << "property float nx\nproperty float ny\nproperty float nz\n";
  if (!grey.empty()) f << "property uchar intensity\n";
  if (!quality.empty()) f << "property float quality\n";
  f << "end_header\n";
  f.write(body.data(), static_cast<std::streamsize>(body.size()));
  if (!f) return IoError("write failed for '" + path + "'");
  if (written) *written = n;
  return Status::Ok();
}

}  // namespace d3d
