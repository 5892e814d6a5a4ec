#include "calib/projector/stereo_calibration.h"

#include <ceres/ceres.h>

#include <Eigen/Dense>
#include <cmath>
#include <sstream>

#include "calib/camera/ceres_terms.h"
#include "calib/camera/conditioning.h"
#include "common/core/status.h"

namespace d3d {
namespace {}  // namespace

void StereoCalibrationOptions::Check() const {
  camera.Check();
  projector.Check();
  D3D_CHECK_MSG(max_iterations > 0, "max_iterations must be positive");
  D3D_CHECK_MSG(max_extrinsic_sigma_mm > 0 && max_extrinsic_sigma_rad > 0,
                "extrinsic limits must be positive");
}

Rigid3d AverageRigid(const std::vector<Rigid3d>& poses) {
  D3D_CHECK_MSG(!poses.empty(), "nothing to average");
  Eigen::Matrix4d M = Eigen::Matrix4d::Zero();
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
  for (const auto& p : poses) {
    const Eigen::Quaterniond q(p.linear());
    const Eigen::Vector4d v(q.w(), q.x(), q.y(), q.z());
    M += v * v.transpose();
    t += p.translation();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix4d> eig(M);
  const Eigen::Vector4d v = eig.eigenvectors().col(3);
  Rigid3d out = Rigid3d::Identity();
  out.linear() = Eigen::Quaterniond(v[0], v[1], v[2], v[3]).normalized().toRotationMatrix();
  out.translation() = t / static_cast<double>(poses.size());
  return out;
}

StereoCalibrationResult CalibrateStereo(const std::vector<StereoView>& views, int camera_width,
                                        int camera_height, int projector_width,
                                        int projector_height,
                                        const StereoCalibrationOptions& options) {
  options.Check();
  for (const auto& v : views) {
    D3D_CHECK_MSG(v.object_points.size() == v.camera_px.size() &&
                      v.camera_px.size() == v.projector_px.size() &&
                      v.projector_px.size() == v.projector_valid.size(),
                  "stereo view '" << v.name << "': point lists differ in length");
  }
  StereoCalibrationResult res;
  std::ostringstream why;
  // Step 3: the camera alone.
  std::vector<TargetView> cam_views, proj_views;
  for (const auto& v : views) {
    cam_views.push_back({v.name, v.object_points, v.camera_px});
    TargetView p{v.name, {}, {}};
    for (size_t k = 0; k < v.object_points.size(); ++k) {
      if (!v.projector_valid[k]) continue;
      p.object_points.push_back(v.object_points[k]);
      p.image_points.push_back(v.projector_px[k]);
    }
    proj_views.push_back(p);
  }
  res.camera_only = CalibrateCamera(cam_views, camera_width, camera_height, options.camera);
  if (!res.camera_only.ok) {
    res.reason = "camera: " + res.camera_only.reason;
    return res;
  }
  CameraCalibrationOptions po = options.projector;
  po.circle_radius_mm = 0.0;
  res.projector_only = CalibrateCamera(proj_views, projector_width, projector_height, po);
  if (!res.projector_only.ok) {
    res.reason = "projector: " + res.projector_only.reason;
    return res;
  }
  std::vector<Rigid3d> rel;
  for (size_t i = 0; i < views.size(); ++i)
    rel.push_back(res.projector_only.views[i].device_from_target *
                  res.camera_only.views[i].device_from_target.inverse());
  const Rigid3d proj_from_cam0 = AverageRigid(rel);
  res.initial_cam_from_proj = proj_from_cam0.inverse();

  // Bundle adjustment of both devices and all target poses.
  const auto& c = res.camera_only.camera;
  const auto& p = res.projector_only.camera;
  double cam_intr[4] = {c.fx, c.fy, c.cx, c.cy}, cam_dist[5] = {c.k1, c.k2, c.p1, c.p2, c.k3};
  double proj_intr[4] = {p.fx, p.fy, p.cx, p.cy}, proj_dist[5] = {p.k1, p.k2, p.p1, p.p2, p.k3};
  auto extr = PoseToParams(proj_from_cam0);
  std::vector<std::array<double, 6>> poses;
  for (const auto& v : res.camera_only.views) poses.push_back(PoseToParams(v.device_from_target));
  const double cam_aspect = options.camera.fix_aspect_ratio ? options.camera.aspect_ratio : 0.0;
  const double proj_aspect =
      options.projector.fix_aspect_ratio ? options.projector.aspect_ratio : 0.0;
  ceres::Problem problem;
  int residuals = 0;
  for (size_t i = 0; i < views.size(); ++i) {
    const auto& v = views[i];
    for (size_t k = 0; k < v.object_points.size(); ++k) {
      problem.AddResidualBlock(
          new ceres::AutoDiffCostFunction<CameraFeatureCost, 2, 4, 5, 6>(new CameraFeatureCost{
              v.object_points[k], v.camera_px[k], options.camera.circle_radius_mm, cam_aspect}),
          nullptr, cam_intr, cam_dist, poses[i].data());
      residuals += 2;
      if (!v.projector_valid[k]) continue;
      problem.AddResidualBlock(
          new ceres::AutoDiffCostFunction<ProjectorFeatureCost, 2, 4, 5, 6, 6>(
              new ProjectorFeatureCost{v.object_points[k], v.projector_px[k], proj_aspect}),
          nullptr, proj_intr, proj_dist, extr.data(), poses[i].data());
      residuals += 2;
    }
  }
  const auto fci = FixedIntrinsics(options.camera), fcd = FixedDistortion(options.camera);
  const auto fpi = FixedIntrinsics(options.projector), fpd = FixedDistortion(options.projector);
  SetFixedSubset(&problem, cam_intr, 4, fci);
  SetFixedSubset(&problem, cam_dist, 5, fcd);
  SetFixedSubset(&problem, proj_intr, 4, fpi);
  SetFixedSubset(&problem, proj_dist, 5, fpd);
  const ceres::Solver::Options so = CalibrationSolverOptions(options.max_iterations);
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  if (!summary.IsSolutionUsable()) {
    res.reason = "bundle adjustment failed: " + summary.message;
    return res;
  }
  if (cam_aspect > 0) cam_intr[1] = cam_aspect * cam_intr[0];
  if (proj_aspect > 0) proj_intr[1] = proj_aspect * proj_intr[0];
  res.camera = {camera_width, camera_height, cam_intr[0], cam_intr[1], cam_intr[2], cam_intr[3],
                cam_dist[0],  cam_dist[1],   cam_dist[2], cam_dist[3], cam_dist[4]};
  res.projector = {projector_width, projector_height, proj_intr[0], proj_intr[1],
                   proj_intr[2],    proj_intr[3],     proj_dist[0], proj_dist[1],
                   proj_dist[2],    proj_dist[3],     proj_dist[4]};
  const Rigid3d proj_from_cam = ParamsToPose(extr.data());
  res.cam_from_proj = proj_from_cam.inverse();
  double cs = 0, ps = 0;
  int cn = 0, pn = 0;
  for (size_t i = 0; i < views.size(); ++i) {
    const Rigid3d pose = ParamsToPose(poses[i].data());
    res.cam_from_target.push_back(pose);
    std::vector<Eigen::Vector2d> cr, pr;
    double vs = 0, vp = 0;
    for (size_t k = 0; k < views[i].object_points.size(); ++k) {
      cr.push_back(views[i].camera_px[k] - ProjectTargetFeature(res.camera, pose,
                                                                views[i].object_points[k],
                                                                options.camera.circle_radius_mm));
      vs += cr.back().squaredNorm();
      if (!views[i].projector_valid[k]) {
        pr.push_back(Eigen::Vector2d(NAN, NAN));
        continue;
      }
      pr.push_back(views[i].projector_px[k] - ProjectTargetFeature(res.projector,
                                                                   proj_from_cam * pose,
                                                                   views[i].object_points[k], 0.0));
      vp += pr.back().squaredNorm();
      ++pn;
    }
    cn += static_cast<int>(cr.size());
    cs += vs;
    ps += vp;
    const int vpn = static_cast<int>(
        std::count(views[i].projector_valid.begin(), views[i].projector_valid.end(), 1));
    res.camera_view_rms_px.push_back(std::sqrt(vs / std::max<size_t>(1, cr.size())));
    res.projector_view_rms_px.push_back(std::sqrt(vp / std::max(1, vpn)));
    res.camera_residuals_px.push_back(std::move(cr));
    res.projector_residuals_px.push_back(std::move(pr));
  }
  res.camera_rms_px = std::sqrt(cs / std::max(1, cn));
  res.projector_rms_px = std::sqrt(ps / std::max(1, pn));

  // Conditioning of the whole system.
  std::vector<double*> order;
  for (auto& q : poses) order.push_back(q.data());
  order.insert(order.end(), {cam_intr, cam_dist, proj_intr, proj_dist, extr.data()});
  const ConditioningReport cond = ComputeCovariance(&problem, order, residuals);
  res.reciprocal_condition = cond.reciprocal_condition;
  if (!cond.ok) {
    why << "ill-conditioned: the stereo Jacobian is rank-deficient (reciprocal condition "
        << cond.reciprocal_condition << ")";
    res.reason = why.str();
    return res;
  }
  size_t off = 6 * views.size();
  auto take = [&](std::array<double, 9>* sig, int base, int size, const std::vector<int>& fixed) {
    for (int k = 0; k < size; ++k)
      if (std::find(fixed.begin(), fixed.end(), k) == fixed.end())
        (*sig)[static_cast<size_t>(base + k)] = cond.sigma[off++];
  };
  take(&res.camera_sigma, 0, 4, fci);
  take(&res.camera_sigma, 4, 5, fcd);
  take(&res.projector_sigma, 0, 4, fpi);
  take(&res.projector_sigma, 4, 5, fpd);
  for (size_t k = 0; k < 6; ++k) res.extrinsic_sigma[k] = cond.sigma[off++];
  const double sig_rot =
      std::max({res.extrinsic_sigma[0], res.extrinsic_sigma[1], res.extrinsic_sigma[2]});
  const double sig_t =
      std::max({res.extrinsic_sigma[3], res.extrinsic_sigma[4], res.extrinsic_sigma[5]});
  if (sig_rot > options.max_extrinsic_sigma_rad || sig_t > options.max_extrinsic_sigma_mm) {
    why << "ill-conditioned: sigma of cam_from_proj " << sig_rot << " rad, " << sig_t
        << " mm (limits " << options.max_extrinsic_sigma_rad << " rad, "
        << options.max_extrinsic_sigma_mm << " mm)";
    res.reason = why.str();
    return res;
  }
  res.ok = true;
  return res;
}

}  // namespace d3d
