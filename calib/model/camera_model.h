// Pinhole camera with Brown–Conrady distortion in OpenCV's convention, used for both the camera
// and the projector (an inverse camera), so one calibration file describes a real or virtual probe.
//
// Model (OpenCV calib3d, "Detailed description"): for p_in_cam = (X, Y, Z), Z > 0,
//   x = X/Z, y = Y/Z, r² = x² + y²
//   x' = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²)
//   y' = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y
//   u = fx x' + cx,  v = fy y' + cy            (pixels; the centre of pixel (0,0) is at (0,0))
#pragma once

#include <Eigen/Core>
#include <optional>

namespace d3d {

struct PinholeBrownConrady {
  int width = 0;  // image size, pixels
  int height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;          // intrinsics K, pixels
  double k1 = 0, k2 = 0, p1 = 0, p2 = 0, k3 = 0;  // distortion, OpenCV order (k1,k2,p1,p2,k3)

  // Throws std::invalid_argument for a non-positive size or focal length, or non-finite values.
  void Check() const;
  Eigen::Matrix3d K() const;

  // Normalised undistorted (x, y) → normalised distorted (x', y').
  Eigen::Vector2d Distort(const Eigen::Vector2d& xy) const;
  // Inverse of Distort by Gauss–Newton on the 2×2 Jacobian (converges to < 1e-12 in the image
  // for the distortions of real lenses); nullopt if it does not converge (far outside the image).
  std::optional<Eigen::Vector2d> Undistort(const Eigen::Vector2d& xy_distorted) const;
  // p_in_cam (mm, Z > 0) → pixel. nullopt for Z <= 0.
  std::optional<Eigen::Vector2d> Project(const Eigen::Vector3d& p_in_cam) const;
  // Pixel → ray direction (x, y, 1) in the camera frame (not normalised). nullopt if Undistort
  // fails.
  std::optional<Eigen::Vector3d> PixelRay(const Eigen::Vector2d& pixel) const;
  // True if the pixel lies inside the image [-0.5, width-0.5) × [-0.5, height-0.5).
  bool InImage(const Eigen::Vector2d& pixel) const;
};

// The camera whose pixels are `factor` × `factor` blocks of `camera`'s (a binned read-out, or the
// frames averaged over such blocks): size / factor, fx, fy / factor, and the principal point moved
// so that binned pixel (u', v') is centred where its block's centre was, u = factor·u' + (factor −
// 1)/2: cx' = (cx − (factor − 1)/2) / factor (cy alike). Distortion acts on normalised coordinates
// and is unchanged. Throws std::invalid_argument for factor < 1 or a size not divisible by factor.
PinholeBrownConrady BinnedCamera(const PinholeBrownConrady& camera, int factor);

// Inline: per pixel in the virtual probe's geometry pass (once per camera ray, for the projector).
inline Eigen::Vector2d PinholeBrownConrady::Distort(const Eigen::Vector2d& xy) const {
  const double x = xy.x(), y = xy.y();
  const double r2 = x * x + y * y;
  const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
  return {x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
          y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y};
}

inline std::optional<Eigen::Vector2d> PinholeBrownConrady::Project(
    const Eigen::Vector3d& p_in_cam) const {
  if (!(p_in_cam.z() > 0.0)) return std::nullopt;
  const Eigen::Vector2d d = Distort(p_in_cam.head<2>() / p_in_cam.z());
  return Eigen::Vector2d(fx * d.x() + cx, fy * d.y() + cy);
}

inline bool PinholeBrownConrady::InImage(const Eigen::Vector2d& pixel) const {
  return pixel.x() >= -0.5 && pixel.y() >= -0.5 && pixel.x() < width - 0.5 &&
         pixel.y() < height - 0.5;
}

}  // namespace d3d
