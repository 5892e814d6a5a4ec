#include "pipeline/triangulate/triangulate.h"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "common/core/parallel_rows.h"

namespace d3d {
namespace {
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr float kNaNf = std::numeric_limits<float>::quiet_NaN();
}  // namespace

void TriangulateOptions::Check() const {
  D3D_CHECK_MSG(depth_margin_mm >= 0, "depth margin must be ≥ 0");
  D3D_CHECK_MSG(max_newton_steps >= 1 && max_newton_steps <= 50,
                "max_newton_steps must be in [1, 50]");
}

PhaseTriangulator::PhaseTriangulator(const ProbeCalibration& calibration,
                                     const TriangulateOptions& options)
    : calibration_(calibration),
      options_(options),
      proj_from_cam_(calibration.cam_from_proj.inverse()),
      axis_(calibration.pattern.axis == 'y' ? 1 : 0) {
  calibration_.Check();
  options_.Check();
  const auto& cam = calibration_.camera;
  rays_.resize(static_cast<size_t>(cam.width) * static_cast<size_t>(cam.height));
  for (int r = 0; r < cam.height; ++r)
    for (int c = 0; c < cam.width; ++c) {
      const auto ray = cam.PixelRay(Eigen::Vector2d(c, r));
      rays_[static_cast<size_t>(r) * static_cast<size_t>(cam.width) + static_cast<size_t>(c)] =
          ray ? *ray : Eigen::Vector3d::Constant(kNaN);
    }
  // Fast path: pinhole coefficients and a least-squares cubic of δ(z) on 9 depths, checked on 17.
  const double z_lo = calibration_.depth_min_mm - options_.depth_margin_mm;
  const double z_hi = calibration_.depth_max_mm + options_.depth_margin_mm;
  z_mid_ = 0.5 * (z_lo + z_hi);
  z_half_ = 0.5 * (z_hi - z_lo);
  const auto& proj = calibration_.projector;
  const double f_px = axis_ == 0 ? proj.fx : proj.fy;
  const double centre = axis_ == 0 ? proj.cx : proj.cy;
  const Eigen::Vector3d& t = proj_from_cam_.translation();
  const double b = t[axis_], f = t.z();
  constexpr int kNodes = 11;
  Eigen::Matrix<double, kNodes, kFitTerms> V;
  for (int j = 0; j < kNodes; ++j) {
    const double tt = -1.0 + 2.0 * j / (kNodes - 1);
    for (int k = 0; k < kFitTerms; ++k) V(j, k) = std::pow(tt, k);
  }
  const Eigen::Matrix<double, kFitTerms, kNodes> fit =
      (V.transpose() * V).inverse() * V.transpose();
  auto eval = [](const auto& d, double tt) {
    double v = 0;
    for (int k = kFitTerms - 1; k >= 0; --k) v = v * tt + d[k];
    return v;
  };
  model_.resize(rays_.size());
  fast_ok_.assign(rays_.size(), 0);
  for (size_t i = 0; i < rays_.size(); ++i) {
    const Eigen::Vector3d& r = rays_[i];
    if (!r.allFinite()) continue;
    const Eigen::Vector3d Rr = proj_from_cam_.linear() * r;
    const double a = Rr[axis_], e = Rr.z();
    auto delta = [&](double z) {
      return CodedCoordinate(r * z) - (centre + f_px * (a * z + b) / (e * z + f));
    };
    Eigen::Matrix<double, kNodes, 1> samples;
    bool ok = true;
    for (int j = 0; j < kNodes && ok; ++j) {
      samples[j] = delta(z_mid_ + z_half_ * V(j, 1));
      ok = std::isfinite(samples[j]);
    }
    if (!ok) continue;
    const Eigen::Matrix<double, kFitTerms, 1> d = fit * samples;
    PixelModel& m = model_[i];
    m.a = a;
    m.e = e;
    for (int k = 0; k < kFitTerms; ++k) m.d[k] = static_cast<float>(d[k]);
    for (int j = 0; j <= 20 && ok; ++j) {
      const double tt = -1.0 + 2.0 * j / 20.0;
      const double exact = delta(z_mid_ + z_half_ * tt);
      ok = std::isfinite(exact) && std::abs(exact - eval(m.d, tt)) < 1e-4;
    }
    fast_ok_[i] = ok ? 1 : 0;
  }
}

double PhaseTriangulator::FastPathShare() const {
  size_t n = 0;
  for (uint8_t ok : fast_ok_) n += ok;
  return fast_ok_.empty() ? 0.0 : static_cast<double>(n) / static_cast<double>(fast_ok_.size());
}

double PhaseTriangulator::FastDepth(size_t index, double Phi) const {
  const PixelModel& m = model_[index];
  const auto& proj = calibration_.projector;
  const double f_px = axis_ == 0 ? proj.fx : proj.fy;
  const double centre = axis_ == 0 ? proj.cx : proj.cy;
  const Eigen::Vector3d& t = proj_from_cam_.translation();
  const double b = t[axis_], f = t.z();
  const FringePatternSpec& spec = calibration_.pattern;
  const double target = spec.phase_origin_px + Phi * spec.fringe_period_px / (2.0 * M_PI);
  double delta = m.d[0];  // δ at the middle of the volume: a good start
  double z = kNaN;
  for (int it = 0; it < 3; ++it) {                       // three: see the header
    const double mm = (target - delta - centre) / f_px;  // normalised pinhole target
    const double denom = mm * m.e - m.a;
    if (std::abs(denom) < 1e-12) return kNaN;
    z = (b - mm * f) / denom;
    const double tt = std::clamp((z - z_mid_) / z_half_, -1.0, 1.0);
    delta = 0;
    for (int k = kFitTerms - 1; k >= 0; --k) delta = delta * tt + m.d[k];
  }
  return std::abs(z - z_mid_) <= z_half_ ? z : kNaN;
}

double PhaseTriangulator::CodedCoordinate(const Eigen::Vector3d& p_in_cam) const {
  const auto px = calibration_.projector.Project(proj_from_cam_ * p_in_cam);
  return px ? (*px)[axis_] : kNaN;
}

double PhaseTriangulator::PhaseAtDepth(int col, int row, double z_mm) const {
  const Eigen::Vector3d& r =
      rays_[static_cast<size_t>(row) * static_cast<size_t>(calibration_.camera.width) +
            static_cast<size_t>(col)];
  const auto px = calibration_.projector.Project(proj_from_cam_ * (r * z_mm));
  if (!px || !calibration_.projector.InImage(*px)) return kNaN;
  return calibration_.pattern.AbsolutePhase((*px)[axis_]);
}

double PhaseTriangulator::DepthForPhase(int col, int row, double Phi) const {
  const Eigen::Vector3d& r =
      rays_[static_cast<size_t>(row) * static_cast<size_t>(calibration_.camera.width) +
            static_cast<size_t>(col)];
  if (!std::isfinite(Phi) || !r.allFinite()) return kNaN;
  const auto& proj = calibration_.projector;
  const double f_px = axis_ == 0 ? proj.fx : proj.fy;
  const double centre = axis_ == 0 ? proj.cx : proj.cy;
  const FringePatternSpec& spec = calibration_.pattern;
  const double target = spec.phase_origin_px + Phi * spec.fringe_period_px / (2.0 * M_PI);  // c*
  const Eigen::Vector3d Rr = proj_from_cam_.linear() * r;
  const Eigen::Vector3d& t = proj_from_cam_.translation();
  const double a = Rr[axis_], b = t[axis_], e = Rr.z(), f = t.z();
  const double m = (target - centre) / f_px;
  const double denom = m * e - a;
  if (std::abs(denom) < 1e-12) return kNaN;
  double z = (b - m * f) / denom;  // undistorted projector: exact
  const double z_lo = calibration_.depth_min_mm - options_.depth_margin_mm;
  const double z_hi = calibration_.depth_max_mm + options_.depth_margin_mm;
  // First step: Newton with the pinhole derivative; then secant steps on the exact c(z), which
  // converge superlinearly (the pinhole slope alone converges only linearly under distortion).
  if (!(z > 0.0)) return kNaN;
  double c = CodedCoordinate(r * z);
  if (!std::isfinite(c)) return kNaN;
  const double q = e * z + f;
  const double dcdz = f_px * (a * f - b * e) / (q * q);  // c = centre + f_px (a z + b)/(e z + f)
  if (std::abs(dcdz) < 1e-12) return kNaN;
  double z_prev = z, c_prev = c;
  z += (target - c) / dcdz;
  for (int it = 1; it < options_.max_newton_steps; ++it) {
    if (!(z > 0.0)) return kNaN;
    c = CodedCoordinate(r * z);
    if (!std::isfinite(c)) return kNaN;
    if (std::abs(c - c_prev) < 1e-15) break;
    const double step = (target - c) * (z - z_prev) / (c - c_prev);
    z_prev = z;
    c_prev = c;
    z += step;
    if (std::abs(step) < 1e-7) break;
  }
  return z >= z_lo && z <= z_hi ? z : kNaN;
}

void PhaseTriangulator::PhaseRange(cv::Mat* phase_min, cv::Mat* phase_max) const {
  const auto& cam = calibration_.camera;
  phase_min->create(cam.height, cam.width, CV_32F);
  phase_max->create(cam.height, cam.width, CV_32F);
  for (int r = 0; r < cam.height; ++r)
    for (int c = 0; c < cam.width; ++c) {
      const double p0 = PhaseAtDepth(c, r, calibration_.depth_min_mm);
      const double p1 = PhaseAtDepth(c, r, calibration_.depth_max_mm);
      const bool ok = std::isfinite(p0) && std::isfinite(p1);
      phase_min->at<float>(r, c) = ok ? static_cast<float>(std::min(p0, p1)) : kNaNf;
      phase_max->at<float>(r, c) = ok ? static_cast<float>(std::max(p0, p1)) : kNaNf;
    }
}

Eigen::Vector3d PhaseTriangulator::PointForPhase(int col, int row, double Phi) const {
  const auto& cam = calibration_.camera;
  if (col < 0 || row < 0 || col >= cam.width || row >= cam.height || !std::isfinite(Phi))
    return Eigen::Vector3d::Constant(kNaN);
  const size_t index =
      static_cast<size_t>(row) * static_cast<size_t>(cam.width) + static_cast<size_t>(col);
  const double z = fast_ok_[index] ? FastDepth(index, Phi) : DepthForPhase(col, row, Phi);
  if (!std::isfinite(z)) return Eigen::Vector3d::Constant(kNaN);
  return rays_[index] * z;
}

Status PhaseTriangulator::Triangulate(const cv::Mat& Phi, cv::Mat* points_in_cam,
                                      int threads) const {
  const auto& cam = calibration_.camera;
  if (Phi.type() != CV_32F) return InvalidArgument("triangulate: absolute phase must be CV_32F");
  if (Phi.cols != cam.width || Phi.rows != cam.height) {
    return InvalidArgument("triangulate: phase map is " + std::to_string(Phi.cols) + "x" +
                           std::to_string(Phi.rows) + " but the calibration's camera is " +
                           std::to_string(cam.width) + "x" + std::to_string(cam.height));
  }
  points_in_cam->create(cam.height, cam.width, CV_32FC3);
  ForRowBlocks(cam.height, threads, [&](int r0, int r1) {
    for (int r = r0; r < r1; ++r) {
      const float* phi = Phi.ptr<float>(r);
      auto* out = points_in_cam->ptr<cv::Vec3f>(r);
      for (int c = 0; c < cam.width; ++c) {
        if (!std::isfinite(phi[c])) {
          out[c] = cv::Vec3f(kNaNf, kNaNf, kNaNf);
          continue;
        }
        const size_t index =
            static_cast<size_t>(r) * static_cast<size_t>(cam.width) + static_cast<size_t>(c);
        const double z = fast_ok_[index] ? FastDepth(index, phi[c]) : DepthForPhase(c, r, phi[c]);
        if (!std::isfinite(z)) {
          out[c] = cv::Vec3f(kNaNf, kNaNf, kNaNf);
          continue;
        }
        const Eigen::Vector3d p = rays_[index] * z;
        out[c] = cv::Vec3f(static_cast<float>(p.x()), static_cast<float>(p.y()),
                           static_cast<float>(p.z()));
      }
    }
  });
  return Status::Ok();
}

namespace {
// OrganisedNormals' normal at interior pixel (r, c), NaN where it has none.
inline cv::Vec3f NormalAt(const cv::Mat& points, int r, int c, double max_gap_mm) {
  const cv::Vec3f nan3(kNaNf, kNaNf, kNaNf);
  auto at = [&](int rr, int cc) {
    const cv::Vec3f& v = points.at<cv::Vec3f>(rr, cc);
    return Eigen::Vector3d(v[0], v[1], v[2]);
  };
  const Eigen::Vector3d p = at(r, c), L = at(r, c - 1), R = at(r, c + 1), U = at(r - 1, c),
                        D = at(r + 1, c);
  if (!p.allFinite() || !L.allFinite() || !R.allFinite() || !U.allFinite() || !D.allFinite())
    return nan3;
  if ((R - p).norm() > max_gap_mm || (p - L).norm() > max_gap_mm || (D - p).norm() > max_gap_mm ||
      (p - U).norm() > max_gap_mm) {
    return nan3;
  }
  Eigen::Vector3d n = (R - L).cross(D - U);
  if (n.squaredNorm() == 0) return nan3;
  n.normalize();
  if (n.dot(p) > 0) n = -n;  // face the camera at the origin
  return cv::Vec3f(static_cast<float>(n.x()), static_cast<float>(n.y()), static_cast<float>(n.z()));
}
}  // namespace

void OrganisedNormals(const cv::Mat& points, double max_gap_mm, cv::Mat* normals, int threads) {
  normals->create(points.size(), CV_32FC3);
  const cv::Vec3f nan3(kNaNf, kNaNf, kNaNf);
  ForRowBlocks(points.rows, threads, [&](int r0, int r1) {
    for (int r = r0; r < r1; ++r) {
      auto* out = normals->ptr<cv::Vec3f>(r);
      std::fill(out, out + points.cols, nan3);
      if (r == 0 || r + 1 >= points.rows) continue;
      for (int c = 1; c + 1 < points.cols; ++c) out[c] = NormalAt(points, r, c, max_gap_mm);
    }
  });
}

void UpdateOrganisedNormals(const cv::Mat& points, double max_gap_mm,
                            const std::vector<int>& changed, cv::Mat* normals) {
  D3D_CHECK_MSG(
      normals->size() == points.size() && normals->type() == CV_32FC3 && points.type() == CV_32FC3,
      "UpdateOrganisedNormals: normals must be CV_32FC3 of the points' size");
  const int rows = points.rows, cols = points.cols;
  for (const int i : changed) {
    const int r = i / cols, c = i % cols;
    for (const auto& [dr, dc] :
         {std::pair{0, 0}, std::pair{0, -1}, std::pair{0, 1}, std::pair{-1, 0}, std::pair{1, 0}}) {
      const int rr = r + dr, cc = c + dc;
      if (rr < 1 || rr + 1 >= rows || cc < 1 || cc + 1 >= cols) continue;  // the border has none
      normals->at<cv::Vec3f>(rr, cc) = NormalAt(points, rr, cc, max_gap_mm);
    }
  }
}

}  // namespace d3d
