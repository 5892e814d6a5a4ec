// Single-view reconstruction: one phase-shift burst and the probe's calibration → an organised
// point cloud in the camera frame (mm), with normals, texture and quality. The stages run in one
// chain, each callable alone (pipeline/phase, pipeline/unwrap, pipeline/triangulate):
//   frames → wrapped phase φ, modulation B, marker (PhaseEstimator)
//          → quality map (ComputeQualityMap: modulation–Laplace)
//          → absolute phase Φ, fringe order k (Unwrapper: quality-guided, marker/volume anchored)
//          → Φ for the albedo-edge cut beside the anchored pixels (EdgeFiller)
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
#include "pipeline/unwrap/edge_fill.h"
#include "pipeline/unwrap/quality_map.h"
#include "pipeline/unwrap/unwrap.h"

namespace d3d {

struct ReconstructOptions {
  PhaseOptions phase;
  QualityOptions quality;
  UnwrapOptions unwrap;       // marker orders are taken from the calibration's pattern
  EdgeFillOptions edge_fill;  // Φ for the albedo-edge cut beside anchored pixels (edge_fill.h)
  TriangulateOptions triangulate;
  double normal_max_gap_mm = 0.15;  // neighbours farther apart than this are a depth discontinuity
  // The stages' pixel sizes (marker detector boxes, κ tiles, region and vote counts, neck radius)
  // are tuned for a fringe period of kReferenceFringePeriodCamPx camera pixels. With this on, the
  // Reconstructor scales them by the calibration's own period in camera pixels
  // (ScaleToFringePeriod), so the same options serve a 640 × 480 and a 1280 × 1024 probe.
  bool scale_to_fringe_period = true;
  // > 1: the per-pixel passes (phase sums and compensation, marker score, triangulation, normals)
  // run on blocks of rows as oneTBB tasks (common/core/parallel_rows.h): the same bits as 1, less
  // wall time when a core is free (d3d-scan: its --threads). Overrides phase.threads.
  int threads = 1;
  void Check() const;  // throws std::invalid_argument
};

// The fringe period in camera pixels for which the stages' pixel sizes are tuned: the 640 × 480
// probe's, 24 projector px × fx_cam/fx_proj = 24 × 2000/2100 (probe_design.h).
inline constexpr double kReferenceFringePeriodCamPx = 24.0 * 2000.0 / 2100.0;

// The fringe period of `calibration` in camera pixels near the optical axis: T · fx_cam / fx_proj
// (camera and projector at about the same distance from the surface).
double FringePeriodCamPx(const ProbeCalibration& calibration);

// `options` with every pixel-size field scaled by s = fringe_period_cam_px /
// kReferenceFringePeriodCamPx: lengths by s (odd sizes stay odd; the unwrapper's neck radius rounds
// down), pixel counts (areas) by s². |s − 1| < 0.05 returns `options` unchanged. Throws
// std::invalid_argument for a non-positive period.
ReconstructOptions ScaleToFringePeriod(const ReconstructOptions& options,
                                       double fringe_period_cam_px);

// Averages `frame` (H×W CV_8U or CV_16U) over `factor` × `factor` pixel blocks into `binned`
// ((H/factor)×(W/factor), same type; reallocated only when its size or type differs), rounding to
// nearest, as a binned sensor read-out would (pixel centres: BinnedCamera,
// calib/model/camera_model.h). A block with any pixel at full scale (255 / 65535) stays at full
// scale, so that the quality map still sees the clipping (a clipped sinusoid biases φ).
// INVALID_ARGUMENT for another type, factor < 1 or a size not divisible by factor.
[[nodiscard]] Status BinFrame(const cv::Mat& frame, int factor, cv::Mat* binned);

struct ReconstructedView {
  cv::Mat points_in_cam;   // H×W CV_32FC3, mm, NaN where no point
  cv::Mat normals;         // H×W CV_32FC3 unit, camera frame, NaN where unknown
  cv::Mat texture;         // H×W CV_8U: mean of the frames
  cv::Mat quality;         // H×W CV_32F ∈ [0, 1]
  cv::Mat quality_reason;  // H×W CV_8U QualityReason: why a pixel has quality 0
                           // (pipeline/unwrap/quality_map.h)
  PhaseMaps phase;         // φ, B, A, marker ... (pipeline/phase)
  UnwrapResult unwrap;     // Φ, k, regions ... (pipeline/unwrap)
  int64_t points = 0;      // finite points
  int64_t pixels_edge_filled =
      0;  // of the unwrapped pixels, those filled in the albedo-edge cut (EdgeFiller)
  // Wall time of each stage on the calling thread, milliseconds.
  double ms_phase = 0, ms_quality = 0, ms_unwrap = 0, ms_triangulate = 0, ms_total = 0;
};

class Reconstructor {
 public:
  // Throws std::invalid_argument for an invalid calibration or options.
  Reconstructor(const ProbeCalibration& calibration, const ReconstructOptions& options = {});
  ~Reconstructor();

  const ProbeCalibration& calibration() const { return calibration_; }
  // The options in effect (after ScaleToFringePeriod, when scale_to_fringe_period).
  const ReconstructOptions& options() const { return options_; }

  // frames: the burst's phase-shift frames (calibration.pattern.steps of them, texture frame not
  // included), H×W CV_8U or CV_16U of the calibration's camera size. INVALID_ARGUMENT for a wrong
  // count, size or type (naming which); bad data (dark, saturated) gives invalid pixels, not
  // errors.
  [[nodiscard]] Status Reconstruct(const std::vector<cv::Mat>& frames, ReconstructedView* out);

 private:
  ProbeCalibration calibration_;
  ReconstructOptions options_;
  PhaseEstimator phase_;
  Unwrapper unwrapper_;
  EdgeFiller edge_filler_;
  PhaseTriangulator triangulator_;
  cv::Mat phase_min_, phase_max_;
};

}  // namespace d3d
