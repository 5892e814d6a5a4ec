#include "host/app/preview_model.h"

#include <cmath>
#include <stdexcept>

namespace d3d {
namespace {

uint64_t CellKey(const Eigen::Vector3f& p, float inv_cell) {
  const auto q = [&](float v) {
    return static_cast<uint64_t>(static_cast<int64_t>(std::floor(v * inv_cell)) +
                                 (int64_t{1} << 20)) &
           0x1FFFFF;
  };
  return (q(p.x()) << 42) | (q(p.y()) << 21) | q(p.z());
}

// Adds p (normal n) to a decimated cloud: one point per cell, none beyond max_points.
void AddDecimated(const Eigen::Vector3f& p, const Eigen::Vector3f& n, float inv_cell,
                  size_t max_points, std::unordered_map<uint64_t, uint32_t>* cells,
                  std::vector<Eigen::Vector3f>* points, std::vector<Eigen::Vector3f>* normals) {
  if (points->size() >= max_points ||
      !cells->try_emplace(CellKey(p, inv_cell), static_cast<uint32_t>(points->size())).second)
    return;
  points->push_back(p);
  normals->push_back(n);
}

// Appends the tail of `from` that `to` lacks; starts `to` anew when its generation is stale.
void CopyTail(const std::vector<Eigen::Vector3f>& from,
              const std::vector<Eigen::Vector3f>& from_normals, uint64_t generation,
              std::vector<Eigen::Vector3f>* to, std::vector<Eigen::Vector3f>* to_normals,
              uint64_t* to_generation) {
  if (*to_generation != generation || to->size() > from.size()) {
    to->clear();
    to_normals->clear();
    *to_generation = generation;
  }
  to->insert(to->end(), from.begin() + static_cast<std::ptrdiff_t>(to->size()), from.end());
  to_normals->insert(to_normals->end(),
                     from_normals.begin() + static_cast<std::ptrdiff_t>(to_normals->size()),
                     from_normals.end());
}

}  // namespace

void PreviewModelOptions::Check() const {
  if (!(cell_mm > 0) || max_points < 1 || stride_px < 1)
    throw std::invalid_argument(
        "PreviewModelOptions: cell_mm > 0, max_points >= 1 and stride_px >= 1");
}

PreviewModel::PreviewModel(const PreviewModelOptions& options)
    : o_(options), inv_cell_(static_cast<float>(1.0 / options.cell_mm)) {
  o_.Check();
  cells_.reserve(o_.max_points);
  model_points_.reserve(o_.max_points);
  model_normals_.reserve(o_.max_points);
}

void PreviewModel::Reset() {
  cells_.clear();
  model_points_.clear();
  model_normals_.clear();
  views_.clear();
  ++generation_;
  ClearSegment();
}

void PreviewModel::Undo(int64_t first_view) {
  size_t keep = views_.size();
  while (keep > 0 && views_[keep - 1].first >= first_view) --keep;
  if (keep < views_.size()) {
    const size_t points = views_[keep].second;
    for (size_t i = points; i < model_points_.size(); ++i)
      cells_.erase(CellKey(model_points_[i], inv_cell_));
    model_points_.resize(points);
    model_normals_.resize(points);
    views_.resize(keep);
    ++generation_;
  }
  ClearSegment();
}

void PreviewModel::ClearSegment() {
  if (segment_points_.empty()) return;
  segment_cells_.clear();
  segment_points_.clear();
  segment_normals_.clear();
  ++segment_generation_;
}

void PreviewModel::Sample(const cv::Mat& points, const cv::Mat& normals, const Rigid3d& pose,
                          size_t max_points, Cells* cells, std::vector<Eigen::Vector3f>* out_points,
                          std::vector<Eigen::Vector3f>* out_normals) const {
  const Eigen::Matrix3f r = pose.linear().cast<float>();
  const Eigen::Vector3f t = pose.translation().cast<float>();
  for (int y = 0; y < points.rows; y += o_.stride_px) {
    const auto* p = points.ptr<cv::Vec3f>(y);
    const auto* n = normals.ptr<cv::Vec3f>(y);
    for (int x = 0; x < points.cols && out_points->size() < max_points; x += o_.stride_px) {
      if (!std::isfinite(p[x][2]) || !std::isfinite(n[x][2])) continue;
      AddDecimated(r * Eigen::Vector3f(p[x][0], p[x][1], p[x][2]) + t,
                   r * Eigen::Vector3f(n[x][0], n[x][1], n[x][2]), inv_cell_, max_points, cells,
                   out_points, out_normals);
    }
  }
}

void PreviewModel::AddView(int64_t view_index, const TrackResult& track, const cv::Mat& points,
                           const cv::Mat& normals) {
  if (track.segment_joined) {
    const Eigen::Matrix3f r = track.main_from_display.linear().cast<float>();
    const Eigen::Vector3f t = track.main_from_display.translation().cast<float>();
    for (size_t i = 0; i < segment_points_.size() && model_points_.size() < o_.max_points; ++i)
      AddDecimated(r * segment_points_[i] + t, r * segment_normals_[i], inv_cell_, o_.max_points,
                   &cells_, &model_points_, &model_normals_);
    ClearSegment();
  }
  if (!track.accepted) return;
  if (track.in_main) {
    views_.emplace_back(view_index, model_points_.size());
    Sample(points, normals, track.world_from_cam, o_.max_points, &cells_, &model_points_,
           &model_normals_);
    return;
  }
  if (track.segment != segment_) {
    ClearSegment();
    segment_ = track.segment;
  }
  const size_t room =
      o_.max_points > model_points_.size() ? o_.max_points - model_points_.size() : 0;
  Sample(points, normals, track.display_from_cam, room, &segment_cells_, &segment_points_,
         &segment_normals_);
}

void PreviewModel::CopyTo(PreviewSnapshot* s) const {
  CopyTail(model_points_, model_normals_, generation_, &s->points, &s->normals, &s->generation);
  CopyTail(segment_points_, segment_normals_, segment_generation_, &s->segment_points,
           &s->segment_normals, &s->segment_generation);
}

}  // namespace d3d
