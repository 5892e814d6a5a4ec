// The live preview's model (the host's preview stage): the accepted views decimated to one point
// per preview cell in the model frame, and the scan segment apart from it (SegmentOptions::
// after_views) in its display frame (TrackResult::display_from_cam: beside where the model
// was lost, placed, not registered), which moves into the model when the segment joins
// (TrackResult::main_from_display). Both clouds are append-only between resets, so a snapshot
// copies only their new tails (CopyTo). Units: mm. Thread: one (the preview stage's); it owns every
// buffer here.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <opencv2/core.hpp>
#include <unordered_map>
#include <utility>
#include <vector>

#include "pipeline/register/tracker.h"
#include "viewer/preview.h"

namespace d3d {

struct PreviewModelOptions {
  double cell_mm = 0.2;        // one point per cell of this size
  size_t max_points = 150000;  // model and segment together stop growing beyond this
  int stride_px = 3;           // pixels sampled per view
  void Check() const;          // throws std::invalid_argument
};

class PreviewModel {
 public:
  explicit PreviewModel(const PreviewModelOptions& options);

  void Reset();  // a new scan: model and segment go
  // Views first_view … leave the model (their points: the model's tail from the first of them);
  // the segment is cleared (it grows again from the next view).
  void Undo(int64_t first_view);
  // One registered view: points / normals H×W CV_32FC3, camera frame (NaN = none). A join before it
  // (track.segment_joined) first carries the segment into the model; then an accepted view of the
  // main model adds to the model, one of a segment apart to the segment (another segment than the
  // one drawn: that one is dropped from the preview).
  void AddView(int64_t view_index, const TrackResult& track, const cv::Mat& points,
               const cv::Mat& normals);
  // The snapshot's model and segment clouds brought up to date (their generations; tails copied).
  void CopyTo(PreviewSnapshot* s) const;

  size_t model_points() const { return model_points_.size(); }
  size_t segment_points() const { return segment_points_.size(); }
  uint64_t views_in_model() const { return views_.size(); }
  double model_area_mm2() const {
    return static_cast<double>(model_points_.size()) * o_.cell_mm * o_.cell_mm;
  }

 private:
  using Cells = std::unordered_map<uint64_t, uint32_t>;
  // Samples the view at `pose` into one cloud, up to `max_points` points in it.
  void Sample(const cv::Mat& points, const cv::Mat& normals, const Rigid3d& pose, size_t max_points,
              Cells* cells, std::vector<Eigen::Vector3f>* out_points,
              std::vector<Eigen::Vector3f>* out_normals) const;
  void ClearSegment();

  PreviewModelOptions o_;
  float inv_cell_;
  uint64_t generation_ = 0;  // bumps when the model loses points (reset, undo)
  Cells cells_;
  std::vector<Eigen::Vector3f> model_points_, model_normals_;
  std::vector<std::pair<int64_t, size_t>>
      views_;                        // accepted views: (view index, model points before it)
  int segment_ = 0;                  // the segment drawn (0: none yet)
  uint64_t segment_generation_ = 0;  // bumps when the segment is cleared
  Cells segment_cells_;
  std::vector<Eigen::Vector3f> segment_points_, segment_normals_;
};

}  // namespace d3d
