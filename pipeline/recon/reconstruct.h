// Single-view reconstruction: one phase-shift burst and the probe's calibration → an organised
// point cloud in the camera frame (mm), with normals, texture and quality. The stages run in one
// chain, each callable alone (pipeline/phase, pipeline/unwrap, pipeline/triangulate):
//   frames → wrapped phase φ, modulation B, marker (PhaseEstimator)
//          → quality map (ComputeQualityMap: modulation–Laplace)
//          → absolute phase Φ, fringe order k (Unwrapper: quality-guided, marker/volume anchored)
//          → points (PhaseTriangulator), normals (OrganisedNormals)
// A Reconstructor owns every per-pixel constant and buffer, so a warm call does not allocate
// for the same image size. Not thread-safe: one per thread.
#pragma once

#include <memory>
#include <opencv2/core.hpp>
#include <vector>

#include "calib/model/probe_calibration.h"
#include "common/core/status.h"
#include "pipeline/phase/phase.h"
#include "pipeline/triangulate/triangulate.h"
#include "pipeline/unwrap/quality_map.h"
#include "pipeline/unwrap/unwrap.h"

namespace d3d {

struct ReconstructOptions {
  PhaseOptions phase;
  QualityOptions quality;
  UnwrapOptions unwrap;          // marker orders are taken from the calibration's pattern
  TriangulateOptions triangulate;
  double normal_max_gap_mm = 0.15;  // neighbours farther apart than this are a depth discontinuity
  void Check() const;               // throws std::invalid_argument
};

struct ReconstructedView {
  cv::Mat points_in_cam;  // H×W CV_32FC3, mm, NaN where no point
  cv::Mat normals;        // H×W CV_32FC3 unit, camera frame, NaN where unknown
  cv::Mat texture;        // H×W CV_8U: mean of the frames
  cv::Mat quality;        // H×W CV_32F ∈ [0, 1]
  PhaseMaps phase;        // φ, B, A, marker ... (pipeline/phase)
  UnwrapResult unwrap;    // Φ, k, regions ... (pipeline/unwrap)
  int64_t points = 0;     // finite points
  // Wall time of each stage on the calling thread, milliseconds.
  double ms_phase = 0, ms_quality = 0, ms_unwrap = 0, ms_triangulate = 0, ms_total = 0;
};

class Reconstructor {
 public:
  // Throws std::invalid_argument for an invalid calibration or options.
  Reconstructor(const ProbeCalibration& calibration, const ReconstructOptions& options = {});
  ~Reconstructor();

  const ProbeCalibration& calibration() const { return calibration_; }

  // frames: the burst's phase-shift frames (calibration.pattern.steps of them, texture frame not
  // included), H×W CV_8U or CV_16U of the calibration's camera size. INVALID_ARGUMENT for a wrong
  // count, size or type (naming which); bad data (dark, saturated) gives invalid pixels, not errors.
  [[nodiscard]] Status Reconstruct(const std::vector<cv::Mat>& frames, ReconstructedView* out);

 private:
  ProbeCalibration calibration_;
  ReconstructOptions options_;
  PhaseEstimator phase_;
  Unwrapper unwrapper_;
  PhaseTriangulator triangulator_;
  cv::Mat phase_min_, phase_max_;
};

}  // namespace d3d
