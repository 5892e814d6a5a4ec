#include "calib/camera/camera_calibration.h"

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "calib/camera/ceres_terms.h"
#include "calib/camera/conditioning.h"
#include "common/core/status.h"

namespace d3d {
namespace {

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

}  // namespace

std::array<double, 6> PoseToParams(const Rigid3d& pose) {
  std::array<double, 6> p{};
  const Eigen::Matrix3d R = pose.linear();
  ceres::RotationMatrixToAngleAxis(ceres::ColumnMajorAdapter3x3(R.data()), p.data());
  for (int i = 0; i < 3; ++i) p[3 + static_cast<size_t>(i)] = pose.translation()[i];
  return p;
}

Rigid3d ParamsToPose(const double* params) {
  Eigen::Matrix3d R;
  ceres::AngleAxisToRotationMatrix(params, ceres::ColumnMajorAdapter3x3(R.data()));
  Rigid3d pose = Rigid3d::Identity();
  pose.linear() = R;
  pose.translation() = Eigen::Vector3d(params[3], params[4], params[5]);
  return pose;
}

Eigen::Vector2d ProjectTargetFeature(const PinholeBrownConrady& camera,
                                     const Rigid3d& device_from_target, const Eigen::Vector3d& X,
                                     double circle_radius_mm) {
  const double intr[4] = {camera.fx, camera.fy, camera.cx, camera.cy};
  const double dist[5] = {camera.k1, camera.k2, camera.p1, camera.p2, camera.k3};
  const auto pose = PoseToParams(device_from_target);
  double uv[2];
  ProjectFeature(intr, dist, pose.data(), X, circle_radius_mm, 0.0, uv);
  return {uv[0], uv[1]};
}

std::vector<Eigen::Vector2d> ReprojectionResiduals(const TargetView& view,
                                                   const PinholeBrownConrady& camera,
                                                   const Rigid3d& device_from_target,
                                                   double circle_radius_mm) {
  std::vector<Eigen::Vector2d> r;
  r.reserve(view.image_points.size());
  for (size_t i = 0; i < view.image_points.size(); ++i)
    r.push_back(view.image_points[i] - ProjectTargetFeature(camera, device_from_target,
                                                            view.object_points[i],
                                                            circle_radius_mm));
  return r;
}

TsaiPoseResult TsaiPlanarPose(const TargetView& view, double cx, double cy, double aspect,
                              double fixed_f_px, double min_tilt_rad) {
  TsaiPoseResult out;
  const size_t n = view.image_points.size();
  if (n < 6 || view.object_points.size() != n) {
    out.reason = "fewer than 6 features";
    return out;
  }
  double s_obj = 0, s_img = 0;
  for (size_t i = 0; i < n; ++i) {
    s_obj += view.object_points[i].head<2>().squaredNorm();
    s_img += (view.image_points[i] - Eigen::Vector2d(cx, cy)).squaredNorm();
  }
  s_obj = std::sqrt(s_obj / static_cast<double>(n));
  s_img = std::sqrt(s_img / static_cast<double>(n));
  if (s_obj <= 0 || s_img <= 0) {
    out.reason = "degenerate feature positions";
    return out;
  }
  std::vector<double> xd(n), yd(n), X(n), Y(n);
  Eigen::MatrixXd M(static_cast<Eigen::Index>(n), 6);
  for (size_t i = 0; i < n; ++i) {
    xd[i] = view.image_points[i].x() - cx;
    yd[i] = (view.image_points[i].y() - cy) / aspect;
    X[i] = view.object_points[i].x();
    Y[i] = view.object_points[i].y();
    const double x = xd[i] / s_img, y = yd[i] / s_img, Xs = X[i] / s_obj, Ys = Y[i] / s_obj;
    M.row(static_cast<Eigen::Index>(i)) << y * Xs, y * Ys, y, -x * Xs, -x * Ys, -x;
  }
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(M, Eigen::ComputeFullV);
  Eigen::VectorXd v = svd.matrixV().col(5);
  // Undo the target scaling: entries 0, 1, 3, 4 multiply X/s_obj.
  v[0] /= s_obj;
  v[1] /= s_obj;
  v[3] /= s_obj;
  v[4] /= s_obj;
  const double a1 = v[0], a2 = v[1], a4 = v[3], a5 = v[4];
  const double norm2 = a1 * a1 + a2 * a2 + a4 * a4 + a5 * a5;
  const double det = a1 * a5 - a2 * a4;
  const double lambda2 = 0.5 * (norm2 + std::sqrt(std::max(0.0, norm2 * norm2 - 4.0 * det * det)));
  if (!(lambda2 > 0)) {
    out.reason =
        "radial alignment constraint is degenerate (features collinear with the principal point?)";
    return out;
  }
  double lambda = std::sqrt(lambda2);
  // Sign: the projection of the target must lie in the observed image quadrants.
  double agree = 0;
  for (size_t i = 0; i < n; ++i)
    agree +=
        xd[i] * (v[0] * X[i] + v[1] * Y[i] + v[2]) + yd[i] * (v[3] * X[i] + v[4] * Y[i] + v[5]);
  if (agree < 0) lambda = -lambda;
  Eigen::Matrix3d R;
  double r1 = v[0] / lambda, r2 = v[1] / lambda, r4 = v[3] / lambda, r5 = v[4] / lambda;
  const double tx = v[2] / lambda, ty = v[5] / lambda;
  double r3 = std::sqrt(std::max(0.0, 1.0 - r1 * r1 - r2 * r2));
  double r6 = std::sqrt(std::max(0.0, 1.0 - r4 * r4 - r5 * r5));
  if (r1 * r4 + r2 * r5 > 0) r6 = -r6;
  auto build = [&](double s3, double s6) {
    Eigen::Vector3d row1(r1, r2, s3), row2(r4, r5, s6);
    Eigen::Matrix3d Rm;
    Rm.row(0) = row1;
    Rm.row(1) = row2;
    Rm.row(2) = row1.cross(row2);
    const Eigen::JacobiSVD<Eigen::Matrix3d> s(Rm, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Rm = s.matrixU() * s.matrixV().transpose();
    if (Rm.determinant() < 0) Rm = -Rm;
    return Rm;
  };
  // f and tz by linear least squares; f < 0 flips the sign of r3, r6.
  auto solve_f_tz = [&](const Eigen::Matrix3d& Rm, double* f, double* tz) {
    Eigen::Matrix2d AtA = Eigen::Matrix2d::Zero();
    Eigen::Vector2d Atb = Eigen::Vector2d::Zero();
    double sxx = 0, sxb = 0;
    for (size_t i = 0; i < n; ++i) {
      const double b = Rm(2, 0) * X[i] + Rm(2, 1) * Y[i];
      const double ax = Rm(0, 0) * X[i] + Rm(0, 1) * Y[i] + tx;
      const double ay = Rm(1, 0) * X[i] + Rm(1, 1) * Y[i] + ty;
      for (const auto& [a, d] : {std::pair{ax, xd[i]}, std::pair{ay, yd[i]}}) {
        const Eigen::Vector2d row(a, -d);
        AtA += row * row.transpose();
        Atb += row * (d * b);
        sxx += d * d;
        sxb += d * (fixed_f_px * a - d * b);
      }
    }
    if (fixed_f_px > 0) {
      *f = fixed_f_px;
      *tz = sxb / sxx;
      return true;
    }
    if (std::abs(AtA.determinant()) < 1e-12 * AtA.squaredNorm()) return false;
    const Eigen::Vector2d sol = AtA.ldlt().solve(Atb);
    *f = sol[0];
    *tz = sol[1];
    return true;
  };
  double f = 0, tz = 0;
  bool solved = false;
  if (fixed_f_px > 0) {
    // Both tilt directions fit the RAC; keep the one whose projection with f explains the image.
    double best = std::numeric_limits<double>::infinity();
    for (const double sign : {1.0, -1.0}) {
      const Eigen::Matrix3d Rs = build(sign * r3, sign * r6);
      double fs = 0, tzs = 0;
      solve_f_tz(Rs, &fs, &tzs);
      double err = 0;
      for (size_t i = 0; i < n; ++i) {
        const double z = Rs(2, 0) * X[i] + Rs(2, 1) * Y[i] + tzs;
        const double ex = fs * (Rs(0, 0) * X[i] + Rs(0, 1) * Y[i] + tx) / z - xd[i];
        const double ey = fs * (Rs(1, 0) * X[i] + Rs(1, 1) * Y[i] + ty) / z - yd[i];
        err += ex * ex + ey * ey;
      }
      if (tzs > 0 && err < best) {
        best = err;
        R = Rs;
        f = fs;
        tz = tzs;
        solved = true;
      }
    }
    if (!solved) {
      out.reason = "target behind the device";
      return out;
    }
  } else {
    R = build(r3, r6);
    solved = solve_f_tz(R, &f, &tz);
    if (solved && f < 0) {
      r3 = -r3;
      r6 = -r6;
      R = build(r3, r6);
      solve_f_tz(R, &f, &tz);
    }
  }
  out.tilt_rad = std::acos(std::min(1.0, std::abs(R(2, 2))));
  if (fixed_f_px <= 0 && (!solved || out.tilt_rad < min_tilt_rad || !(f > 0))) {
    out.ok = true;  // the rotation is known, f is not
    out.f_px = 0;
    out.device_from_target.linear() = R;
    out.device_from_target.translation() = Eigen::Vector3d(tx, ty, 0);
    return out;
  }
  out.ok = tz > 0;
  if (!out.ok) out.reason = "target behind the device";
  out.f_px = fixed_f_px > 0 ? 0.0 : f;
  out.device_from_target.linear() = R;
  out.device_from_target.translation() = Eigen::Vector3d(tx, ty, tz);
  return out;
}

void CameraCalibrationOptions::Check() const {
  D3D_CHECK_MSG(aspect_ratio > 0, "aspect ratio must be positive");
  D3D_CHECK_MSG(circle_radius_mm >= 0, "circle radius must be ≥ 0");
  D3D_CHECK_MSG(min_views >= 2, "at least 2 views are needed");
  D3D_CHECK_MSG(min_points_per_view >= 6, "at least 6 features per view are needed");
  D3D_CHECK_MSG(min_tilt_deg >= 0 && max_relative_sigma > 0 && max_iterations > 0,
                "bad calibration limits");
}

CameraCalibrationResult CalibrateCamera(const std::vector<TargetView>& views, int width, int height,
                                        const CameraCalibrationOptions& options) {
  options.Check();
  D3D_CHECK_MSG(width > 0 && height > 0, "image size must be positive");
  for (const auto& v : views)
    D3D_CHECK_MSG(v.object_points.size() == v.image_points.size(),
                  "view '" << v.name << "': point lists differ in length");
  CameraCalibrationResult res;
  std::ostringstream why;
  if (static_cast<int>(views.size()) < options.min_views) {
    why << "too few views: " << views.size() << " < " << options.min_views << " needed";
    res.reason = why.str();
    return res;
  }
  for (const auto& v : views) {
    if (static_cast<int>(v.image_points.size()) < options.min_points_per_view) {
      why << "view '" << v.name << "' has " << v.image_points.size() << " features < "
          << options.min_points_per_view;
      res.reason = why.str();
      return res;
    }
  }
  const double cx0 = (width - 1) / 2.0, cy0 = (height - 1) / 2.0;
  const double aspect0 = options.fix_aspect_ratio ? options.aspect_ratio : 1.0;
  const double min_tilt = options.min_tilt_deg * M_PI / 180.0;
  std::vector<double> votes;
  res.views.resize(views.size());
  for (size_t i = 0; i < views.size(); ++i) {
    const TsaiPoseResult t = TsaiPlanarPose(views[i], cx0, cy0, aspect0, 0.0, min_tilt);
    res.views[i].name = views[i].name;
    res.views[i].tsai_f_px = t.f_px;
    res.views[i].tilt_deg = t.tilt_rad * 180.0 / M_PI;
    if (!t.ok) {
      why << "view '" << views[i].name << "': " << t.reason;
      res.reason = why.str();
      return res;
    }
    if (t.f_px > 0) votes.push_back(t.f_px);
  }
  if (votes.empty()) {
    double max_tilt = 0;
    for (const auto& v : res.views) max_tilt = std::max(max_tilt, v.tilt_deg);
    why << "all " << views.size() << " views are nearly fronto-parallel (largest tilt " << max_tilt
        << " deg < " << options.min_tilt_deg
        << " deg): the focal length is undetermined; tilt the target by 10–40 deg";
    res.reason = why.str();
    return res;
  }
  if (votes.size() < 2) {
    why << "only 1 view is tilted enough (≥ " << options.min_tilt_deg
        << " deg) to determine the focal length; need 2";
    res.reason = why.str();
    return res;
  }
  const double f0 = Median(votes);
  res.initial = {width, height, f0, aspect0 * f0, cx0, cy0, 0, 0, 0, 0, 0};
  std::vector<std::array<double, 6>> poses(views.size());
  double sum_sq = 0;
  int count = 0;
  for (size_t i = 0; i < views.size(); ++i) {
    const TsaiPoseResult t = TsaiPlanarPose(views[i], cx0, cy0, aspect0, f0, min_tilt);
    if (!t.ok) {
      why << "view '" << views[i].name << "': " << t.reason;
      res.reason = why.str();
      return res;
    }
    poses[i] = PoseToParams(t.device_from_target);
    for (const auto& r : ReprojectionResiduals(views[i], res.initial, t.device_from_target,
                                               options.circle_radius_mm)) {
      sum_sq += r.squaredNorm();
      ++count;
    }
  }
  res.initial_rms_px = std::sqrt(sum_sq / std::max(1, count));

  // Nonlinear refinement.
  const double fixed_aspect = options.fix_aspect_ratio ? options.aspect_ratio : 0.0;
  double intr[4] = {f0, aspect0 * f0, cx0, cy0};
  double dist[5] = {0, 0, 0, 0, 0};
  int residuals = 0;
  for (const auto& v : views) residuals += 2 * static_cast<int>(v.image_points.size());
  const std::vector<int> fixed_intr = FixedIntrinsics(options),
                         fixed_dist = FixedDistortion(options);
  const ceres::Solver::Options so = CalibrationSolverOptions(options.max_iterations);
  ceres::Solver::Summary summary;
  // Stages (a distortion-free start is far from a distorted optimum; freeing everything at once
  // lets k2/k3 run away): 1) f and poses, 2) + principal point and k1, 3) everything asked for.
  const std::vector<std::vector<int>> stage_fixed_intr = {{1, 2, 3}, {1}, fixed_intr};
  const std::vector<std::vector<int>> stage_fixed_dist = {
      {0, 1, 2, 3, 4}, {1, 2, 3, 4}, fixed_dist};
  for (size_t stage = 0; stage < 3; ++stage) {
    std::vector<int> fi = stage_fixed_intr[stage], fd = stage_fixed_dist[stage];
    for (int k : fixed_intr)
      if (std::find(fi.begin(), fi.end(), k) == fi.end()) fi.push_back(k);
    for (int k : fixed_dist)
      if (std::find(fd.begin(), fd.end(), k) == fd.end()) fd.push_back(k);
    std::sort(fi.begin(), fi.end());
    std::sort(fd.begin(), fd.end());
    if (stage < 2 && !options.fix_aspect_ratio)
      intr[1] = intr[0] * aspect0;  // one f in the first stages
    const double stage_aspect = stage < 2 ? aspect0 : fixed_aspect;
    ceres::Problem problem;
    for (size_t i = 0; i < views.size(); ++i) {
      for (size_t k = 0; k < views[i].image_points.size(); ++k) {
        auto* cost = new ceres::AutoDiffCostFunction<CameraFeatureCost, 2, 4, 5, 6>(
            new CameraFeatureCost{views[i].object_points[k], views[i].image_points[k],
                                  options.circle_radius_mm, stage_aspect});
        problem.AddResidualBlock(cost, nullptr, intr, dist, poses[i].data());
      }
    }
    SetFixedSubset(&problem, intr, 4, fi);
    SetFixedSubset(&problem, dist, 5, fd);
    ceres::Solve(so, &problem, &summary);
    if (!summary.IsSolutionUsable()) break;
    if (stage < 2) intr[1] = intr[0] * aspect0;
    if (stage == 2) {
      res.iterations = static_cast<int>(summary.iterations.size());
      if (options.fix_aspect_ratio) intr[1] = options.aspect_ratio * intr[0];
      // Conditioning: covariance of the free parameters from the column-scaled Gauss–Newton normal
      // matrix (Jacobi scaling makes the condition number meaningful across px, mm, rad and k3).
      std::vector<double*> order;
      for (auto& p : poses) order.push_back(p.data());
      order.push_back(intr);
      order.push_back(dist);
      const ConditioningReport cond = ComputeCovariance(&problem, order, residuals);
      res.reciprocal_condition = cond.reciprocal_condition;
      if (cond.ok) {
        int offset = 6 * static_cast<int>(views.size());
        for (int k = 0; k < 4; ++k)
          if (std::find(fixed_intr.begin(), fixed_intr.end(), k) == fixed_intr.end())
            res.sigma[static_cast<size_t>(k)] = cond.sigma[static_cast<size_t>(offset++)];
        for (int k = 0; k < 5; ++k)
          if (std::find(fixed_dist.begin(), fixed_dist.end(), k) == fixed_dist.end())
            res.sigma[4 + static_cast<size_t>(k)] = cond.sigma[static_cast<size_t>(offset++)];
        if (options.fix_aspect_ratio) res.sigma[1] = options.aspect_ratio * res.sigma[0];
      } else {
        res.sigma.fill(std::numeric_limits<double>::infinity());
      }
    }
  }
  if (!summary.IsSolutionUsable()) {
    res.reason = "nonlinear refinement failed: " + summary.message;
    return res;
  }
  res.camera = {width,   height,  intr[0], intr[1], intr[2], intr[3],
                dist[0], dist[1], dist[2], dist[3], dist[4]};
  sum_sq = 0;
  res.features = 0;
  for (size_t i = 0; i < views.size(); ++i) {
    auto& vr = res.views[i];
    vr.device_from_target = ParamsToPose(poses[i].data());
    vr.residuals_px = ReprojectionResiduals(views[i], res.camera, vr.device_from_target,
                                            options.circle_radius_mm);
    double s = 0;
    for (const auto& r : vr.residuals_px) s += r.squaredNorm();
    vr.rms_px = std::sqrt(s / static_cast<double>(std::max<size_t>(1, vr.residuals_px.size())));
    sum_sq += s;
    res.features += static_cast<int>(vr.residuals_px.size());
  }
  res.rms_px = std::sqrt(sum_sq / std::max(1, res.features));

  if (!std::isfinite(res.sigma[0])) {
    why << "ill-conditioned: the Jacobian is rank-deficient (reciprocal condition "
        << res.reciprocal_condition << "); views too similar or too flat";
    res.reason = why.str();
    return res;
  }
  const double rel = std::max(res.sigma[0] / res.camera.fx, res.sigma[1] / res.camera.fy);
  if (!(rel <= options.max_relative_sigma)) {
    why << "ill-conditioned: sigma(fx) = " << res.sigma[0] << " px, sigma(fy) = " << res.sigma[1]
        << " px (" << 100.0 * rel << " % > " << 100.0 * options.max_relative_sigma
        << " %); add views at other tilts";
    res.reason = why.str();
    return res;
  }
  try {
    res.camera.Check();
  } catch (const std::invalid_argument& e) {
    res.reason = std::string("refined camera is invalid: ") + e.what();
    return res;
  }
  res.ok = true;
  return res;
}

}  // namespace d3d
