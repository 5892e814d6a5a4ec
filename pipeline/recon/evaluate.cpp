#include "pipeline/recon/evaluate.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>

#include "common/core/status.h"

namespace d3d {

CloudErrors EvaluateCloud(const cv::Mat& points, const cv::Mat& Phi, const FrameTruth& truth,
                          const TriangleMesh& scene, const FringePatternSpec& spec,
                          cv::Mat* error_um) {
  CloudErrors e;
  const Eigen::Matrix3d cam_from_world = truth.world_from_probe.rotation().transpose();
  if (error_um) error_um->create(points.size(), CV_32F), error_um->setTo(std::nanf(""));
  std::vector<double> abs_err;
  double sum2 = 0, sum = 0;
  for (int r = 0; r < points.rows; ++r)
    for (int c = 0; c < points.cols; ++c) {
      const cv::Vec3f& p = points.at<cv::Vec3f>(r, c);
      const bool has_point = std::isfinite(p[2]);
      const uint8_t vis = truth.visibility.at<uint8_t>(r, c);
      const bool tooth =
          truth.label.at<uint8_t>(r, c) == static_cast<uint8_t>(SurfaceLabel::kTooth);
      if (vis == 2 && tooth) {
        ++e.tooth_lit;
        e.tooth_valid += has_point;
      }
      if (!has_point) continue;
      if (vis == 0) {
        ++e.spurious;
        continue;
      }
      const cv::Vec3f& t = truth.points_in_cam.at<cv::Vec3f>(r, c);
      if (!std::isfinite(t[2]))
        continue;  // BinnedTruth: a block across a depth step, not evaluated
      const Eigen::Vector3d delta(p[0] - t[0], p[1] - t[1], p[2] - t[2]);
      const int face = truth.face_index.at<int32_t>(r, c);
      double d;
      if (face >= 0 && face < static_cast<int>(scene.faces.size())) {
        Eigen::Vector3d n = cam_from_world * scene.FaceNormal(face);
        if (n.dot(Eigen::Vector3d(t[0], t[1], t[2])) > 0)
          n = -n;  // toward the camera: + = in front
        d = n.dot(delta);
      } else {
        d = -delta.z();
      }
      const double um = d * 1000.0;
      if (error_um) error_um->at<float>(r, c) = static_cast<float>(um);
      abs_err.push_back(std::abs(um));
      sum += um;
      sum2 += um * um;
      ++e.points;
      if (!Phi.empty() && vis == 2 && std::isfinite(Phi.at<float>(r, c)) &&
          std::isfinite(truth.projector_uv.at<cv::Vec2f>(r, c)[0])) {
        const double true_phase =
            spec.AbsolutePhase(truth.projector_uv.at<cv::Vec2f>(r, c)[spec.axis == 'y' ? 1 : 0]);
        ++e.order_checked;
        e.order_errors += std::abs(Phi.at<float>(r, c) - true_phase) > M_PI;
      }
    }
  if (e.points > 0) {
    e.rms_um = std::sqrt(sum2 / static_cast<double>(e.points));
    e.mean_um = sum / static_cast<double>(e.points);
    double abs_sum = 0;
    for (double a : abs_err) abs_sum += a;
    e.mean_abs_um = abs_sum / static_cast<double>(e.points);
    const size_t k95 = static_cast<size_t>(0.95 * static_cast<double>(abs_err.size() - 1));
    std::nth_element(abs_err.begin(), abs_err.begin() + static_cast<long>(k95), abs_err.end());
    e.p95_um = abs_err[k95];
    e.max_um = *std::max_element(abs_err.begin(), abs_err.end());
  }
  e.order_error_pct = e.order_checked ? 100.0 * static_cast<double>(e.order_errors) /
                                            static_cast<double>(e.order_checked)
                                      : 0.0;
  e.tooth_valid_pct =
      e.tooth_lit ? 100.0 * static_cast<double>(e.tooth_valid) / static_cast<double>(e.tooth_lit)
                  : 0.0;
  return e;
}

FrameTruth BinnedTruth(const FrameTruth& truth, int factor) {
  D3D_CHECK_MSG(truth.has_maps() && factor >= 1, "BinnedTruth: needs maps and factor >= 1");
  const int H = truth.depth_mm.rows, W = truth.depth_mm.cols;
  D3D_CHECK_MSG(H % factor == 0 && W % factor == 0,
                "BinnedTruth: " << W << "x" << H << " is not divisible by " << factor);
  const int h = H / factor, w = W / factor;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  FrameTruth b;
  b.world_from_probe = truth.world_from_probe;
  b.depth_mm.create(h, w, CV_32F);
  b.points_in_cam.create(h, w, CV_32FC3);
  b.projector_uv.create(h, w, CV_32FC2);
  b.visibility.create(h, w, CV_8U);
  b.label.create(h, w, CV_8U);
  b.face_index.create(h, w, CV_32S);
  const double n = factor * factor;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      uint8_t vis = 2;
      const uint8_t label = truth.label.at<uint8_t>(y * factor, x * factor);
      bool one_label = true;
      cv::Vec3d p(0, 0, 0);
      cv::Vec2d uv(0, 0);
      double depth = 0, zmin = std::numeric_limits<double>::infinity(), zmax = -zmin;
      for (int dy = 0; dy < factor; ++dy)
        for (int dx = 0; dx < factor; ++dx) {
          const int r = y * factor + dy, c = x * factor + dx;
          vis = std::min(vis, truth.visibility.at<uint8_t>(r, c));
          one_label = one_label && truth.label.at<uint8_t>(r, c) == label;
          p += cv::Vec3d(truth.points_in_cam.at<cv::Vec3f>(r, c));
          uv += cv::Vec2d(truth.projector_uv.at<cv::Vec2f>(r, c));
          const double z = truth.depth_mm.at<float>(r, c);
          depth += z;
          zmin = std::min(zmin, z);
          zmax = std::max(zmax, z);
        }
      // One smooth piece of surface: every pixel sees it and its depth spans at most a few pixel
      // widths.
      const bool surface =
          vis >= 1 && std::isfinite(p[2]) && std::isfinite(depth) && zmax - zmin <= 0.1;
      const bool lit = surface && vis == 2 && std::isfinite(uv[0]) && std::isfinite(uv[1]);
      b.visibility.at<uint8_t>(y, x) = vis;
      b.label.at<uint8_t>(y, x) = surface && one_label ? label : 0;
      b.points_in_cam.at<cv::Vec3f>(y, x) = surface ? cv::Vec3f(p / n) : cv::Vec3f(nan, nan, nan);
      b.depth_mm.at<float>(y, x) = surface ? static_cast<float>(depth / n) : nan;
      b.projector_uv.at<cv::Vec2f>(y, x) = lit ? cv::Vec2f(uv / n) : cv::Vec2f(nan, nan);
      b.face_index.at<int32_t>(y, x) =
          surface ? truth.face_index.at<int32_t>(y * factor, x * factor) : -1;
    }
  return b;
}

cv::Mat FalseColour(const cv::Mat& values, double lo, double hi, int colormap) {
  const double scale = hi > lo ? 255.0 / (hi - lo) : 1.0;
  cv::Mat u8, colour;
  values.convertTo(u8, CV_8U, scale, hi > lo ? -lo * scale : 0.0);
  cv::applyColorMap(u8, colour, colormap);
  colour.setTo(cv::Scalar(0, 0, 0), ~(values == values));  // NaN (NaN == NaN is false)
  return colour;
}

cv::Mat ErrorHeatMap(const cv::Mat& error_um, double range_um) {
  return FalseColour(error_um, -range_um, range_um, cv::COLORMAP_JET);
}

}  // namespace d3d
