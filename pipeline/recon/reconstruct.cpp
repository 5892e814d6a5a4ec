#include "pipeline/recon/reconstruct.h"

#include <chrono>
#include <cmath>

namespace d3d {
namespace {

UnwrapOptions WithMarkerOf(UnwrapOptions o, const FringePatternSpec& spec) {
  o.marker_first_order = spec.marker_first_order;
  o.marker_spacing_orders = spec.marker_spacing_orders;
  o.marker_width_periods = spec.marker_width_periods;
  return o;
}

double MsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

void ReconstructOptions::Check() const {
  phase.Check();
  quality.Check();
  unwrap.Check();
  triangulate.Check();
  D3D_CHECK_MSG(normal_max_gap_mm > 0, "normal_max_gap_mm must be positive");
}

Reconstructor::Reconstructor(const ProbeCalibration& calibration, const ReconstructOptions& options)
    : calibration_(calibration),
      options_(options),
      phase_(calibration.pattern, calibration.projector_gamma, options.phase),
      unwrapper_(WithMarkerOf(options.unwrap, calibration.pattern)),
      triangulator_(calibration, options.triangulate) {
  options_.Check();
  triangulator_.PhaseRange(&phase_min_, &phase_max_);
}

Reconstructor::~Reconstructor() = default;

Status Reconstructor::Reconstruct(const std::vector<cv::Mat>& frames, ReconstructedView* out) {
  const auto& cam = calibration_.camera;
  if (static_cast<int>(frames.size()) != calibration_.pattern.steps) {
    return InvalidArgument("reconstruct: " + std::to_string(frames.size()) + " frames, the pattern has " +
                           std::to_string(calibration_.pattern.steps));
  }
  for (const cv::Mat& f : frames) {
    if (f.cols != cam.width || f.rows != cam.height) {
      return InvalidArgument("reconstruct: a frame is " + std::to_string(f.cols) + "x" + std::to_string(f.rows) +
                             " but the calibration's camera is " + std::to_string(cam.width) + "x" +
                             std::to_string(cam.height));
    }
  }
  const auto t_start = std::chrono::steady_clock::now();
  auto t = t_start;
  D3D_RETURN_IF_ERROR(phase_.Compute(frames, &out->phase));
  out->ms_phase = MsSince(t);
  t = std::chrono::steady_clock::now();
  D3D_RETURN_IF_ERROR(ComputeQualityMap(out->phase.phi, out->phase.modulation, out->phase.valid, options_.quality,
                                        &out->quality));
  out->ms_quality = MsSince(t);
  t = std::chrono::steady_clock::now();
  D3D_RETURN_IF_ERROR(unwrapper_.Run(out->phase.phi, out->quality, out->phase.marker, phase_min_, phase_max_, &out->unwrap));
  out->ms_unwrap = MsSince(t);
  t = std::chrono::steady_clock::now();
  D3D_RETURN_IF_ERROR(triangulator_.Triangulate(out->unwrap.Phi, &out->points_in_cam));
  OrganisedNormals(out->points_in_cam, options_.normal_max_gap_mm, &out->normals);
  out->ms_triangulate = MsSince(t);
  out->texture = out->phase.texture;
  out->points = 0;
  for (int r = 0; r < out->points_in_cam.rows; ++r) {
    const auto* p = out->points_in_cam.ptr<cv::Vec3f>(r);
    for (int c = 0; c < out->points_in_cam.cols; ++c) out->points += std::isfinite(p[c][2]) ? 1 : 0;
  }
  out->ms_total = MsSince(t_start);
  return Status::Ok();
}

}  // namespace d3d
