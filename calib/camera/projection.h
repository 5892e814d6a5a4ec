// The projection model that every calibration step fits, templated for Ceres' automatic
// differentiation (T = double or ceres::Jet).
//
// Parameter blocks:
//   intrinsics[4] = (fx, fy, cx, cy)  px; with a fixed aspect ratio a, fy is taken as a·fx
//   distortion[5] = (k1, k2, p1, p2, k3)  OpenCV's order and model (calib/model/camera_model.h)
//   pose[6]       = (angle-axis ω (rad), t (mm)): device_from_target, p_dev = R(ω)·p_target + t
//
// Feature models:
//   point   the image of the target point X (chessboard corners, mapped projector features);
//   circle  the centre of the image of a circle of radius r around X on the target plane: the
//           pole of the line at infinity w.r.t. the projected dual conic,
//             c ≃ H · Q*(X, r) · (row 3 of H)ᵀ,  H = [r₁ r₂ t],
//             Q*(X, r) = T·diag(r², r², −1)·Tᵀ, T = translation by (X, Y) on the target plane,
//           i.e. where the centroid of the (undistorted) imaged ellipse lies. This is the
//           perspective bias of circle centres (Heikkilä 2000, IEEE TPAMI 22(10), sect. 3)
//           built into the model instead of corrected afterwards. Lens distortion is applied to
//           that centre (the blob is small: distortion is locally affine over it, and an affine
//           map keeps centroids).
#pragma once

#include <ceres/rotation.h>

#include <Eigen/Core>

namespace d3d {

// Normalised undistorted image coordinates (x/z, y/z) of a target feature seen from a device
// with rotation R (3×3, row-major: R[3*i + j]) and translation t. radius_mm = 0: point model.
template <typename T>
void NormalisedFeature(const T* R, const T* t, const Eigen::Vector3d& X, double radius_mm, T* xy) {
  if (radius_mm <= 0.0) {
    T p[3];
    for (int i = 0; i < 3; ++i)
      p[i] = R[3 * i] * X.x() + R[3 * i + 1] * X.y() + R[3 * i + 2] * X.z() + t[i];
    xy[0] = p[0] / p[2];
    xy[1] = p[1] / p[2];
    return;
  }
  // The target plane is z = 0: H = [r1 r2 t] (columns 0, 1 of R and t). X.z() must be 0.
  const double X0 = X.x(), Y0 = X.y(), r2 = radius_mm * radius_mm;
  const T h3[3] = {R[6], R[7], t[2]};  // row 3 of H
  const double Q[3][3] = {
      {r2 - X0 * X0, -X0 * Y0, -X0}, {-X0 * Y0, r2 - Y0 * Y0, -Y0}, {-X0, -Y0, -1.0}};
  T m[3];
  for (int i = 0; i < 3; ++i) m[i] = Q[i][0] * h3[0] + Q[i][1] * h3[1] + Q[i][2] * h3[2];
  T c[3];
  for (int i = 0; i < 3; ++i) c[i] = R[3 * i] * m[0] + R[3 * i + 1] * m[1] + t[i] * m[2];
  xy[0] = c[0] / c[2];
  xy[1] = c[1] / c[2];
}

// OpenCV's Brown–Conrady distortion of normalised coordinates.
template <typename T>
void DistortNormalised(const T* d, const T* xy, T* xyd) {
  const T x = xy[0], y = xy[1];
  const T r2 = x * x + y * y;
  const T radial = T(1.0) + r2 * (d[0] + r2 * (d[1] + r2 * d[4]));
  xyd[0] = x * radial + T(2.0) * d[2] * x * y + d[3] * (r2 + T(2.0) * x * x);
  xyd[1] = y * radial + d[2] * (r2 + T(2.0) * y * y) + T(2.0) * d[3] * x * y;
}

// Inverse of DistortNormalised by fixed-point iteration (a fixed count, so it differentiates
// with Jets): x ← (x_d − tangential(x)) / radial(x). Converges for the distortions of real
// lenses inside the image (|k1 r²| ≪ 1).
template <typename T>
void UndistortNormalised(const T* d, const T* xyd, T* xy, int iterations = 12) {
  T x = xyd[0], y = xyd[1];
  for (int it = 0; it < iterations; ++it) {
    const T r2 = x * x + y * y;
    const T radial = T(1.0) + r2 * (d[0] + r2 * (d[1] + r2 * d[4]));
    const T dx = T(2.0) * d[2] * x * y + d[3] * (r2 + T(2.0) * x * x);
    const T dy = d[2] * (r2 + T(2.0) * y * y) + T(2.0) * d[3] * x * y;
    x = (xyd[0] - dx) / radial;
    y = (xyd[1] - dy) / radial;
  }
  xy[0] = x;
  xy[1] = y;
}

// fx, fy of an intrinsics block (fy = aspect·fx when the aspect ratio is fixed, aspect > 0).
template <typename T>
void FocalLengths(const T* intr, double fixed_aspect, T* fx, T* fy) {
  *fx = intr[0];
  *fy = fixed_aspect > 0.0 ? T(fixed_aspect) * intr[0] : intr[1];
}

// Pixel of a target feature: pose block → R, t → normalised → distorted → K.
template <typename T>
void ProjectFeature(const T* intr, const T* dist, const T* pose, const Eigen::Vector3d& X,
                    double radius_mm, double fixed_aspect, T* uv) {
  T R[9];
  ceres::AngleAxisToRotationMatrix(pose, ceres::RowMajorAdapter3x3(R));
  T xy[2], xyd[2];
  NormalisedFeature(R, pose + 3, X, radius_mm, xy);
  DistortNormalised(dist, xy, xyd);
  T fx, fy;
  FocalLengths(intr, fixed_aspect, &fx, &fy);
  uv[0] = fx * xyd[0] + intr[2];
  uv[1] = fy * xyd[1] + intr[3];
}

// Composition for a second device rigidly attached to the first: dev2_from_target =
// dev2_from_dev1 ∘ dev1_from_target, as row-major R and t.
template <typename T>
void ComposePoses(const T* dev2_from_dev1, const T* dev1_from_target, T* R, T* t) {
  T Ra[9], Rb[9];
  ceres::AngleAxisToRotationMatrix(dev2_from_dev1, ceres::RowMajorAdapter3x3(Ra));
  ceres::AngleAxisToRotationMatrix(dev1_from_target, ceres::RowMajorAdapter3x3(Rb));
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j)
      R[3 * i + j] = Ra[3 * i] * Rb[j] + Ra[3 * i + 1] * Rb[3 + j] + Ra[3 * i + 2] * Rb[6 + j];
    t[i] = Ra[3 * i] * dev1_from_target[3] + Ra[3 * i + 1] * dev1_from_target[4] +
           Ra[3 * i + 2] * dev1_from_target[5] + dev2_from_dev1[3 + i];
  }
}

}  // namespace d3d
