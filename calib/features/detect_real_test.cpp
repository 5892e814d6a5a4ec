// Our features on OpenCV's test images against OpenCV's reference corner/centre files
// (../shared/data/calibration/opencv_extra_chess, opencv_extra_acircles).
#include <gtest/gtest.h>

#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "calib/features/detect.h"

namespace d3d {
namespace {

namespace fs = std::filesystem;

struct Reference {
  bool found = false;
  int rows = 0, cols = 0;
  std::vector<Eigen::Vector2d> points;
};

Reference ReadReference(const fs::path& path) {
  Reference ref;
  cv::FileStorage fsr(path.string(), cv::FileStorage::READ);
  if (!fsr.isOpened()) return ref;
  int found = 0;
  fsr["isFound"] >> found;
  cv::Mat corners;
  fsr["corners"] >> corners;
  ref.found = found != 0 && !corners.empty();
  ref.rows = corners.rows;
  ref.cols = corners.cols;
  for (int r = 0; r < corners.rows; ++r)
    for (int c = 0; c < corners.cols; ++c) {
      const auto p = corners.at<cv::Vec2f>(r, c);
      ref.points.emplace_back(p[0], p[1]);
    }
  return ref;
}

// RMS distance in the same order or the reverse one (a grid may be returned upside down).
double RmsBestOrder(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b) {
  double s = 0, sr = 0;
  const size_t n = a.size();
  for (size_t i = 0; i < n; ++i) {
    s += (a[i] - b[i]).squaredNorm();
    sr += (a[i] - b[n - 1 - i]).squaredNorm();
  }
  return std::sqrt(std::min(s, sr) / static_cast<double>(n));
}

struct Agreement {
  int images = 0;
  double sum_sq = 0;
  int64_t points = 0;
};

Agreement Compare(const fs::path& dir, const std::string& image_prefix,
                  const std::string& ref_prefix, int count, TargetKind kind) {
  Agreement a;
  for (int i = 1; i <= count; ++i) {
    const fs::path img_path = dir / (image_prefix + std::to_string(i) + ".png");
    const Reference ref = ReadReference(dir / (ref_prefix + std::to_string(i) + ".dat"));
    if (!ref.found) continue;
    cv::Mat img = cv::imread(img_path.string(), cv::IMREAD_GRAYSCALE);
    if (img.empty()) continue;
    CalibrationTarget t;
    t.kind = kind;
    t.cols = ref.cols;  // OpenCV: pattern size = Size(cols, rows) of the reference matrix
    t.rows = ref.rows;
    t.spacing_mm = 1.0;
    const DetectedFeatures f = DetectTarget(img, t);
    EXPECT_TRUE(f.found) << img_path << ": " << f.reason;
    if (!f.found) continue;
    const double rms = RmsBestOrder(f.points_px, ref.points);
    std::printf("  %s: %zu features, RMS vs OpenCV reference %.4f px\n",
                img_path.filename().c_str(), f.points_px.size(), rms);
    a.images++;
    a.sum_sq += rms * rms * static_cast<double>(f.points_px.size());
    a.points += static_cast<int64_t>(f.points_px.size());
  }
  return a;
}

const fs::path kData = fs::path(D3D_SHARED_DATA_DIR) / "calibration";

TEST(RealFeatures, ChessCornersAgreeWithOpenCvReference) {
  const fs::path dir = kData / "opencv_extra_chess";
  if (!fs::exists(dir)) GTEST_SKIP() << "real data absent: " << dir;
  const Agreement a = Compare(dir, "chess", "chess_corners", 9, TargetKind::kChessboard);
  ASSERT_GE(a.images, 7);
  const double rms = std::sqrt(a.sum_sq / static_cast<double>(a.points));
  std::printf("chess: %d images, %lld corners, RMS vs reference %.4f px\n", a.images,
              static_cast<long long>(a.points), rms);
  EXPECT_LE(rms, 0.1);
}

TEST(RealFeatures, AsymmetricCircleCentresAgreeWithOpenCvReference) {
  const fs::path dir = kData / "opencv_extra_acircles";
  if (!fs::exists(dir)) GTEST_SKIP() << "real data absent: " << dir;
  const Agreement a =
      Compare(dir, "acircles", "acircles_corners", 5, TargetKind::kAsymmetricCircleGrid);
  ASSERT_GE(a.images, 4);
  const double rms = std::sqrt(a.sum_sq / static_cast<double>(a.points));
  std::printf("acircles: %d images, %lld centres, RMS vs reference %.4f px\n", a.images,
              static_cast<long long>(a.points), rms);
  EXPECT_LE(rms, 0.1);
}

}  // namespace
}  // namespace d3d
