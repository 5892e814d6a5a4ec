#include "calib/model/camera_model.h"

#include <Eigen/LU>
#include <cmath>

#include "common/core/status.h"

namespace d3d {

void PinholeBrownConrady::Check() const {
  D3D_CHECK_MSG(width > 0 && height > 0,
                "image size must be positive, got " << width << "x" << height);
  D3D_CHECK_MSG(fx > 0 && fy > 0 && std::isfinite(fx) && std::isfinite(fy),
                "focal lengths must be positive, got fx=" << fx << " fy=" << fy);
  for (double v : {cx, cy, k1, k2, p1, p2, k3})
    D3D_CHECK_MSG(std::isfinite(v), "non-finite intrinsic/distortion");
}

Eigen::Matrix3d PinholeBrownConrady::K() const {
  Eigen::Matrix3d K;
  K << fx, 0, cx, 0, fy, cy, 0, 0, 1;
  return K;
}

std::optional<Eigen::Vector2d> PinholeBrownConrady::Undistort(
    const Eigen::Vector2d& xy_distorted) const {
  Eigen::Vector2d xy = xy_distorted;
  for (int it = 0; it < 30; ++it) {
    const double x = xy.x(), y = xy.y();
    const double r2 = x * x + y * y;
    const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    const double dradial_dr2 = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3);
    const Eigen::Vector2d residual = Distort(xy) - xy_distorted;
    if (residual.squaredNorm() < 1e-30) return xy;
    Eigen::Matrix2d J;
    J(0, 0) = radial + 2.0 * x * x * dradial_dr2 + 2.0 * p1 * y + 6.0 * p2 * x;
    J(0, 1) = 2.0 * x * y * dradial_dr2 + 2.0 * p1 * x + 2.0 * p2 * y;
    J(1, 0) = 2.0 * x * y * dradial_dr2 + 2.0 * p1 * x + 2.0 * p2 * y;
    J(1, 1) = radial + 2.0 * y * y * dradial_dr2 + 6.0 * p1 * y + 2.0 * p2 * x;
    const double det = J.determinant();
    if (std::abs(det) < 1e-12) return std::nullopt;
    xy -= J.inverse() * residual;
    if (!xy.allFinite()) return std::nullopt;
  }
  if ((Distort(xy) - xy_distorted).norm() < 1e-10) return xy;
  return std::nullopt;
}

std::optional<Eigen::Vector3d> PinholeBrownConrady::PixelRay(const Eigen::Vector2d& pixel) const {
  const Eigen::Vector2d xd((pixel.x() - cx) / fx, (pixel.y() - cy) / fy);
  const auto xy = Undistort(xd);
  if (!xy) return std::nullopt;
  return Eigen::Vector3d(xy->x(), xy->y(), 1.0);
}

PinholeBrownConrady BinnedCamera(const PinholeBrownConrady& camera, int factor) {
  D3D_CHECK_MSG(factor >= 1, "binning factor must be >= 1, got " << factor);
  D3D_CHECK_MSG(camera.width % factor == 0 && camera.height % factor == 0,
                "camera size " << camera.width << "x" << camera.height
                               << " is not divisible by the binning factor " << factor);
  PinholeBrownConrady b = camera;
  const double f = factor, half = 0.5 * (factor - 1);
  b.width = camera.width / factor;
  b.height = camera.height / factor;
  b.fx = camera.fx / f;
  b.fy = camera.fy / f;
  b.cx = (camera.cx - half) / f;
  b.cy = (camera.cy - half) / f;
  return b;
}

}  // namespace d3d
