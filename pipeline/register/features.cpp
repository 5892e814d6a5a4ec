#include "pipeline/register/features.h"

#include <algorithm>
#include <cmath>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "common/core/status.h"
#include "pipeline/register/surface_points.h"

namespace d3d {

void FeatureOptions::Check() const {
  D3D_CHECK_MSG(use_texture || use_range, "FeatureOptions: at least one of texture / range");
  D3D_CHECK_MSG(
      max_features > 0 && ratio > 0 && ratio <= 1 && lift_window >= 0 && contrast_threshold > 0,
      "FeatureOptions: invalid value");
  D3D_CHECK_MSG(image_scale > 0 && image_scale <= 1,
                "FeatureOptions: image_scale must be in (0, 1]");
  ransac.Check();
}

cv::Mat RangeImage(const cv::Mat& points, cv::Mat* mask) {
  D3D_CHECK_MSG(points.type() == CV_32FC3, "RangeImage: points must be CV_32FC3");
  std::vector<float> z;
  z.reserve(points.total());
  for (int r = 0; r < points.rows; ++r) {
    const cv::Vec3f* p = points.ptr<cv::Vec3f>(r);
    for (int c = 0; c < points.cols; ++c)
      if (std::isfinite(p[c][2])) z.push_back(p[c][2]);
  }
  cv::Mat img(points.size(), CV_8U, cv::Scalar(0));
  mask->create(points.size(), CV_8U);
  mask->setTo(0);
  if (z.size() < 16) return img;
  auto q = [&](double f) {
    auto it = z.begin() + static_cast<std::ptrdiff_t>(f * static_cast<double>(z.size() - 1));
    std::nth_element(z.begin(), it, z.end());
    return *it;
  };
  const float lo = q(0.01), hi = std::max(q(0.99), lo + 1e-3f);
  for (int r = 0; r < points.rows; ++r) {
    const cv::Vec3f* p = points.ptr<cv::Vec3f>(r);
    uint8_t* o = img.ptr<uint8_t>(r);
    uint8_t* m = mask->ptr<uint8_t>(r);
    for (int c = 0; c < points.cols; ++c) {
      if (!std::isfinite(p[c][2])) continue;
      o[c] = static_cast<uint8_t>(
          std::clamp(1.0f + 254.0f * (p[c][2] - lo) / (hi - lo), 1.0f, 255.0f));
      m[c] = 255;
    }
  }
  return img;
}

cv::Mat ShadedRangeImage(const cv::Mat& points, double max_gap_mm, cv::Mat* mask) {
  const cv::Mat N = GridNormals(points, max_gap_mm);
  cv::Mat img(points.size(), CV_8U, cv::Scalar(0));
  mask->create(points.size(), CV_8U);
  mask->setTo(0);
  for (int r = 0; r < points.rows; ++r)
    for (int c = 0; c < points.cols; ++c) {
      const cv::Vec3f& n = N.at<cv::Vec3f>(r, c);
      const cv::Vec3f& p = points.at<cv::Vec3f>(r, c);
      if (!std::isfinite(n[0])) continue;
      const float len = std::sqrt(p.dot(p));
      // For scans not in a camera frame (the ray is unknown), light along the z axis.
      const float shade = len > 1e-6f && p[2] > 0 ? std::abs(n.dot(p)) / len : std::abs(n[2]);
      img.at<uint8_t>(r, c) = static_cast<uint8_t>(std::clamp(1.0f + 254.0f * shade, 1.0f, 255.0f));
      mask->at<uint8_t>(r, c) = 255;
    }
  return img;
}

namespace {

void Detect(const cv::Mat& image, const cv::Mat& mask, const cv::Mat& points,
            const FeatureOptions& o, std::vector<Eigen::Vector3f>* out_points, cv::Mat* out_desc) {
  out_points->clear();
  *out_desc = cv::Mat();
  if (image.empty()) return;
  cv::Ptr<cv::SIFT> sift = cv::SIFT::create(o.max_features, 3, o.contrast_threshold);
  std::vector<cv::KeyPoint> kps;
  cv::Mat desc;
  if (o.image_scale < 1) {
    // SIFT on the downsampled image (area average; the mask by nearest neighbour), keypoints mapped
    // back to full-resolution pixel coordinates (pixel centres: x = (x_s + 0.5) / s − 0.5).
    cv::Mat small, small_mask;
    cv::resize(image, small, cv::Size(), o.image_scale, o.image_scale, cv::INTER_AREA);
    if (!mask.empty()) cv::resize(mask, small_mask, small.size(), 0, 0, cv::INTER_NEAREST);
    sift->detectAndCompute(small, small_mask, kps, desc);
    const float inv = static_cast<float>(1.0 / o.image_scale);
    for (cv::KeyPoint& k : kps) {
      k.pt = (k.pt + cv::Point2f(0.5f, 0.5f)) * inv - cv::Point2f(0.5f, 0.5f);
      k.size *= inv;
    }
  } else {
    sift->detectAndCompute(image, mask, kps, desc);
  }
  cv::Mat keep_desc;
  for (size_t i = 0; i < kps.size(); ++i) {
    const int u0 = static_cast<int>(std::lround(kps[i].pt.x)),
              v0 = static_cast<int>(std::lround(kps[i].pt.y));
    float best = 1e9f;
    Eigen::Vector3f pick;
    for (int v = std::max(0, v0 - o.lift_window);
         v <= std::min(points.rows - 1, v0 + o.lift_window); ++v)
      for (int u = std::max(0, u0 - o.lift_window);
           u <= std::min(points.cols - 1, u0 + o.lift_window); ++u) {
        const cv::Vec3f& p = points.at<cv::Vec3f>(v, u);
        if (!std::isfinite(p[0]) || !std::isfinite(p[2])) continue;
        const float d = static_cast<float>((u - kps[i].pt.x) * (u - kps[i].pt.x) +
                                           (v - kps[i].pt.y) * (v - kps[i].pt.y));
        if (d < best) {
          best = d;
          pick = Eigen::Vector3f(p[0], p[1], p[2]);
        }
      }
    if (best > 1e8f) continue;
    out_points->push_back(pick);
    keep_desc.push_back(desc.row(static_cast<int>(i)));
  }
  *out_desc = keep_desc;
}

void Match(const std::vector<Eigen::Vector3f>& sp, const cv::Mat& sd,
           const std::vector<Eigen::Vector3f>& tp, const cv::Mat& td, const FeatureOptions& o,
           std::vector<Correspondence3d>* out) {
  if (sd.rows < 2 || td.rows < 2) return;
  cv::BFMatcher matcher(cv::NORM_L2);
  std::vector<std::vector<cv::DMatch>> fwd, bwd;
  matcher.knnMatch(sd, td, fwd, 2);
  if (o.mutual) matcher.knnMatch(td, sd, bwd, 1);
  for (const auto& m : fwd) {
    if (m.size() < 2 || m[0].distance > o.ratio * m[1].distance) continue;
    if (o.mutual && (bwd[static_cast<size_t>(m[0].trainIdx)].empty() ||
                     bwd[static_cast<size_t>(m[0].trainIdx)][0].trainIdx != m[0].queryIdx))
      continue;
    Correspondence3d c;
    c.source = sp[static_cast<size_t>(m[0].queryIdx)].cast<double>();
    c.target = tp[static_cast<size_t>(m[0].trainIdx)].cast<double>();
    out->push_back(c);
  }
}

}  // namespace

ViewFeatures ExtractViewFeatures(const cv::Mat& points, const cv::Mat& texture,
                                 const FeatureOptions& o) {
  o.Check();
  D3D_CHECK_MSG(points.type() == CV_32FC3, "ExtractViewFeatures: points must be CV_32FC3");
  D3D_CHECK_MSG(texture.empty() || (texture.type() == CV_8U && texture.size() == points.size()),
                "ExtractViewFeatures: texture must be CV_8U of the points' size");
  ViewFeatures f;
  cv::Mat mask;
  const cv::Mat range = RangeImage(points, &mask);
  if (o.use_texture && !texture.empty())
    Detect(texture, mask, points, o, &f.texture_points, &f.texture_descriptors);
  if (o.use_range && o.range_rendering != RangeRendering::kShaded)
    Detect(range, mask, points, o, &f.range_points, &f.range_descriptors);
  if (o.use_range && o.range_rendering != RangeRendering::kDepth) {
    cv::Mat smask;
    const cv::Mat shaded = ShadedRangeImage(points, o.max_gap_mm, &smask);
    Detect(shaded, smask, points, o, &f.shaded_points, &f.shaded_descriptors);
  }
  return f;
}

FeatureAlignResult AlignByFeatures(const ViewFeatures& s, const ViewFeatures& t,
                                   const FeatureOptions& o) {
  o.Check();
  FeatureAlignResult r;
  std::vector<Correspondence3d> c;
  if (o.use_texture)
    Match(s.texture_points, s.texture_descriptors, t.texture_points, t.texture_descriptors, o, &c);
  if (o.use_range)
    Match(s.range_points, s.range_descriptors, t.range_points, t.range_descriptors, o, &c);
  if (o.use_range)
    Match(s.shaded_points, s.shaded_descriptors, t.shaded_points, t.shaded_descriptors, o, &c);
  r.matches = static_cast<int>(c.size());
  const RansacResult rr = RansacRigid(c, o.ransac);
  r.inliers = static_cast<int>(rr.inliers.size());
  if (!rr.ok) {
    r.reason = "features: " + rr.reason;
    return r;
  }
  r.ok = true;
  r.target_from_source = rr.target_from_source;
  r.inlier_rmse_mm = rr.inlier_rmse_mm;
  return r;
}

}  // namespace d3d
