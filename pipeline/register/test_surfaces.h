// Test-only synthetic scenes with exact ground truth: a textured height field z = h(x, y) (world,
// mm) seen by a pinhole camera, giving organised views like pipeline/recon's. Header-only.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/core.hpp>
#include <random>
#include <vector>

#include "calib/model/camera_model.h"
#include "common/core/rigid.h"

namespace d3d::testing {

inline PinholeBrownConrady TestCamera(int w = 320, int h = 240, double f = 1000) {
  PinholeBrownConrady c;
  c.width = w;
  c.height = h;
  c.fx = c.fy = f;
  c.cx = (w - 1) / 2.0;
  c.cy = (h - 1) / 2.0;
  return c;
}

// A bumpy surface: random Gaussian bumps (tooth-like relief, 0.3–1.5 mm high, 0.8–2.5 mm wide)
// over a gentle wave, plus an albedo of random blobs.
struct HeightField {
  struct Bump {
    double x, y, a, s;
  };
  std::vector<Bump> bumps, blobs;
  double flat = 0;  // 1 → a plane z = 0 (no relief)
  double extent = 60;
  // 1-mm cells along x holding the bumps / blobs that reach into them.
  std::vector<std::vector<int>> bump_cells, blob_cells;
  // width_scale < 1: finer relief (more bumps of smaller width and height).
  explicit HeightField(uint32_t seed, double extent_mm = 60, int n = 400, double width_scale = 1.0)
      : extent(extent_mm) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> U(-extent_mm / 2, extent_mm / 2),
        A(0.3 * width_scale, 1.5 * width_scale), S(0.8 * width_scale, 2.5 * width_scale);
    for (int i = 0; i < n; ++i)
      bumps.push_back({U(rng), U(rng) / 3, A(rng) * (i % 2 ? 1 : -0.6), S(rng)});
    std::uniform_real_distribution<double> Bs(0.04, 0.15);
    for (int i = 0; i < 40 * n; ++i) blobs.push_back({U(rng), U(rng) / 3, A(rng) - 0.9, Bs(rng)});
    Bin(bumps, &bump_cells);
    Bin(blobs, &blob_cells);
  }
  // 1-mm cells in x and y (y within ±extent/2).
  int Cell(double x, double y) const {
    const int n = static_cast<int>(2 * extent) + 1;
    const int cx = std::clamp(static_cast<int>(std::floor(x + extent)), 0, n - 1);
    const int cy = std::clamp(static_cast<int>(std::floor(y + extent)), 0, n - 1);
    return cx * n + cy;
  }
  void Bin(const std::vector<Bump>& v, std::vector<std::vector<int>>* cells) const {
    const int n = static_cast<int>(2 * extent) + 1;
    cells->assign(static_cast<size_t>(n * n), {});
    for (int i = 0; i < static_cast<int>(v.size()); ++i) {
      const Bump& b = v[static_cast<size_t>(i)];
      for (double x = std::floor(b.x - 4 * b.s); x <= b.x + 4 * b.s + 1; x += 1)
        for (double y = std::floor(b.y - 4 * b.s); y <= b.y + 4 * b.s + 1; y += 1) {
          auto& c = (*cells)[static_cast<size_t>(Cell(x, y))];
          if (c.empty() || c.back() != i) c.push_back(i);
        }
    }
  }
  static double Sum(const std::vector<Bump>& v, const std::vector<int>& idx, double x, double y) {
    double z = 0;
    for (int i : idx) {
      const Bump& b = v[static_cast<size_t>(i)];
      const double d2 = (x - b.x) * (x - b.x) + (y - b.y) * (y - b.y);
      if (d2 < 16 * b.s * b.s) z += b.a * std::exp(-d2 / (2 * b.s * b.s));
    }
    return z;
  }
  double Height(double x, double y) const {
    if (flat > 0) return 0;
    return 0.4 * std::sin(0.3 * x) * std::cos(0.4 * y) +
           Sum(bumps, bump_cells[static_cast<size_t>(Cell(x, y))], x, y);
  }
  // Height and its gradient (∂h/∂x, ∂h/∂y) in one pass over the bumps (the ray caster's Newton
  // step).
  double HeightAndGradient(double x, double y, double* gx, double* gy) const {
    *gx = *gy = 0;
    if (flat > 0) return 0;
    const double sx = std::sin(0.3 * x), cx = std::cos(0.3 * x), sy = std::sin(0.4 * y),
                 cy = std::cos(0.4 * y);
    double z = 0.4 * sx * cy;
    *gx = 0.12 * cx * cy;
    *gy = -0.16 * sx * sy;
    for (int i : bump_cells[static_cast<size_t>(Cell(x, y))]) {
      const Bump& b = bumps[static_cast<size_t>(i)];
      const double d2 = (x - b.x) * (x - b.x) + (y - b.y) * (y - b.y);
      if (d2 >= 16 * b.s * b.s) continue;
      const double e = b.a * std::exp(-d2 / (2 * b.s * b.s));
      z += e;
      *gx -= e * (x - b.x) / (b.s * b.s);
      *gy -= e * (y - b.y) / (b.s * b.s);
    }
    return z;
  }
  double Albedo(double x, double y) const {
    const double a = 0.5 + 0.1 * std::sin(2.1 * x + 1.3 * y) +
                     0.5 * Sum(blobs, blob_cells[static_cast<size_t>(Cell(x, y))], x, y);
    return std::clamp(a, 0.02, 1.0);
  }
};

struct SyntheticView {
  cv::Mat points, normals, quality, texture;  // camera frame
};

// Ray-casts the height field from world_from_cam (camera looking roughly along world −z).
// noise_mm: Gaussian noise along the ray. Points with |x| or |y| beyond `half_extent` are dropped.
inline SyntheticView RenderHeightField(const HeightField& hf, const PinholeBrownConrady& cam,
                                       const Rigid3d& world_from_cam, double noise_mm,
                                       uint32_t seed, double half_extent = 29) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  SyntheticView v;
  v.points.create(cam.height, cam.width, CV_32FC3);
  v.normals.create(cam.height, cam.width, CV_32FC3);
  v.points.setTo(cv::Scalar::all(nan));
  v.normals.setTo(cv::Scalar::all(nan));
  v.quality = cv::Mat(cam.height, cam.width, CV_32F, cv::Scalar(0));
  v.texture = cv::Mat(cam.height, cam.width, CV_8U, cv::Scalar(0));
  std::mt19937 rng(seed);
  std::normal_distribution<double> N(0, 1);
  const Eigen::Vector3d C = world_from_cam.translation();
  const Rigid3d cam_from_world = world_from_cam.inverse();
  for (int r = 0; r < cam.height; ++r)
    for (int c = 0; c < cam.width; ++c) {
      const Eigen::Vector3d d =
          world_from_cam.linear() *
          Eigen::Vector3d((c - cam.cx) / cam.fx, (r - cam.cy) / cam.fy, 1).normalized();
      if (d.z() > -0.2) continue;
      // Root of g(t) = C.z + t·d.z − h(C + t·d) on the ray parameter: Newton steps, a damped
      // fixed-point step where the ray grazes the surface (g' near 0).
      double t = (0 - C.z()) / d.z();
      for (int k = 0; k < 30; ++k) {
        const Eigen::Vector3d p = C + t * d;
        double gx, gy;
        const double h = hf.HeightAndGradient(p.x(), p.y(), &gx, &gy);
        const double g = C.z() + t * d.z() - h, dg = d.z() - gx * d.x() - gy * d.y();
        const double step = dg < -0.1 ? -g / dg : 0.6 * ((h - C.z()) / d.z() - t);
        t += step;
        if (std::abs(step) < 1e-9) break;
      }
      const Eigen::Vector3d p = C + t * d;
      double gx, gy;
      const double h = hf.HeightAndGradient(p.x(), p.y(), &gx, &gy);
      if (std::abs(p.z() - h) > 1e-6 || std::abs(p.x()) > half_extent ||
          std::abs(p.y()) > half_extent)
        continue;
      const Eigen::Vector3d n_w = Eigen::Vector3d(-gx, -gy, 1).normalized();
      if (n_w.dot(-d) < 0.2) continue;
      const Eigen::Vector3d pc = cam_from_world * (p + noise_mm * N(rng) * d);
      const Eigen::Vector3d nc = cam_from_world.linear() * n_w;
      v.points.at<cv::Vec3f>(r, c) = cv::Vec3f(
          static_cast<float>(pc.x()), static_cast<float>(pc.y()), static_cast<float>(pc.z()));
      v.normals.at<cv::Vec3f>(r, c) = cv::Vec3f(
          static_cast<float>(nc.x()), static_cast<float>(nc.y()), static_cast<float>(nc.z()));
      v.quality.at<float>(r, c) = 1.0f;
      v.texture.at<uint8_t>(r, c) = static_cast<uint8_t>(
          std::clamp(255.0 * hf.Albedo(p.x(), p.y()) * n_w.dot(-d), 0.0, 255.0));
    }
  return v;
}

// Camera at (x, y, height) looking down (−z), image x along world +x, tilted by small angles.
inline Rigid3d LookDown(double x, double y, double height, double tilt_x_rad = 0,
                        double tilt_y_rad = 0, double yaw = 0) {
  Rigid3d T = Rigid3d::Identity();
  T.linear() = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(tilt_y_rad, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(tilt_x_rad, Eigen::Vector3d::UnitX()) *
                Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  T.translation() = Eigen::Vector3d(x, y, height);
  return T;
}

}  // namespace d3d::testing
