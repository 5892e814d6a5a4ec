#include "calib/features/detect.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "common/core/status.h"

namespace d3d {
namespace {

double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const size_t k = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<long>(k), v.end());
  return v[k];
}

cv::Mat To8Bit(const cv::Mat& gray) {
  D3D_CHECK_MSG(gray.type() == CV_8U || gray.type() == CV_16U,
                "calibration images must be grey CV_8U or CV_16U, got type " << gray.type());
  if (gray.type() == CV_8U) return gray;
  cv::Mat out;
  gray.convertTo(out, CV_8U, 1.0 / 257.0);
  return out;
}

}  // namespace

void FeatureOptions::Check() const {
  D3D_CHECK_MSG(corner_window_half_px >= 2, "corner window half size must be ≥ 2 px");
  D3D_CHECK_MSG(corner_max_iterations >= 1 && corner_epsilon_px > 0,
                "corner refinement stop must be positive");
  D3D_CHECK_MSG(min_blob_area_px > 0 && max_blob_area_fraction > 0 && max_blob_area_fraction < 1,
                "bad blob area limits");
  D3D_CHECK_MSG(centroid_iterations >= 1, "centroid iterations must be ≥ 1");
}

bool DarkBlobCentroid(const cv::Mat& gray8, const Eigen::Vector2d& start_px, double max_radius_px,
                      int iterations, Eigen::Vector2d* centre_px, double* area_px) {
  const int x0 = std::max(0, static_cast<int>(std::floor(start_px.x() - max_radius_px)));
  const int x1 =
      std::min(gray8.cols - 1, static_cast<int>(std::ceil(start_px.x() + max_radius_px)));
  const int y0 = std::max(0, static_cast<int>(std::floor(start_px.y() - max_radius_px)));
  const int y1 =
      std::min(gray8.rows - 1, static_cast<int>(std::ceil(start_px.y() + max_radius_px)));
  if (x1 - x0 < 4 || y1 - y0 < 4) return false;
  struct Px {
    double x, y, v;
  };
  std::vector<Px> px;
  px.reserve(static_cast<size_t>((x1 - x0 + 1) * (y1 - y0 + 1)));
  for (int y = y0; y <= y1; ++y) {
    const uint8_t* row = gray8.ptr<uint8_t>(y);
    for (int x = x0; x <= x1; ++x)
      px.push_back({static_cast<double>(x), static_cast<double>(y), static_cast<double>(row[x])});
  }
  const double R2 = max_radius_px * max_radius_px;
  // Background: a plane fitted to the outer ring (vignetting and illumination gradients).
  Eigen::Matrix3d AtA = Eigen::Matrix3d::Zero();
  Eigen::Vector3d Atb = Eigen::Vector3d::Zero();
  std::vector<double> ring, inside;
  for (const auto& p : px) {
    const double d2 =
        (p.x - start_px.x()) * (p.x - start_px.x()) + (p.y - start_px.y()) * (p.y - start_px.y());
    if (d2 > R2) continue;
    inside.push_back(p.v);
    if (d2 < 0.7 * 0.7 * R2) continue;
    ring.push_back(p.v);
  }
  if (ring.size() < 8 || inside.size() < 16) return false;
  // Reject ring pixels darker than the ring's median by a lot (a neighbouring blob's edge).
  const double ring_median = Median(ring);
  std::sort(inside.begin(), inside.end());
  const double dark0 = inside[inside.size() / 50];
  const double thr0 = 0.5 * (ring_median + dark0);
  for (const auto& p : px) {
    const double dx = p.x - start_px.x(), dy = p.y - start_px.y();
    const double d2 = dx * dx + dy * dy;
    if (d2 > R2 || d2 < 0.7 * 0.7 * R2 || p.v < thr0) continue;
    const Eigen::Vector3d a(1.0, dx, dy);
    AtA += a * a.transpose();
    Atb += a * p.v;
  }
  if (AtA(0, 0) < 8 || std::abs(AtA.determinant()) < 1e-9) return false;
  const Eigen::Vector3d bg = AtA.ldlt().solve(Atb);
  auto background = [&](double x, double y) {
    return bg[0] + bg[1] * (x - start_px.x()) + bg[2] * (y - start_px.y());
  };
  if (ring_median - dark0 < 10.0) return false;  // no contrast

  // Binary blob (darker than half-way): centre, second moments, core level.
  double m0 = 0, mx = 0, my = 0;
  for (const auto& p : px) {
    const double dx = p.x - start_px.x(), dy = p.y - start_px.y();
    if (dx * dx + dy * dy > R2 || p.v > 0.5 * (background(p.x, p.y) + dark0)) continue;
    m0 += 1;
    mx += p.x;
    my += p.y;
  }
  if (m0 < 4) return false;
  Eigen::Vector2d c(mx / m0, my / m0);
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (const auto& p : px) {
    const double dx = p.x - start_px.x(), dy = p.y - start_px.y();
    if (dx * dx + dy * dy > R2 || p.v > 0.5 * (background(p.x, p.y) + dark0)) continue;
    const Eigen::Vector2d d(p.x - c.x(), p.y - c.y());
    cov += d * d.transpose();
  }
  cov /= m0;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(cov);
  const double lmin = std::max(0.25, eig.eigenvalues()[0]),
               lmax = std::max(0.25, eig.eigenvalues()[1]);
  std::vector<double> core;
  const double core_r2 = lmin;  // semi-minor axis a = 2√λ: the core is within a/2
  for (const auto& p : px)
    if ((p.x - c.x()) * (p.x - c.x()) + (p.y - c.y()) * (p.y - c.y()) <= core_r2)
      core.push_back(p.v);
  const double dark = core.empty() ? dark0 : Median(core);
  const double window = std::min(max_radius_px, 2.0 * std::sqrt(lmax) + 2.5);
  const double w2 = window * window;

  double area = 0;
  for (int it = 0; it < iterations; ++it) {
    double s0 = 0, sx = 0, sy = 0;
    for (const auto& p : px) {
      const double dx = p.x - c.x(), dy = p.y - c.y();
      if (dx * dx + dy * dy > w2) continue;
      const double b = background(p.x, p.y);
      if (b - dark < 5.0) continue;
      const double w = std::clamp((b - p.v) / (b - dark), -0.5, 1.5);
      s0 += w;
      sx += w * p.x;
      sy += w * p.y;
    }
    if (s0 <= 1.0) return false;
    const Eigen::Vector2d next(sx / s0, sy / s0);
    const double step = (next - c).norm();
    c = next;
    area = s0;
    if (step < 1e-3) break;
  }
  if ((c - start_px).norm() > max_radius_px) return false;
  *centre_px = c;
  if (area_px) *area_px = area;
  return true;
}

DetectedFeatures DetectTarget(const cv::Mat& gray, const CalibrationTarget& target,
                              const FeatureOptions& options) {
  target.Check();
  options.Check();
  const cv::Mat img = To8Bit(gray);
  DetectedFeatures out;
  const cv::Size pattern(target.cols, target.rows);
  if (target.kind == TargetKind::kChessboard) {
    std::vector<cv::Point2f> corners;
    const bool found = cv::findChessboardCorners(
        img, pattern, corners,
        cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_FAST_CHECK);
    if (!found || static_cast<int>(corners.size()) != target.NumFeatures()) {
      out.reason = "chessboard of " + std::to_string(target.cols) + "x" +
                   std::to_string(target.rows) + " inner corners not found";
      return out;
    }
    const int h = options.corner_window_half_px;
    cv::cornerSubPix(img, corners, cv::Size(h, h), cv::Size(-1, -1),
                     cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT,
                                      options.corner_max_iterations, options.corner_epsilon_px));
    for (const auto& p : corners) out.points_px.emplace_back(p.x, p.y);
    out.found = true;
    return out;
  }

  cv::SimpleBlobDetector::Params params;
  params.minArea = static_cast<float>(options.min_blob_area_px);
  params.maxArea = static_cast<float>(options.max_blob_area_fraction * img.rows * img.cols);
  params.filterByConvexity = true;
  params.minConvexity = 0.8f;
  params.filterByInertia = true;
  params.minInertiaRatio = 0.1f;
  params.minDistBetweenBlobs = 3.0f;
  const cv::Ptr<cv::FeatureDetector> blobs = cv::SimpleBlobDetector::create(params);
  std::vector<cv::Point2f> centres;
  const int flags = target.kind == TargetKind::kAsymmetricCircleGrid ? cv::CALIB_CB_ASYMMETRIC_GRID
                                                                     : cv::CALIB_CB_SYMMETRIC_GRID;
  const bool found = cv::findCirclesGrid(img, pattern, centres, flags, blobs);
  if (!found || static_cast<int>(centres.size()) != target.NumFeatures()) {
    out.reason =
        std::string(target.kind == TargetKind::kAsymmetricCircleGrid ? "asymmetric" : "symmetric") +
        " circle grid of " + std::to_string(target.cols) + "x" + std::to_string(target.rows) +
        " not found";
    return out;
  }
  // Window: half the distance to the nearest other centre (the blobs do not touch).
  const size_t n = centres.size();
  out.points_px.resize(n);
  out.blob_area_px.resize(n);
  for (size_t i = 0; i < n; ++i) {
    double nearest = 1e30;
    for (size_t j = 0; j < n; ++j)
      if (j != i)
        nearest = std::min(nearest, static_cast<double>(cv::norm(centres[i] - centres[j])));
    const Eigen::Vector2d start(centres[i].x, centres[i].y);
    if (!DarkBlobCentroid(img, start, 0.5 * nearest, options.centroid_iterations, &out.points_px[i],
                          &out.blob_area_px[i])) {
      out.points_px.clear();
      out.blob_area_px.clear();
      out.reason = "circle " + std::to_string(i) +
                   " has no measurable blob (no contrast or cut by the image border)";
      return out;
    }
  }
  out.found = true;
  return out;
}

}  // namespace d3d
