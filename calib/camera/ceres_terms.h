// Ceres pieces that every calibration step shares (calib/camera, calib/projector, calib/refine):
// the feature residuals of projection.h's model and the way options fix parameter subsets.
#pragma once

#include <ceres/ceres.h>

#include <Eigen/Core>
#include <vector>

#include "calib/camera/camera_calibration.h"
#include "calib/camera/projection.h"

namespace d3d {

// Camera feature residual (px): ProjectFeature(intrinsics[4], distortion[5], cam_from_target[6])
// minus the observed feature. fixed_aspect > 0: fy = fixed_aspect · fx.
struct CameraFeatureCost {
  Eigen::Vector3d X;  // feature on the target, mm
  Eigen::Vector2d observed;
  double radius_mm;  // circle radius (0: point feature)
  double fixed_aspect;
  template <typename T>
  bool operator()(const T* intr, const T* dist, const T* pose, T* r) const {
    T uv[2];
    ProjectFeature(intr, dist, pose, X, radius_mm, fixed_aspect, uv);
    r[0] = uv[0] - observed.x();
    r[1] = uv[1] - observed.y();
    return true;
  }
};

// Projector feature residual (projector px) of a point feature mapped into the projector:
// blocks intrinsics[4], distortion[5], proj_from_cam[6], cam_from_target[6].
struct ProjectorFeatureCost {
  Eigen::Vector3d X;  // feature on the target, mm
  Eigen::Vector2d observed;
  double fixed_aspect;
  template <typename T>
  bool operator()(const T* intr, const T* dist, const T* proj_from_cam, const T* cam_from_target,
                  T* r) const {
    T R[9], t[3], xy[2], xyd[2];
    ComposePoses(proj_from_cam, cam_from_target, R, t);
    NormalisedFeature(R, t, X, 0.0, xy);
    DistortNormalised(dist, xy, xyd);
    T fx, fy;
    FocalLengths(intr, fixed_aspect, &fx, &fy);
    r[0] = fx * xyd[0] + intr[2] - observed.x();
    r[1] = fy * xyd[1] + intr[3] - observed.y();
    return true;
  }
};

// Indices of the intrinsics[4] (fx, fy, cx, cy) and distortion[5] (k1, k2, p1, p2, k3) that the
// options hold fixed.
inline std::vector<int> FixedIntrinsics(const CameraCalibrationOptions& o) {
  std::vector<int> f;
  if (o.fix_aspect_ratio) f.push_back(1);
  if (o.fix_principal_point) {
    f.push_back(2);
    f.push_back(3);
  }
  return f;
}
inline std::vector<int> FixedDistortion(const CameraCalibrationOptions& o) {
  std::vector<int> f;
  if (o.fix_tangential) {
    f.push_back(2);
    f.push_back(3);
  }
  if (o.fix_k3) f.push_back(4);
  return f;
}

// Holds `fixed` (sorted, unique indices) of a parameter block of `size` constant.
inline void SetFixedSubset(ceres::Problem* p, double* block, int size,
                           const std::vector<int>& fixed) {
  if (static_cast<int>(fixed.size()) == size)
    p->SetParameterBlockConstant(block);
  else if (!fixed.empty())
    p->SetManifold(block, new ceres::SubsetManifold(size, fixed));
}

// The solver settings of the camera and stereo bundle adjustments: dense Schur, tight tolerances
// (sub-0.01 px features), one thread.
inline ceres::Solver::Options CalibrationSolverOptions(int max_iterations) {
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_SCHUR;
  so.max_num_iterations = max_iterations;
  so.function_tolerance = 1e-14;
  so.gradient_tolerance = 1e-14;
  so.parameter_tolerance = 1e-12;
  so.num_threads = 1;
  return so;
}

}  // namespace d3d
