#include "pipeline/fuse/free_space.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "common/core/status.h"

namespace d3d {

void FreeSpaceOptions::Check() const {
  D3D_CHECK_MSG(reference_every >= 1 && max_references >= 1 && nearest_references >= 1,
                "FreeSpaceOptions: reference_every, max_references, nearest_references >= 1");
  D3D_CHECK_MSG(max_centre_distance_mm > 0 && margin_mm > 0,
                "FreeSpaceOptions: max_centre_distance_mm, margin_mm > 0");
  D3D_CHECK_MSG(min_votes >= 1 && min_votes <= nearest_references,
                "FreeSpaceOptions: min_votes in [1, nearest_references]");
}

FreeSpaceTest::FreeSpaceTest(const PinholeBrownConrady& camera, const FreeSpaceOptions& options)
    : camera_(camera), o_(options) {
  camera_.Check();
  o_.Check();
  // Cell (i, j) of the half-size grid covers pixels 2i − 0.5 … 2i + 1.5: u_half = (u + 0.5) / 2.
  fx_ = camera_.fx / 2;
  fy_ = camera_.fy / 2;
  cx_ = (camera_.cx + 0.5) / 2;
  cy_ = (camera_.cy + 0.5) / 2;
  refs_.reserve(static_cast<size_t>(o_.max_references));
}

void FreeSpaceTest::Remember(const cv::Mat& points_in_cam, const Rigid3d& world_from_cam,
                             const cv::Mat& rejected) {
  Reference* slot;
  if (refs_.size() < static_cast<size_t>(o_.max_references)) {
    slot = &refs_.emplace_back();
  } else {  // the oldest goes; its grid is reused
    slot = &refs_[next_];
    next_ = (next_ + 1) % refs_.size();
  }
  Reference& r = *slot;
  r.cam_from_world = world_from_cam.inverse();
  r.centre_in_world = world_from_cam.translation();
  r.depth.create((camera_.height + 1) / 2, (camera_.width + 1) / 2, CV_32F);
  r.depth.setTo(std::numeric_limits<float>::infinity());
  for (int y = 0; y < points_in_cam.rows; ++y) {
    const auto* p = points_in_cam.ptr<cv::Vec3f>(y);
    const auto* out = rejected.ptr<uint8_t>(y);
    for (int x = 0; x < points_in_cam.cols; ++x) {
      const float z = p[x][2];
      if (!(z > 0) || out[x]) continue;  // NaN, behind, or rejected here
      const int u = static_cast<int>(std::floor(fx_ * p[x][0] / z + cx_));
      const int v = static_cast<int>(std::floor(fy_ * p[x][1] / z + cy_));
      if (u < 0 || v < 0 || u >= r.depth.cols || v >= r.depth.rows) continue;
      float& d = r.depth.at<float>(v, u);
      d = std::min(d, z);
    }
  }
}

int64_t FreeSpaceTest::TestAndRemember(const cv::Mat& points_in_cam, const Rigid3d& world_from_cam,
                                       cv::Mat* rejected) {
  D3D_CHECK_MSG(points_in_cam.type() == CV_32FC3 && points_in_cam.rows == camera_.height &&
                    points_in_cam.cols == camera_.width,
                "FreeSpaceTest: points_in_cam must be the camera's H×W CV_32FC3");
  rejected->create(points_in_cam.size(), CV_8U);
  rejected->setTo(0);
  int64_t n = 0;
  if (o_.enabled && !refs_.empty()) {
    // The nearest references by camera centre.
    order_.clear();
    for (int k = 0; k < static_cast<int>(refs_.size()); ++k) {
      const double d =
          (refs_[static_cast<size_t>(k)].centre_in_world - world_from_cam.translation()).norm();
      if (d <= o_.max_centre_distance_mm) order_.emplace_back(d, k);
    }
    std::sort(order_.begin(), order_.end());
    near_.clear();
    for (size_t i = 0;
         i < order_.size() && near_.size() < static_cast<size_t>(o_.nearest_references); ++i)
      near_.push_back(order_[i].second);
    if (static_cast<int>(near_.size()) >= o_.min_votes) {
      // ref_from_cam for each tested reference, as float for the per-point loop.
      rot_.resize(near_.size());
      trans_.resize(near_.size());
      for (size_t i = 0; i < near_.size(); ++i) {
        const Rigid3d ref_from_cam =
            refs_[static_cast<size_t>(near_[i])].cam_from_world * world_from_cam;
        rot_[i] = ref_from_cam.linear().cast<float>();
        trans_[i] = ref_from_cam.translation().cast<float>();
      }
      const float margin = static_cast<float>(o_.margin_mm);
      const float fx = static_cast<float>(fx_), fy = static_cast<float>(fy_),
                  cx = static_cast<float>(cx_), cy = static_cast<float>(cy_);
      // Whether the references saw through q (camera frame).
      auto seen_through = [&](const cv::Vec3f& p) {
        const Eigen::Vector3f q(p[0], p[1], p[2]);
        int votes = 0;
        for (size_t i = 0; i < near_.size() && votes < o_.min_votes; ++i) {
          // Stop when min_votes is out of reach of the references left.
          if (votes + static_cast<int>(near_.size() - i) < o_.min_votes) break;
          const Eigen::Vector3f r = rot_[i] * q + trans_[i];
          if (!(r.z() > 0)) continue;
          const int u = static_cast<int>(std::floor(fx * r.x() / r.z() + cx));
          const int v = static_cast<int>(std::floor(fy * r.y() / r.z() + cy));
          const cv::Mat& depth = refs_[static_cast<size_t>(near_[i])].depth;
          if (u < 1 || v < 1 || u >= depth.cols - 1 || v >= depth.rows - 1) continue;
          int seen = 0;
          float nearest = std::numeric_limits<float>::infinity();
          for (int dv = -1; dv <= 1; ++dv) {
            const float* row = depth.ptr<float>(v + dv);
            for (int du = -1; du <= 1; ++du) {
              const float d = row[u + du];
              if (d < std::numeric_limits<float>::infinity()) {
                ++seen;
                nearest = std::min(nearest, d);
              }
            }
          }
          votes += seen >= 5 && nearest > r.z() + margin;
        }
        return votes >= o_.min_votes;
      };
      // On a 2 × 2 pixel lattice: a block's first point decides for the block (a wrong region is
      // thousands of pixels; a quarter of the projections).
      for (int y = 0; y < points_in_cam.rows; y += 2) {
        const int rows = std::min(2, points_in_cam.rows - y);
        for (int x = 0; x < points_in_cam.cols; x += 2) {
          const int cols = std::min(2, points_in_cam.cols - x);
          const cv::Vec3f* sample = nullptr;
          for (int dy = 0; dy < rows && !sample; ++dy)
            for (int dx = 0; dx < cols && !sample; ++dx) {
              const cv::Vec3f& p = points_in_cam.at<cv::Vec3f>(y + dy, x + dx);
              if (std::isfinite(p[2])) sample = &p;
            }
          if (!sample || !seen_through(*sample)) continue;
          for (int dy = 0; dy < rows; ++dy)
            for (int dx = 0; dx < cols; ++dx)
              if (std::isfinite(points_in_cam.at<cv::Vec3f>(y + dy, x + dx)[2])) {
                rejected->at<uint8_t>(y + dy, x + dx) = 255;
                ++n;
              }
        }
      }
    }
  }
  if (o_.enabled && calls_ % o_.reference_every == 0)
    Remember(points_in_cam, world_from_cam, *rejected);
  ++calls_;
  return n;
}

}  // namespace d3d
