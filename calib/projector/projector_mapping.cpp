#include "calib/projector/projector_mapping.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>

namespace d3d {

void PhaseDecodeOptions::Check() const {
  D3D_CHECK_MSG(steps >= 3, "phase steps must be ≥ 3");
  D3D_CHECK_MSG(!periods_px.empty(), "at least one period");
  for (double p : periods_px) D3D_CHECK_MSG(p >= 2.0, "periods must be ≥ 2 px");
  D3D_CHECK_MSG(min_modulation_dn >= 0, "min modulation must be ≥ 0");
}

void FeatureMappingOptions::Check() const {
  D3D_CHECK_MSG(window_radius_px >= 3, "window radius must be ≥ 3 px");
  D3D_CHECK_MSG(modulation_fraction >= 0 && modulation_fraction < 1,
                "modulation fraction must be in [0, 1)");
  D3D_CHECK_MSG(min_samples >= 12, "at least 12 samples for a quadratic fit");
  D3D_CHECK_MSG(max_fit_rms_px > 0, "max fit RMS must be positive");
}

Status DecodeProjectorCoordinate(const std::vector<cv::Mat>& frames,
                                 const PhaseDecodeOptions& options, ProjectorCoordinateMap* out) {
  options.Check();
  const size_t N = static_cast<size_t>(options.steps), P = options.periods_px.size();
  if (frames.size() != N * P) {
    return InvalidArgument("phase decoding: expected " + std::to_string(N * P) + " frames (" +
                           std::to_string(N) + " steps × " + std::to_string(P) + " periods), got " +
                           std::to_string(frames.size()));
  }
  const cv::Size size = frames[0].size();
  for (const auto& f : frames) {
    if (f.size() != size) return InvalidArgument("phase decoding: frames differ in size");
    if (f.type() != CV_8U && f.type() != CV_16U)
      return InvalidArgument("phase decoding: frames must be CV_8U or CV_16U");
  }
  std::vector<cv::Mat> fl(frames.size());
  for (size_t i = 0; i < frames.size(); ++i)
    frames[i].convertTo(fl[i], CV_32F, frames[i].type() == CV_16U ? 1.0 / 257.0 : 1.0);
  std::vector<double> cs(N), sn(N);
  for (size_t n = 0; n < N; ++n) {
    cs[n] = std::cos(2.0 * M_PI * static_cast<double>(n) / static_cast<double>(N));
    sn[n] = std::sin(2.0 * M_PI * static_cast<double>(n) / static_cast<double>(N));
  }
  out->coord_px.create(size, CV_32F);
  out->modulation.create(size, CV_32F);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int r = 0; r < size.height; ++r)
    for (int c = 0; c < size.width; ++c) {
      double coord = 0, mod = 0;
      bool saturated = false;
      for (size_t p = 0; p < P; ++p) {
        double re = 0, im = 0;
        for (size_t n = 0; n < N; ++n) {
          const float v = fl[p * N + n].at<float>(r, c);
          saturated |= v >= 254.5f;
          re += v * cs[n];
          im += v * sn[n];
        }
        const double T = options.periods_px[p];
        double phi = std::atan2(im, re);
        if (phi < 0) phi += 2.0 * M_PI;
        mod = 2.0 / static_cast<double>(N) * std::hypot(re, im);
        if (p == 0) {
          coord = phi * T / (2.0 * M_PI);
        } else {
          const double k = std::round((2.0 * M_PI * coord / T - phi) / (2.0 * M_PI));
          coord = (phi + 2.0 * M_PI * k) * T / (2.0 * M_PI);
        }
      }
      const bool ok = !saturated && mod >= options.min_modulation_dn;
      out->coord_px.at<float>(r, c) = ok ? static_cast<float>(coord) : nan;
      out->modulation.at<float>(r, c) = static_cast<float>(mod);
    }
  return Status::Ok();
}

std::vector<MappedFeature> MapFeaturesToProjector(const ProjectorCoordinateMap& u_map,
                                                  const ProjectorCoordinateMap& v_map,
                                                  const std::vector<Eigen::Vector2d>& camera_px,
                                                  const FeatureMappingOptions& options) {
  options.Check();
  D3D_CHECK_MSG(u_map.coord_px.size() == v_map.coord_px.size() && !u_map.coord_px.empty(),
                "u and v maps must have one size");
  const int W = u_map.coord_px.cols, H = u_map.coord_px.rows;
  const double R = options.window_radius_px;
  std::vector<MappedFeature> out(camera_px.size());
  for (size_t i = 0; i < camera_px.size(); ++i) {
    MappedFeature& m = out[i];
    const Eigen::Vector2d c = camera_px[i];
    const int x0 = std::max(0, static_cast<int>(std::floor(c.x() - R))),
              x1 = std::min(W - 1, static_cast<int>(std::ceil(c.x() + R)));
    const int y0 = std::max(0, static_cast<int>(std::floor(c.y() - R))),
              y1 = std::min(H - 1, static_cast<int>(std::ceil(c.y() + R)));
    struct S {
      double dx, dy, u, v;
    };
    std::vector<float> mods;
    for (int y = y0; y <= y1; ++y)
      for (int x = x0; x <= x1; ++x) {
        if ((x - c.x()) * (x - c.x()) + (y - c.y()) * (y - c.y()) > R * R) continue;
        mods.push_back(
            std::min(u_map.modulation.at<float>(y, x), v_map.modulation.at<float>(y, x)));
      }
    if (mods.size() < static_cast<size_t>(options.min_samples)) {
      m.reason = "feature too close to the image border";
      continue;
    }
    std::nth_element(mods.begin(),
                     mods.begin() + static_cast<long>(0.9 * static_cast<double>(mods.size() - 1)),
                     mods.end());
    const double limit = options.modulation_fraction *
                         mods[static_cast<size_t>(0.9 * static_cast<double>(mods.size() - 1))];
    std::vector<S> samples;
    for (int y = y0; y <= y1; ++y)
      for (int x = x0; x <= x1; ++x) {
        if ((x - c.x()) * (x - c.x()) + (y - c.y()) * (y - c.y()) > R * R) continue;
        const float u = u_map.coord_px.at<float>(y, x), v = v_map.coord_px.at<float>(y, x);
        if (!std::isfinite(u) || !std::isfinite(v)) continue;
        if (std::min(u_map.modulation.at<float>(y, x), v_map.modulation.at<float>(y, x)) < limit)
          continue;
        samples.push_back({(x - c.x()) / R, (y - c.y()) / R, u, v});
      }
    std::vector<uint8_t> use(samples.size(), 1);
    Eigen::Vector2d value = Eigen::Vector2d::Zero();
    double rms = 0;
    int used = 0;
    bool fitted = false;
    for (int round = 0; round < 2; ++round) {
      used = 0;
      for (auto b : use) used += b;
      if (used < options.min_samples) break;
      Eigen::MatrixXd A(used, 6);
      Eigen::MatrixXd B(used, 2);
      int row = 0;
      for (size_t k = 0; k < samples.size(); ++k) {
        if (!use[k]) continue;
        const auto& s = samples[k];
        A.row(row) << 1.0, s.dx, s.dy, s.dx * s.dx, s.dx * s.dy, s.dy * s.dy;
        B.row(row) << s.u, s.v;
        ++row;
      }
      const Eigen::MatrixXd coef = A.colPivHouseholderQr().solve(B);
      const Eigen::MatrixXd res = A * coef - B;
      rms = std::sqrt(res.squaredNorm() / used);
      value = coef.row(0).transpose();
      fitted = true;
      if (round == 0) {
        row = 0;
        for (size_t k = 0; k < samples.size(); ++k) {
          if (!use[k]) continue;
          if (res.row(row).norm() > 3.0 * rms + 1e-9) use[k] = 0;
          ++row;
        }
      }
    }
    m.samples = used;
    m.fit_rms_px = rms;
    if (!fitted || used < options.min_samples) {
      m.reason =
          "too few pixels with good modulation around the feature (" + std::to_string(used) + ")";
      continue;
    }
    if (rms > options.max_fit_rms_px) {
      m.reason = "projector coordinates do not fit a smooth surface around the feature (RMS " +
                 std::to_string(rms) + " px)";
      continue;
    }
    m.ok = true;
    m.projector_px = value;
  }
  return out;
}

}  // namespace d3d
