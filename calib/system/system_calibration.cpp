#include "calib/system/system_calibration.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

namespace d3d {
namespace {

namespace fs = std::filesystem;
const Eigen::Vector2d kNaN2(std::numeric_limits<double>::quiet_NaN(),
                            std::numeric_limits<double>::quiet_NaN());

double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// |det J| of the target-plane → image map at X (px² per mm²), by central differences.
double AreaScale(const PinholeBrownConrady& cam, const Rigid3d& pose, const Eigen::Vector3d& X) {
  const double h = 1e-3;
  const Eigen::Vector2d du = (ProjectTargetFeature(cam, pose, X + Eigen::Vector3d(h, 0, 0), 0) -
                              ProjectTargetFeature(cam, pose, X - Eigen::Vector3d(h, 0, 0), 0)) /
                             (2 * h);
  const Eigen::Vector2d dv = (ProjectTargetFeature(cam, pose, X + Eigen::Vector3d(0, h, 0), 0) -
                              ProjectTargetFeature(cam, pose, X - Eigen::Vector3d(0, h, 0), 0)) /
                             (2 * h);
  return std::abs(du.x() * dv.y() - du.y() * dv.x());
}

}  // namespace

SystemCalibrationOptions::SystemCalibrationOptions() {
  // The probe's fields are narrow (±9° camera, ±15° projector): k3 cannot be told from k1, k2.
  camera.fix_k3 = true;
  projector.fix_k3 = true;
  mapping.window_radius_px = 0.0;
}

void SystemCalibrationOptions::Check() const {
  quality.Check();
  features.Check();
  camera.Check();
  projector.Check();
  phase.Check();
  FeatureMappingOptions m = mapping;
  if (m.window_radius_px <= 0) m.window_radius_px = 10;
  m.Check();
  refine.Check();
  D3D_CHECK_MSG(projector_gamma > 0.1 && projector_gamma < 10, "projector gamma out of range");
  D3D_CHECK_MSG(depth_margin_mm >= 0 && min_projector_features >= 6,
                "bad depth margin or projector feature minimum");
}

SystemCalibrationResult CalibrateSystem(const CalibrationTarget& target,
                                        const std::vector<CalibrationImage>& images,
                                        const SystemCalibrationOptions& options) {
  target.Check();
  options.Check();
  SystemCalibrationResult res;
  std::ostringstream why;
  if (images.empty()) {
    res.reason = "no calibration images";
    return res;
  }
  // Images of different sizes: name them.
  const cv::Size size = images[0].white.size();
  for (const auto& im : images) {
    if (im.white.size() != size) {
      why << "images of different sizes: '" << images[0].name << "' is " << size.width << "x"
          << size.height << ", '" << im.name << "' is " << im.white.cols << "x" << im.white.rows;
      res.reason = why.str();
      return res;
    }
  }
  const bool with_phase = std::any_of(images.begin(), images.end(),
                                      [](const CalibrationImage& i) { return !i.phase_x.empty(); });
  if (with_phase && (options.projector_width <= 0 || options.projector_height <= 0)) {
    res.reason = "phase sets given but the projector size is unknown";
    return res;
  }
  // Steps 1 and 2.
  std::vector<size_t> used;
  std::vector<DetectedFeatures> feats(images.size());
  int not_found = 0;
  for (size_t i = 0; i < images.size(); ++i) {
    ImageReport rep;
    rep.name = images[i].name;
    rep.quality = AssessImage(images[i].white, options.quality);
    if (!rep.quality.accepted) {
      rep.rejected = "pre-treatment: " + rep.quality.reason;
    } else {
      feats[i] = DetectTarget(images[i].white, target, options.features);
      if (!feats[i].found) {
        rep.rejected = "features: " + feats[i].reason;
        ++not_found;
      } else {
        rep.camera_px = feats[i].points_px;
        rep.used = true;
        used.push_back(i);
      }
    }
    res.images.push_back(rep);
  }
  if (used.size() < static_cast<size_t>(options.camera.min_views)) {
    why << "too few usable views: " << used.size() << " of " << images.size() << " (need "
        << options.camera.min_views << ")";
    if (not_found == static_cast<int>(images.size())) {
      why << "; target " << target.ToString()
          << " not found in any image (wrong target size or kind?)";
    } else {
      for (const auto& r : res.images)
        if (!r.used) why << "; " << r.name << ": " << r.rejected;
    }
    res.reason = why.str();
    return res;
  }
  // Step 3: the camera (point model first when the circle diameter must be estimated).
  std::vector<TargetView> views;
  for (size_t i : used)
    views.push_back({images[i].name, target.FeaturePoints(), feats[i].points_px});
  CameraCalibrationOptions co = options.camera;
  res.circle_diameter_mm = target.circle_diameter_mm;
  if (target.IsCircles() && res.circle_diameter_mm <= 0) {
    co.circle_radius_mm = 0.0;
    const CameraCalibrationResult first = CalibrateCamera(views, size.width, size.height, co);
    if (!first.ok) {
      res.reason = "camera: " + first.reason;
      return res;
    }
    std::vector<double> d;
    for (size_t v = 0; v < used.size(); ++v) {
      const auto& areas = feats[used[v]].blob_area_px;
      for (size_t k = 0; k < areas.size(); ++k) {
        const double s =
            AreaScale(first.camera, first.views[v].device_from_target, views[v].object_points[k]);
        if (s > 0) d.push_back(2.0 * std::sqrt(areas[k] / (M_PI * s)));
      }
    }
    res.circle_diameter_mm = Median(d);
    res.circle_diameter_estimated = true;
  }
  co.circle_radius_mm = target.IsCircles() ? 0.5 * res.circle_diameter_mm : 0.0;
  res.camera = CalibrateCamera(views, size.width, size.height, co);
  if (!res.camera.ok) {
    res.reason = "camera: " + res.camera.reason;
    return res;
  }
  res.views_used = static_cast<int>(used.size());
  res.calibration.camera = res.camera.camera;
  res.calibration.source = "d3d-calibrate";
  res.calibration.projector_gamma = options.projector_gamma;
  res.camera_rms_px = res.camera.rms_px;
  for (size_t v = 0; v < used.size(); ++v) {
    auto& rep = res.images[used[v]];
    rep.camera_residuals_px = res.camera.views[v].residuals_px;
    rep.camera_rms_px = res.camera.views[v].rms_px;
  }
  std::vector<Rigid3d> final_poses;
  for (const auto& v : res.camera.views) final_poses.push_back(v.device_from_target);

  if (with_phase) {
    // Step 4: projector features from the absolute phase along both axes.
    std::vector<StereoView> sviews;
    std::vector<std::vector<PlaneSample>> dense;
    std::vector<size_t> stereo_index;  // into `used`
    for (size_t v = 0; v < used.size(); ++v) {
      const CalibrationImage& im = images[used[v]];
      ImageReport& rep = res.images[used[v]];
      if (im.phase_x.empty() || im.phase_y.empty()) {
        rep.projector_px.assign(rep.camera_px.size(), kNaN2);
        continue;
      }
      ProjectorCoordinateMap umap, vmap;
      Status s = DecodeProjectorCoordinate(im.phase_x, options.phase, &umap);
      if (s.ok()) s = DecodeProjectorCoordinate(im.phase_y, options.phase, &vmap);
      if (!s.ok()) {
        res.reason = "view '" + im.name + "': " + s.message();
        return res;
      }
      const Rigid3d& pose = res.camera.views[v].device_from_target;
      const double r = co.circle_radius_mm;
      std::vector<Eigen::Vector2d>
          corrected;  // images of the circles' centres (perspective bias removed)
      std::vector<double> spacing;
      for (size_t k = 0; k < views[v].object_points.size(); ++k) {
        const Eigen::Vector3d& X = views[v].object_points[k];
        const Eigen::Vector2d bias = ProjectTargetFeature(res.camera.camera, pose, X, r) -
                                     ProjectTargetFeature(res.camera.camera, pose, X, 0.0);
        corrected.push_back(views[v].image_points[k] - bias);
        if (k + 1 < views[v].object_points.size())
          spacing.push_back((views[v].image_points[k + 1] - views[v].image_points[k]).norm());
      }
      FeatureMappingOptions mo = options.mapping;
      if (mo.window_radius_px <= 0)
        mo.window_radius_px = std::max(
            8.0, 0.8 * Median(spacing) * target.NearestFeatureDistanceMm() / target.spacing_mm);
      const auto mapped = MapFeaturesToProjector(umap, vmap, corrected, mo);
      StereoView sv{im.name, views[v].object_points, views[v].image_points, {}, {}};
      for (const auto& m : mapped) {
        sv.projector_px.push_back(m.ok ? m.projector_px : kNaN2);
        sv.projector_valid.push_back(m.ok ? 1 : 0);
        rep.projector_features += m.ok ? 1 : 0;
      }
      rep.projector_px = sv.projector_px;
      if (rep.projector_features < options.min_projector_features) continue;
      sviews.push_back(sv);
      stereo_index.push_back(v);
      dense.push_back(SampleDensePlane(umap, vmap, options.refine));
    }
    if (sviews.size() < static_cast<size_t>(options.projector.min_views)) {
      why << "too few views with projector features: " << sviews.size() << " (need "
          << options.projector.min_views << ")";
      res.reason = why.str();
      return res;
    }
    StereoCalibrationOptions so;
    so.camera = co;
    so.projector = options.projector;
    res.stereo = CalibrateStereo(sviews, size.width, size.height, options.projector_width,
                                 options.projector_height, so);
    if (!res.stereo.ok) {
      res.reason = "stereo: " + res.stereo.reason;
      return res;
    }
    res.has_projector = true;
    PinholeBrownConrady cam = res.stereo.camera, proj = res.stereo.projector;
    Rigid3d cam_from_proj = res.stereo.cam_from_proj;
    std::vector<Rigid3d> poses = res.stereo.cam_from_target;
    // Step 5.
    if (options.global_refinement) {
      res.refine = RefineMultiPlane(sviews, dense, res.stereo, so, options.refine);
      if (!res.refine.ok) {
        res.reason = "global refinement: " + res.refine.reason;
        return res;
      }
      cam = res.refine.camera;
      proj = res.refine.projector;
      cam_from_proj = res.refine.cam_from_proj;
      poses = res.refine.cam_from_target;
    } else {
      res.refine.before = MeasurePlanarity(cam, proj, cam_from_proj, poses, dense);
    }
    res.calibration.camera = cam;
    res.calibration.projector = proj;
    res.calibration.cam_from_proj = cam_from_proj;
    // Residuals of the final calibration, per image.
    double cs = 0, ps = 0;
    int cn = 0, pn = 0;
    const Rigid3d proj_from_cam = cam_from_proj.inverse();
    for (size_t s = 0; s < sviews.size(); ++s) {
      ImageReport& rep = res.images[used[stereo_index[s]]];
      rep.camera_residuals_px.clear();
      rep.projector_residuals_px.clear();
      double vc = 0, vp = 0;
      int np = 0;
      for (size_t k = 0; k < sviews[s].object_points.size(); ++k) {
        const Eigen::Vector3d& X = sviews[s].object_points[k];
        rep.camera_residuals_px.push_back(
            sviews[s].camera_px[k] - ProjectTargetFeature(cam, poses[s], X, co.circle_radius_mm));
        vc += rep.camera_residuals_px.back().squaredNorm();
        if (!sviews[s].projector_valid[k]) {
          rep.projector_residuals_px.push_back(kNaN2);
          continue;
        }
        rep.projector_residuals_px.push_back(
            sviews[s].projector_px[k] -
            ProjectTargetFeature(proj, proj_from_cam * poses[s], X, 0.0));
        vp += rep.projector_residuals_px.back().squaredNorm();
        ++np;
      }
      rep.camera_rms_px = std::sqrt(vc / static_cast<double>(sviews[s].object_points.size()));
      rep.projector_rms_px = std::sqrt(vp / std::max(1, np));
      cs += vc;
      cn += static_cast<int>(sviews[s].object_points.size());
      ps += vp;
      pn += np;
      if (s < res.refine.before.size()) rep.plane_rms_before_um = res.refine.before[s].fit_rms_um;
      if (s < res.refine.after.size()) rep.plane_rms_after_um = res.refine.after[s].fit_rms_um;
    }
    res.camera_rms_px = std::sqrt(cs / std::max(1, cn));
    res.projector_rms_px = std::sqrt(ps / std::max(1, pn));
    res.views_used = static_cast<int>(sviews.size());
    final_poses = poses;
  }
  // Measurement volume: the depths at which the target was seen, with a margin.
  double zmin = 1e30, zmax = -1e30;
  for (size_t v = 0; v < final_poses.size(); ++v)
    for (const auto& X : target.FeaturePoints()) {
      const double z = (final_poses[v] * X).z();
      zmin = std::min(zmin, z);
      zmax = std::max(zmax, z);
    }
  res.calibration.depth_min_mm = std::max(1e-3, zmin - options.depth_margin_mm);
  res.calibration.depth_max_mm = zmax + options.depth_margin_mm;
  if (!res.has_projector) {  // camera only: no probe calibration to check (the projector is
                             // unknown)
    res.ok = true;
    return res;
  }
  try {
    res.calibration.Check();
  } catch (const std::invalid_argument& e) {
    res.reason = std::string("calibration is invalid: ") + e.what();
    return res;
  }
  res.ok = true;
  return res;
}

Status LoadCalibrationImages(const std::string& images_dir, const std::string& phase_dir,
                             std::vector<CalibrationImage>* out,
                             SystemCalibrationOptions* options) {
  out->clear();
  if (!fs::is_directory(images_dir))
    return NotFound("images folder '" + images_dir + "' not found");
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(images_dir)) {
    std::string ext = e.path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (e.is_regular_file() && (ext == ".png" || ext == ".jpg" || ext == ".jpeg" || ext == ".bmp" ||
                                ext == ".tif" || ext == ".tiff"))
      files.push_back(e.path());
  }
  std::sort(files.begin(), files.end());
  if (files.empty()) return NotFound("no images (png, jpg, bmp, tif) in '" + images_dir + "'");
  nlohmann::json phase;
  if (!phase_dir.empty()) {
    std::ifstream f(fs::path(phase_dir) / "phase.json");
    if (!f) return NotFound("'" + (fs::path(phase_dir) / "phase.json").string() + "' not found");
    try {
      f >> phase;
      options->phase.steps = phase.at("steps").get<int>();
      options->phase.periods_px = phase.at("periods_px").get<std::vector<double>>();
      options->projector_width = phase.at("projector_width").get<int>();
      options->projector_height = phase.at("projector_height").get<int>();
      options->phase.Check();
    } catch (const std::exception& e) {
      return ParseError("phase.json: " + std::string(e.what()));
    }
  }
  for (const auto& path : files) {
    CalibrationImage im;
    im.name = path.filename().string();
    im.white = cv::imread(path.string(), cv::IMREAD_ANYDEPTH | cv::IMREAD_GRAYSCALE);
    if (im.white.empty()) return ParseError("cannot read image '" + path.string() + "'");
    if (!phase_dir.empty()) {
      const fs::path dir = fs::path(phase_dir) / path.stem();
      if (!fs::is_directory(dir))
        return NotFound("phase frames of '" + im.name + "' not found: no folder '" + dir.string() +
                        "'");
      for (const char axis : {'x', 'y'}) {
        auto& frames = axis == 'x' ? im.phase_x : im.phase_y;
        for (size_t p = 0; p < options->phase.periods_px.size(); ++p)
          for (int s = 0; s < options->phase.steps; ++s) {
            const fs::path file = dir / (std::string(1, axis) + "_" + std::to_string(p) + "_" +
                                         std::to_string(s) + ".png");
            cv::Mat f = cv::imread(file.string(), cv::IMREAD_ANYDEPTH | cv::IMREAD_GRAYSCALE);
            if (f.empty())
              return NotFound("phase frame '" + file.string() + "' missing or unreadable");
            if (f.size() != im.white.size())
              return InvalidArgument("phase frame '" + file.string() +
                                     "' differs in size from its image");
            frames.push_back(f);
          }
      }
    }
    out->push_back(std::move(im));
  }
  return Status::Ok();
}

}  // namespace d3d
