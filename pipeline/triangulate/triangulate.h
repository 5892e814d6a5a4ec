// Triangulation of absolute phase: for each camera pixel, the point on its ray whose projection
// into the projector has the coded coordinate of its absolute phase Φ.
//
// Model: the camera ray of pixel p is X(z) = z · r(p), r = (x, y, 1) the undistorted normalised
// coordinates (camera_model.h), z the camera depth (mm). The fringe coordinate c (projector pixels
// along the pattern axis) of a depth is c(z) = π_axis(projector, proj_from_cam · X(z)) with the
// projector's Brown–Conrady distortion. We solve c(z) = c*, c* = origin + Φ T / 2π:
//   1. closed form for the undistorted projector (a projective function of z): with
//      P = proj_from_cam, a = (P.R r)_axis, b = (P.t)_axis, e = (P.R r)_z, f = (P.t)_z and
//      m* = (c* − c_centre)/f_px the normalised target, z₀ = (b − m* f) / (m* e − a);
//   2. one Newton step on the exact c(z) (distortion included) with the pinhole derivative, then
//      secant steps on the exact c(z) until |Δz| < 1e-7 mm (two or three for real lenses).
// This is the "camera ray ∩ projector plane" of the issue, exact also when distortion bends the
// projector's iso-phase surface.
//
// Fast path (Triangulate): per pixel, the pinhole coefficients (a, e) and a degree-5 least-squares
// fit, in depth, of the distortion's correction δ(z) = c(z) − c_pinhole(z) over the measurement
// volume (+margin) are precomputed; z then solves c_pinhole(z) = c* − δ(z) by fixed-point
// iteration of the closed form (δ changes ~300× more slowly with z than c: three iterations;
// measured over the 34 million pixels of a 450-burst typodont replay, the third is within 3e-7 mm
// of a fourth, 30× below the fit's own 1e-5 mm, the second within 9e-5 mm).
// Pixels whose fit misses the exact δ by more than 1e-4 px (≈ 1e-5 mm) anywhere on 21 check depths
// use the exact solver.
//
// Thread safety: const methods may run concurrently; the object holds only per-pixel constants.
#pragma once

#include <opencv2/core.hpp>
#include <vector>

#include "calib/model/probe_calibration.h"
#include "common/core/status.h"

namespace d3d {

struct TriangulateOptions {
  // Points outside [depth_min − margin, depth_max + margin] (calibration's measurement volume) are
  // dropped: they cannot come from a correct fringe order.
  double depth_margin_mm = 2.0;
  int max_newton_steps = 6;
  void Check() const;
};

class PhaseTriangulator {
 public:
  // Precomputes every pixel's ray. Throws std::invalid_argument for an invalid calibration/options.
  PhaseTriangulator(const ProbeCalibration& calibration, const TriangulateOptions& options = {});

  const ProbeCalibration& calibration() const { return calibration_; }

  // Absolute phase Φ that each pixel would see at the near and far ends of the measurement volume
  // (H×W CV_32F each, phase_min ≤ phase_max; NaN where the pixel's ray leaves the projector image
  // there). The unwrapper uses it as the geometric constraint on the fringe order (An et al. 2016,
  // "Pixel-wise absolute phase unwrapping using geometric constraints of structured light system",
  // Opt. Express 24(16):18445).
  void PhaseRange(cv::Mat* phase_min, cv::Mat* phase_max) const;

  // Φ (H×W CV_32F, NaN where unknown) → points_in_cam (H×W CV_32FC3, mm, NaN where no valid
  // point). INVALID_ARGUMENT if Φ's size or type does not match the calibration's camera.
  // threads > 1: blocks of rows as oneTBB tasks (common/core/parallel_rows.h), the same bits.
  [[nodiscard]] Status Triangulate(const cv::Mat& Phi, cv::Mat* points_in_cam,
                                   int threads = 1) const;

  // Share of the pixels that use the fast path (the others fall back to the exact solver).
  double FastPathShare() const;

  // Depth (camera z, mm) of pixel (col,row) for absolute phase Phi; NaN if there is no solution in
  // the measurement volume (with margin).
  double DepthForPhase(int col, int row, double Phi) const;
  // Point (camera frame, mm) of pixel (col,row) for absolute phase Phi, as Triangulate computes it
  // (fast path where it is accurate); NaN where Triangulate gives none (outside the volume).
  Eigen::Vector3d PointForPhase(int col, int row, double Phi) const;
  // Absolute phase that pixel (col,row) sees at depth z_mm (exact, with distortion); NaN outside
  // the projector image.
  double PhaseAtDepth(int col, int row, double z_mm) const;

 private:
  double CodedCoordinate(const Eigen::Vector3d& p_in_cam) const;  // c of a point, NaN if behind

  // Per-pixel constants of the fast path (see above): a, e, then δ(z) = Σ_k d_k t^k (k ≤ 5) with
  // t = (z − z_mid)/z_half ∈ [−1, 1]; fast_ok = 0 where the fit is not accurate enough.
  static constexpr int kFitTerms = 6;
  struct PixelModel {
    double a = 0, e = 0;
    float d[kFitTerms] = {};
  };
  double FastDepth(size_t index, double Phi) const;

  ProbeCalibration calibration_;
  TriangulateOptions options_;
  std::vector<PixelModel> model_;
  std::vector<uint8_t> fast_ok_;
  double z_mid_ = 0, z_half_ = 1;
  Rigid3d proj_from_cam_;
  int axis_;                           // 0 for x-coded patterns, 1 for y
  std::vector<Eigen::Vector3d> rays_;  // r(p), row-major; NaN where undistortion failed
};

// Organised normals: unit normals (CV_32FC3, camera frame, facing the camera) from the cross
// product of central differences of the point map; NaN where a neighbour is missing or the
// neighbours are farther apart than max_gap_mm (a depth discontinuity). threads > 1: blocks of rows
// as oneTBB tasks (common/core/parallel_rows.h), the same bits.
void OrganisedNormals(const cv::Mat& points_in_cam, double max_gap_mm, cv::Mat* normals,
                      int threads = 1);
// After the points at `changed` (row-major pixel indices) were rewritten: OrganisedNormals again at
// those pixels and their 4-neighbours, the only normals that read them. `normals` then equals
// OrganisedNormals over the whole map, for O(changed) work (model anchoring rewrites ~2 % of a
// view's pixels). Throws std::invalid_argument unless normals and points are CV_32FC3 of one size.
void UpdateOrganisedNormals(const cv::Mat& points_in_cam, double max_gap_mm,
                            const std::vector<int>& changed, cv::Mat* normals);

}  // namespace d3d
