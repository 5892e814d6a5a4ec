#include "pipeline/recon/reconstruct.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <vector>

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

int ScaleLength(int v, double s, bool odd) {
  const int r = std::max(v > 0 ? 1 : 0, static_cast<int>(std::lround(v * s)));
  return odd && r % 2 == 0 ? r + 1 : r;
}

int ScaleArea(int v, double s) {
  return std::max(v > 0 ? 1 : 0, static_cast<int>(std::lround(v * s * s)));
}

ReconstructOptions Effective(const ProbeCalibration& calibration,
                             const ReconstructOptions& options) {
  options.Check();
  ReconstructOptions o = options.scale_to_fringe_period
                             ? ScaleToFringePeriod(options, FringePeriodCamPx(calibration))
                             : options;
  o.phase.threads = o.threads;
  return o;
}

}  // namespace

double FringePeriodCamPx(const ProbeCalibration& calibration) {
  return calibration.pattern.fringe_period_px * calibration.camera.fx / calibration.projector.fx;
}

ReconstructOptions ScaleToFringePeriod(const ReconstructOptions& options,
                                       double fringe_period_cam_px) {
  D3D_CHECK_MSG(fringe_period_cam_px > 0 && std::isfinite(fringe_period_cam_px),
                "fringe period must be positive, got " << fringe_period_cam_px);
  const double s = fringe_period_cam_px / kReferenceFringePeriodCamPx;
  ReconstructOptions o = options;
  if (std::abs(s - 1.0) < 0.05) return o;
  o.phase.marker_box_px = ScaleLength(o.phase.marker_box_px, s, true);
  o.phase.marker_close_px = ScaleLength(o.phase.marker_close_px, s, true);
  o.phase.marker_guard_px = ScaleLength(o.phase.marker_guard_px, s, false);
  o.phase.marker_suspect_reach_px = ScaleLength(o.phase.marker_suspect_reach_px, s, false);
  o.phase.kappa_tile_px = ScaleLength(o.phase.kappa_tile_px, s, false);
  o.unwrap.min_region_pixels = ScaleArea(o.unwrap.min_region_pixels, s);
  o.unwrap.min_marker_votes = ScaleArea(o.unwrap.min_marker_votes, s);
  o.unwrap.marker_rival_votes = ScaleArea(o.unwrap.marker_rival_votes, s);
  o.unwrap.marker_tile_px = ScaleLength(o.unwrap.marker_tile_px, s, false);
  o.unwrap.marker_tile_rival_votes = ScaleArea(o.unwrap.marker_tile_rival_votes, s);
  o.unwrap.max_violations = ScaleLength(o.unwrap.max_violations, s, false);
  // The neck radius rounds down, so that a neck is never cut wider than the tuned 2 px at the
  // reference period: at half that period (2×2-binned frames) a 1 px radius cut necks of 0.35
  // fringe periods and dropped whole marker regions (typodont full arch, burst 129: 576 of 14.3k
  // anchored pixels kept; the tracker lost the scan there), so it is off. 40 bursts along each
  // arch's path, 2×2-binned, radius 1 → 0: points per view 30.4k → 38.6k (typodont), 36.7k → 43.9k
  // (real arch); fringe-order errors 0 → 0.00007 %, 0.0006 → 0.0019 % (full resolution: 0.0016,
  // 0.0067 %).
  o.unwrap.neck_radius = static_cast<int>(std::floor(o.unwrap.neck_radius * s + 1e-9));
  o.edge_fill.passes = ScaleLength(o.edge_fill.passes, s, false);
  return o;
}

void ReconstructOptions::Check() const {
  phase.Check();
  quality.Check();
  unwrap.Check();
  edge_fill.Check();
  triangulate.Check();
  D3D_CHECK_MSG(normal_max_gap_mm > 0, "normal_max_gap_mm must be positive");
  D3D_CHECK_MSG(threads >= 1, "threads must be >= 1, got " << threads);
}

namespace {
// 2 × 2 blocks (the host's default bin): two source rows at a time in one pass, which the
// compiler vectorises; the same values as the general loop below.
template <typename T>
void BinBlocks2(const cv::Mat& src, T full_scale, cv::Mat* dst) {
  for (int yb = 0; yb < dst->rows; ++yb) {
    const T* s0 = src.ptr<T>(2 * yb);
    const T* s1 = src.ptr<T>(2 * yb + 1);
    T* d = dst->ptr<T>(yb);
    for (int xb = 0; xb < dst->cols; ++xb) {
      const T a = s0[2 * xb], b = s0[2 * xb + 1], c = s1[2 * xb], e = s1[2 * xb + 1];
      const uint32_t sum = uint32_t{a} + b + c + e;
      const bool clip =
          (a == full_scale) | (b == full_scale) | (c == full_scale) | (e == full_scale);
      d[xb] = clip ? full_scale : static_cast<T>((sum + 2) / 4);
    }
  }
}

template <typename T>
void BinBlocks(const cv::Mat& src, int f, T full_scale, cv::Mat* dst) {
  if (f == 2) {
    BinBlocks2<T>(src, full_scale, dst);
    return;
  }
  const uint32_t n = static_cast<uint32_t>(f * f), half = n / 2;
  std::vector<uint32_t> sum(static_cast<size_t>(dst->cols));
  std::vector<uint8_t> clipped(static_cast<size_t>(dst->cols));
  for (int yb = 0; yb < dst->rows; ++yb) {
    std::fill(sum.begin(), sum.end(), 0u);
    std::fill(clipped.begin(), clipped.end(), uint8_t{0});
    for (int dy = 0; dy < f; ++dy) {
      const T* s = src.ptr<T>(yb * f + dy);
      for (int xb = 0; xb < dst->cols; ++xb) {
        uint32_t acc = 0;
        uint8_t clip = 0;
        for (int dx = 0; dx < f; ++dx) {
          const T v = s[xb * f + dx];
          acc += v;
          clip |= static_cast<uint8_t>(v == full_scale);
        }
        sum[static_cast<size_t>(xb)] += acc;
        clipped[static_cast<size_t>(xb)] |= clip;
      }
    }
    T* d = dst->ptr<T>(yb);
    for (int xb = 0; xb < dst->cols; ++xb)
      d[xb] = clipped[static_cast<size_t>(xb)]
                  ? full_scale
                  : static_cast<T>((sum[static_cast<size_t>(xb)] + half) / n);
  }
}
}  // namespace

Status BinFrame(const cv::Mat& frame, int factor, cv::Mat* binned) {
  if (factor < 1) return InvalidArgument("bin: factor must be >= 1, got " + std::to_string(factor));
  if (frame.type() != CV_8UC1 && frame.type() != CV_16UC1)
    return InvalidArgument("bin: frame must be CV_8UC1 or CV_16UC1");
  if (frame.empty() || frame.cols % factor != 0 || frame.rows % factor != 0)
    return InvalidArgument("bin: a frame of " + std::to_string(frame.cols) + "x" +
                           std::to_string(frame.rows) + " is not divisible into " +
                           std::to_string(factor) + "x" + std::to_string(factor) + " blocks");
  binned->create(frame.rows / factor, frame.cols / factor, frame.type());
  if (frame.depth() == CV_8U)
    BinBlocks<uint8_t>(frame, factor, 255, binned);
  else
    BinBlocks<uint16_t>(frame, factor, 65535, binned);
  return Status::Ok();
}

Reconstructor::Reconstructor(const ProbeCalibration& calibration, const ReconstructOptions& options)
    : calibration_(calibration),
      options_(Effective(calibration, options)),
      phase_(calibration.pattern, calibration.projector_gamma, options_.phase),
      unwrapper_(WithMarkerOf(options_.unwrap, calibration.pattern)),
      edge_filler_(options_.edge_fill, options_.unwrap),
      triangulator_(calibration, options_.triangulate) {
  options_.Check();
  triangulator_.PhaseRange(&phase_min_, &phase_max_);
  // The unwrapper's stripe window is widened on the far side of the measurement volume
  // (UnwrapOptions::marker_margin_above for a probe whose Φ grows with depth, as ours); where Φ
  // falls with depth, the far side is below.
  const auto& cam = calibration.camera;
  const double near =
      triangulator_.PhaseAtDepth(cam.width / 2, cam.height / 2, calibration.depth_min_mm);
  const double far =
      triangulator_.PhaseAtDepth(cam.width / 2, cam.height / 2, calibration.depth_max_mm);
  if (std::isfinite(near) && std::isfinite(far) && far < near) {
    UnwrapOptions u = WithMarkerOf(options_.unwrap, calibration.pattern);
    std::swap(u.marker_margin_below, u.marker_margin_above);
    unwrapper_ = Unwrapper(u);
  }
}

Reconstructor::~Reconstructor() = default;

Status Reconstructor::Reconstruct(const std::vector<cv::Mat>& frames, ReconstructedView* out) {
  const auto& cam = calibration_.camera;
  if (static_cast<int>(frames.size()) != calibration_.pattern.steps) {
    return InvalidArgument("reconstruct: " + std::to_string(frames.size()) +
                           " frames, the pattern has " +
                           std::to_string(calibration_.pattern.steps));
  }
  for (const cv::Mat& f : frames) {
    if (f.cols != cam.width || f.rows != cam.height) {
      return InvalidArgument("reconstruct: a frame is " + std::to_string(f.cols) + "x" +
                             std::to_string(f.rows) + " but the calibration's camera is " +
                             std::to_string(cam.width) + "x" + std::to_string(cam.height));
    }
  }
  const auto t_start = std::chrono::steady_clock::now();
  auto t = t_start;
  D3D_RETURN_IF_ERROR(phase_.Compute(frames, &out->phase));
  out->ms_phase = MsSince(t);
  t = std::chrono::steady_clock::now();
  D3D_RETURN_IF_ERROR(ComputeQualityMap(out->phase.phi, out->phase.modulation, out->phase.valid,
                                        options_.quality, &out->quality, &out->quality_reason));
  out->ms_quality = MsSince(t);
  t = std::chrono::steady_clock::now();
  D3D_RETURN_IF_ERROR(unwrapper_.Run(out->phase.phi, out->quality, out->phase.marker, phase_min_,
                                     phase_max_, &out->unwrap));
  EdgeFillStats fill;
  D3D_RETURN_IF_ERROR(edge_filler_.Fill(out->phase.phi, out->phase.modulation, out->quality_reason,
                                        phase_min_, phase_max_, &out->unwrap.Phi,
                                        &out->unwrap.order, &out->quality, &fill));
  out->pixels_edge_filled = fill.pixels_filled;
  out->ms_unwrap = MsSince(t);
  t = std::chrono::steady_clock::now();
  D3D_RETURN_IF_ERROR(
      triangulator_.Triangulate(out->unwrap.Phi, &out->points_in_cam, options_.threads));
  OrganisedNormals(out->points_in_cam, options_.normal_max_gap_mm, &out->normals, options_.threads);
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
