#include "calib/refine/multi_plane.h"

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <Eigen/Dense>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "calib/camera/ceres_terms.h"
#include "common/core/status.h"

namespace d3d {
namespace {

struct DenseCost {
  Eigen::Vector2d camera_px, projector_px;
  double cam_aspect, proj_aspect;
  template <typename T>
  bool operator()(const T* ci, const T* cd, const T* pi, const T* pd, const T* proj_from_cam,
                  const T* cam_from_target, T* r) const {
    T fx, fy;
    FocalLengths(ci, cam_aspect, &fx, &fy);
    const T xyd[2] = {(T(camera_px.x()) - ci[2]) / fx, (T(camera_px.y()) - ci[3]) / fy};
    T xy[2];
    UndistortNormalised(cd, xyd, xy);
    T R[9];
    ceres::AngleAxisToRotationMatrix(cam_from_target, ceres::RowMajorAdapter3x3(R));
    const T n[3] = {R[2], R[5], R[8]};  // target normal in the camera frame
    const T* t = cam_from_target + 3;
    const T lambda =
        (n[0] * t[0] + n[1] * t[1] + n[2] * t[2]) / (n[0] * xy[0] + n[1] * xy[1] + n[2]);
    const T P[3] = {lambda * xy[0], lambda * xy[1], lambda};
    T Rp[9];
    ceres::AngleAxisToRotationMatrix(proj_from_cam, ceres::RowMajorAdapter3x3(Rp));
    T Q[3];
    for (int i = 0; i < 3; ++i)
      Q[i] = Rp[3 * i] * P[0] + Rp[3 * i + 1] * P[1] + Rp[3 * i + 2] * P[2] + proj_from_cam[3 + i];
    const T q[2] = {Q[0] / Q[2], Q[1] / Q[2]};
    T qd[2];
    DistortNormalised(pd, q, qd);
    T pfx, pfy;
    FocalLengths(pi, proj_aspect, &pfx, &pfy);
    r[0] = pfx * qd[0] + pi[2] - projector_px.x();
    r[1] = pfy * qd[1] + pi[3] - projector_px.y();
    return true;
  }
};

double DenseRms(const PinholeBrownConrady& cam, const PinholeBrownConrady& proj,
                const Rigid3d& cam_from_proj, const std::vector<Rigid3d>& poses,
                const std::vector<std::vector<PlaneSample>>& dense) {
  const double ci[4] = {cam.fx, cam.fy, cam.cx, cam.cy},
               cd[5] = {cam.k1, cam.k2, cam.p1, cam.p2, cam.k3};
  const double pi[4] = {proj.fx, proj.fy, proj.cx, proj.cy},
               pd[5] = {proj.k1, proj.k2, proj.p1, proj.p2, proj.k3};
  const auto extr = PoseToParams(cam_from_proj.inverse());
  double s = 0;
  int64_t n = 0;
  for (size_t i = 0; i < dense.size(); ++i) {
    const auto pose = PoseToParams(poses[i]);
    for (const auto& smp : dense[i]) {
      double r[2];
      DenseCost{smp.camera_px, smp.projector_px, 0.0, 0.0}(ci, cd, pi, pd, extr.data(), pose.data(),
                                                           r);
      s += r[0] * r[0] + r[1] * r[1];
      ++n;
    }
  }
  return n ? std::sqrt(s / static_cast<double>(n)) : 0.0;
}

}  // namespace

void MultiPlaneOptions::Check() const {
  D3D_CHECK_MSG(sample_step_px >= 1, "sample step must be ≥ 1 px");
  D3D_CHECK_MSG(modulation_fraction >= 0 && modulation_fraction < 1,
                "modulation fraction must be in [0, 1)");
  D3D_CHECK_MSG(edge_guard_px >= 0 && huber_px > 0 && max_iterations > 0, "bad refinement options");
}

std::vector<PlaneSample> SampleDensePlane(const ProjectorCoordinateMap& u_map,
                                          const ProjectorCoordinateMap& v_map,
                                          const MultiPlaneOptions& options) {
  options.Check();
  D3D_CHECK_MSG(u_map.coord_px.size() == v_map.coord_px.size(), "u and v maps must have one size");
  cv::Mat mod;
  cv::min(u_map.modulation, v_map.modulation, mod);
  std::vector<float> values;
  for (int r = 0; r < mod.rows; r += 2)
    for (int c = 0; c < mod.cols; c += 2) values.push_back(mod.at<float>(r, c));
  std::vector<PlaneSample> out;
  if (values.empty()) return out;
  std::nth_element(values.begin(),
                   values.begin() + static_cast<long>(0.9 * static_cast<double>(values.size() - 1)),
                   values.end());
  const double limit = options.modulation_fraction *
                       values[static_cast<size_t>(0.9 * static_cast<double>(values.size() - 1))];
  cv::Mat good = mod >= limit;
  good &= (u_map.coord_px == u_map.coord_px) & (v_map.coord_px == v_map.coord_px);  // not NaN
  if (options.edge_guard_px > 0) {
    const int k = 2 * static_cast<int>(std::ceil(options.edge_guard_px)) + 1;
    cv::erode(good, good, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(k, k)));
  }
  for (int r = options.sample_step_px / 2; r < mod.rows; r += options.sample_step_px)
    for (int c = options.sample_step_px / 2; c < mod.cols; c += options.sample_step_px) {
      if (!good.at<uint8_t>(r, c)) continue;
      out.push_back({Eigen::Vector2d(c, r), Eigen::Vector2d(u_map.coord_px.at<float>(r, c),
                                                            v_map.coord_px.at<float>(r, c))});
    }
  return out;
}

bool TriangulateColumn(const PinholeBrownConrady& camera, const PinholeBrownConrady& projector,
                       const Rigid3d& cam_from_proj, const Eigen::Vector2d& camera_px,
                       double projector_u, Eigen::Vector3d* p_in_cam) {
  const auto ray = camera.PixelRay(camera_px);
  if (!ray) return false;
  const Rigid3d proj_from_cam = cam_from_proj.inverse();
  auto g = [&](double z, double* value) {
    const auto uv = projector.Project(proj_from_cam * (z * *ray));
    if (!uv) return false;
    *value = uv->x() - projector_u;
    return true;
  };
  double z0 = 40.0, z1 = 60.0, g0 = 0, g1 = 0;
  if (!g(z0, &g0) || !g(z1, &g1)) return false;
  for (int it = 0; it < 40 && std::abs(g1) > 1e-10; ++it) {
    if (g1 == g0) return false;
    const double z2 = z1 - g1 * (z1 - z0) / (g1 - g0);
    z0 = z1;
    g0 = g1;
    z1 = z2;
    if (!(z1 > 0) || !g(z1, &g1)) return false;
  }
  if (std::abs(g1) > 1e-6) return false;
  *p_in_cam = z1 * *ray;
  return true;
}

std::vector<PlanarityFigures> MeasurePlanarity(const PinholeBrownConrady& camera,
                                               const PinholeBrownConrady& projector,
                                               const Rigid3d& cam_from_proj,
                                               const std::vector<Rigid3d>& cam_from_target,
                                               const std::vector<std::vector<PlaneSample>>& dense) {
  std::vector<PlanarityFigures> out(dense.size());
  for (size_t i = 0; i < dense.size(); ++i) {
    std::vector<Eigen::Vector3d> pts;
    for (const auto& s : dense[i]) {
      Eigen::Vector3d p;
      if (TriangulateColumn(camera, projector, cam_from_proj, s.camera_px, s.projector_px.x(), &p))
        pts.push_back(p);
    }
    PlanarityFigures& f = out[i];
    f.points = static_cast<int>(pts.size());
    if (pts.size() < 3) continue;
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto& p : pts) mean += p;
    mean /= static_cast<double>(pts.size());
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    for (const auto& p : pts) C += (p - mean) * (p - mean).transpose();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(C);
    const Eigen::Vector3d n = eig.eigenvectors().col(0);
    const Eigen::Vector3d nt = cam_from_target[i].linear().col(2);
    const Eigen::Vector3d t = cam_from_target[i].translation();
    double s1 = 0, s2 = 0;
    for (const auto& p : pts) {
      s1 += std::pow(n.dot(p - mean), 2);
      s2 += std::pow(nt.dot(p - t), 2);
    }
    f.fit_rms_um = 1000.0 * std::sqrt(s1 / static_cast<double>(pts.size()));
    f.target_rms_um = 1000.0 * std::sqrt(s2 / static_cast<double>(pts.size()));
  }
  return out;
}

MultiPlaneResult RefineMultiPlane(const std::vector<StereoView>& views,
                                  const std::vector<std::vector<PlaneSample>>& dense,
                                  const StereoCalibrationResult& start,
                                  const StereoCalibrationOptions& so_in,
                                  const MultiPlaneOptions& options) {
  options.Check();
  D3D_CHECK_MSG(views.size() == dense.size() && views.size() == start.cam_from_target.size(),
                "multi-plane refinement: views, dense samples and poses differ in number");
  MultiPlaneResult res;
  const auto& c = start.camera;
  const auto& p = start.projector;
  double ci[4] = {c.fx, c.fy, c.cx, c.cy}, cd[5] = {c.k1, c.k2, c.p1, c.p2, c.k3};
  double pi[4] = {p.fx, p.fy, p.cx, p.cy}, pd[5] = {p.k1, p.k2, p.p1, p.p2, p.k3};
  auto extr = PoseToParams(start.cam_from_proj.inverse());
  std::vector<std::array<double, 6>> poses;
  for (const auto& q : start.cam_from_target) poses.push_back(PoseToParams(q));
  const double ca = so_in.camera.fix_aspect_ratio ? so_in.camera.aspect_ratio : 0.0;
  const double pa = so_in.projector.fix_aspect_ratio ? so_in.projector.aspect_ratio : 0.0;
  res.before = MeasurePlanarity(c, p, start.cam_from_proj, start.cam_from_target, dense);
  res.dense_rms_before_px = DenseRms(c, p, start.cam_from_proj, start.cam_from_target, dense);

  ceres::Problem problem;
  for (size_t i = 0; i < views.size(); ++i) {
    const auto& v = views[i];
    for (size_t k = 0; k < v.object_points.size(); ++k) {
      problem.AddResidualBlock(
          new ceres::AutoDiffCostFunction<CameraFeatureCost, 2, 4, 5, 6>(new CameraFeatureCost{
              v.object_points[k], v.camera_px[k], so_in.camera.circle_radius_mm, ca}),
          nullptr, ci, cd, poses[i].data());
      if (!v.projector_valid[k]) continue;
      problem.AddResidualBlock(
          new ceres::AutoDiffCostFunction<ProjectorFeatureCost, 2, 4, 5, 6, 6>(
              new ProjectorFeatureCost{v.object_points[k], v.projector_px[k], pa}),
          nullptr, pi, pd, extr.data(), poses[i].data());
    }
    for (const auto& s : dense[i]) {
      problem.AddResidualBlock(new ceres::AutoDiffCostFunction<DenseCost, 2, 4, 5, 4, 5, 6, 6>(
                                   new DenseCost{s.camera_px, s.projector_px, ca, pa}),
                               new ceres::HuberLoss(options.huber_px), ci, cd, pi, pd, extr.data(),
                               poses[i].data());
      ++res.samples;
    }
  }
  SetFixedSubset(&problem, ci, 4, FixedIntrinsics(so_in.camera));
  SetFixedSubset(&problem, cd, 5, FixedDistortion(so_in.camera));
  SetFixedSubset(&problem, pi, 4, FixedIntrinsics(so_in.projector));
  SetFixedSubset(&problem, pd, 5, FixedDistortion(so_in.projector));
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_SCHUR;
  so.max_num_iterations = options.max_iterations;
  so.function_tolerance = 1e-12;
  so.parameter_tolerance = 1e-12;
  so.num_threads = 2;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  if (!summary.IsSolutionUsable()) {
    res.reason = "multi-plane refinement failed: " + summary.message;
    return res;
  }
  if (ca > 0) ci[1] = ca * ci[0];
  if (pa > 0) pi[1] = pa * pi[0];
  res.camera = {c.width, c.height, ci[0], ci[1], ci[2], ci[3], cd[0], cd[1], cd[2], cd[3], cd[4]};
  res.projector = {p.width, p.height, pi[0], pi[1], pi[2], pi[3],
                   pd[0],   pd[1],    pd[2], pd[3], pd[4]};
  res.cam_from_proj = ParamsToPose(extr.data()).inverse();
  for (const auto& q : poses) res.cam_from_target.push_back(ParamsToPose(q.data()));
  res.after =
      MeasurePlanarity(res.camera, res.projector, res.cam_from_proj, res.cam_from_target, dense);
  res.dense_rms_after_px =
      DenseRms(res.camera, res.projector, res.cam_from_proj, res.cam_from_target, dense);
  double cs = 0, ps = 0;
  int cn = 0, pn = 0;
  const Rigid3d proj_from_cam = res.cam_from_proj.inverse();
  for (size_t i = 0; i < views.size(); ++i)
    for (size_t k = 0; k < views[i].object_points.size(); ++k) {
      cs += (views[i].camera_px[k] - ProjectTargetFeature(res.camera, res.cam_from_target[i],
                                                          views[i].object_points[k],
                                                          so_in.camera.circle_radius_mm))
                .squaredNorm();
      ++cn;
      if (!views[i].projector_valid[k]) continue;
      ps += (views[i].projector_px[k] - ProjectTargetFeature(res.projector,
                                                             proj_from_cam * res.cam_from_target[i],
                                                             views[i].object_points[k], 0.0))
                .squaredNorm();
      ++pn;
    }
  res.camera_rms_px = std::sqrt(cs / std::max(1, cn));
  res.projector_rms_px = std::sqrt(ps / std::max(1, pn));
  auto pool = [](const std::vector<PlanarityFigures>& f, bool fit) {
    double s = 0;
    int64_t n = 0;
    for (const auto& x : f) {
      const double v = fit ? x.fit_rms_um : x.target_rms_um;
      s += v * v * x.points;
      n += x.points;
    }
    return n ? std::sqrt(s / static_cast<double>(n)) : 0.0;
  };
  res.plane_fit_rms_before_um = pool(res.before, true);
  res.plane_fit_rms_after_um = pool(res.after, true);
  res.target_plane_rms_before_um = pool(res.before, false);
  res.target_plane_rms_after_um = pool(res.after, false);
  try {
    res.camera.Check();
    res.projector.Check();
  } catch (const std::invalid_argument& e) {
    res.reason = std::string("multi-plane refinement gave an invalid device: ") + e.what();
    return res;
  }
  res.ok = true;
  return res;
}

}  // namespace d3d
