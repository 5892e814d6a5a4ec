// d3d-calibrate: calibrates a probe's camera and projector from images of a planar target (the
// dissertation's method, calib/system) and writes calibration.json ("d3dscan.calibration" v1).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "calib/system/system_calibration.h"
#include "common/options/option_registry.h"

namespace {

namespace fs = std::filesystem;
using d3d::ImageReport;
using nlohmann::json;

json CameraJson(const d3d::PinholeBrownConrady& c) {
  return {{"width", c.width}, {"height", c.height}, {"fx", c.fx}, {"fy", c.fy},
          {"cx", c.cx},       {"cy", c.cy},         {"k1", c.k1}, {"k2", c.k2},
          {"p1", c.p1},       {"p2", c.p2},         {"k3", c.k3}};
}

json Vec(const Eigen::Vector2d& v) {
  if (!v.allFinite()) return nullptr;
  return {v.x(), v.y()};
}

// The image with the detected features and their residual vectors (scaled) drawn over it.
cv::Mat ResidualPicture(const cv::Mat& gray, const ImageReport& rep) {
  cv::Mat g8, bgr;
  if (gray.type() == CV_16U)
    gray.convertTo(g8, CV_8U, 1.0 / 257.0);
  else
    g8 = gray;
  cv::cvtColor(g8, bgr, cv::COLOR_GRAY2BGR);
  std::vector<double> mags;
  for (const auto& r : rep.camera_residuals_px) mags.push_back(r.norm());
  for (const auto& r : rep.projector_residuals_px)
    if (r.allFinite()) mags.push_back(r.norm());
  double p95 = 0;
  if (!mags.empty()) {
    std::sort(mags.begin(), mags.end());
    p95 = mags[static_cast<size_t>(0.95 * static_cast<double>(mags.size() - 1))];
  }
  const double scale = p95 > 0 ? std::min(2000.0, 20.0 / p95) : 1.0;
  for (size_t k = 0; k < rep.camera_px.size(); ++k) {
    const cv::Point2d p(rep.camera_px[k].x(), rep.camera_px[k].y());
    cv::circle(bgr, p, 3, cv::Scalar(0, 255, 255), 1, cv::LINE_AA);
    if (k < rep.camera_residuals_px.size()) {
      const auto& r = rep.camera_residuals_px[k];
      cv::arrowedLine(bgr, p, p + cv::Point2d(scale * r.x(), scale * r.y()), cv::Scalar(0, 0, 255),
                      1, cv::LINE_AA, 0, 0.2);
    }
    if (k < rep.projector_residuals_px.size() && rep.projector_residuals_px[k].allFinite()) {
      const auto& r = rep.projector_residuals_px[k];
      cv::arrowedLine(bgr, p, p + cv::Point2d(scale * r.x(), scale * r.y()),
                      cv::Scalar(255, 128, 0), 1, cv::LINE_AA, 0, 0.2);
    }
  }
  char text[200];
  std::snprintf(text, sizeof(text),
                "%s  camera %.3f px (red)  projector %.3f px (blue)  arrows x%.0f",
                rep.name.c_str(), rep.camera_rms_px, rep.projector_rms_px, scale);
  cv::putText(bgr, text, cv::Point(6, 16), cv::FONT_HERSHEY_SIMPLEX, 0.42, cv::Scalar(0, 0, 0), 3,
              cv::LINE_AA);
  cv::putText(bgr, text, cv::Point(6, 16), cv::FONT_HERSHEY_SIMPLEX, 0.42,
              cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
  return bgr;
}

// Everything the command line sets.
struct ToolOptions {
  std::string target_text, images_dir, phase_dir, out_path, report_dir;
  bool json_out = false, fix_aspect = false, no_refine = false, quiet = false, free_k3 = false;
  d3d::SystemCalibrationOptions calibration;
};

void DeclareOptions(d3d::OptionRegistry* options, ToolOptions* o) {
  d3d::SystemCalibrationOptions& opt = o->calibration;
  options
      ->Add("--target", &o->target_text,
            "chessboard:COLSxROWS:SQUARE_MM | "
            "circles:COLSxROWS:SPACING_MM[:asymmetric][:d=DIAM_MM] (inner corners or "
            "circles per row x rows; without d= the circle diameter is estimated)")
      .Required();
  options->Add("--images", &o->images_dir, "folder of white-light target images (sorted by name)")
      .Required();
  options->Add("--projector-phase", &o->phase_dir,
               "folder with phase.json and, per image stem, the phase frames along projector x and "
               "y (as written by "
               "d3d-sim --calibration-session): calibrates the projector and cam_from_proj too");
  options
      ->Add("--out", &o->out_path,
            "calibration.json to write (camera only without --projector-phase: a "
            "d3dscan.camera-calibration document)")
      .Required();
  options->Add("--report", &o->report_dir,
               "folder for the report: report.json, residuals_<image>.png, rejected.txt");
  options->Flag("--json", &o->json_out, "print one JSON summary object as the last line");
  options->Flag("--fix-aspect-ratio", &o->fix_aspect, "fy = fx (OpenCV's CALIB_FIX_ASPECT_RATIO)");
  options->Flag(
      "--free-k3", &o->free_k3,
      "estimate k3 (default: k3 = 0, as the probe's narrow fields cannot tell it from k1, k2; "
      "wide-angle lenses need it)");
  options->Add("--corner-window", &opt.features.corner_window_half_px,
               "chessboard corner refinement half window, px (default 5: 11x11; OpenCV's sample "
               "uses 11: 23x23)");
  options->Add("--corner-epsilon", &opt.features.corner_epsilon_px,
               "corner refinement stop, px (default 1e-4)");
  options->Add("--max-edge-blur", &opt.quality.max_edge_blur_px,
               "pre-treatment: reject above this edge blur, px (default 2.5)");
  options->Add("--max-noise", &opt.quality.max_noise_dn,
               "pre-treatment: reject above this noise, DN (default 6)");
  options->Add("--projector-gamma", &opt.projector_gamma,
               "projector gamma to write (not measured; default 1)");
  options->Flag("--no-global-refinement", &o->no_refine, "skip step 5 (multi-plane refinement)");
  options->Flag("--quiet", &o->quiet, "only errors and the JSON line");
}

// Per image: whether it was used (or why it was rejected), its quality and residuals.
json PerImageJson(const d3d::SystemCalibrationResult& r) {
  json per_image = json::array();
  for (const auto& im : r.images) {
    json j{{"image", im.name},
           {"used", im.used},
           {"rejected", im.rejected},
           {"edge_blur_px", im.quality.edge_blur_px},
           {"noise_dn", im.quality.noise_dn},
           {"contrast_dn", im.quality.contrast_dn},
           {"features", im.camera_px.size()},
           {"camera_rms_px", im.camera_rms_px}};
    if (r.has_projector) {
      j["projector_features"] = im.projector_features;
      j["projector_rms_px"] = im.projector_rms_px;
      j["plane_fit_rms_before_um"] = im.plane_rms_before_um;
      j["plane_fit_rms_after_um"] = im.plane_rms_after_um;
    }
    per_image.push_back(j);
  }
  return per_image;
}

// The projector's figures: its model, cam_from_proj, and the steps 4 and 5 that estimated them.
void AddProjectorSummary(const d3d::SystemCalibrationResult& r, bool global_refinement,
                         json* summary) {
  const auto& cal = r.calibration;
  const Eigen::Matrix3d R = cal.cam_from_proj.rotation();
  const Eigen::Vector3d t = cal.cam_from_proj.translation();
  const Eigen::AngleAxisd aa(R);
  json& s = *summary;
  s["proj_rms_px"] = r.projector_rms_px;
  s["projector"] = CameraJson(cal.projector);
  s["cam_from_proj"] = {
      {"R",
       {{R(0, 0), R(0, 1), R(0, 2)}, {R(1, 0), R(1, 1), R(1, 2)}, {R(2, 0), R(2, 1), R(2, 2)}}},
      {"t_mm", {t.x(), t.y(), t.z()}},
      {"angle_axis_rad",
       {aa.angle() * aa.axis().x(), aa.angle() * aa.axis().y(), aa.angle() * aa.axis().z()}},
      {"baseline_mm", t.norm()},
      {"triangulation_angle_deg", cal.TriangulationAngleRad() * 180.0 / M_PI}};
  s["step4_projector_only"] = {{"rms_px", r.stereo.projector_only.rms_px},
                               {"tsai_start_f_px", r.stereo.projector_only.initial.fx},
                               {"projector", CameraJson(r.stereo.projector_only.camera)}};
  s["step4_bundle_adjustment"] = {{"camera_rms_px", r.stereo.camera_rms_px},
                                  {"projector_rms_px", r.stereo.projector_rms_px},
                                  {"camera_sigma", r.stereo.camera_sigma},
                                  {"projector_sigma", r.stereo.projector_sigma},
                                  {"cam_from_proj_sigma", r.stereo.extrinsic_sigma},
                                  {"reciprocal_condition", r.stereo.reciprocal_condition}};
  if (global_refinement) {
    s["step5_multi_plane"] = {{"samples", r.refine.samples},
                              {"dense_rms_before_px", r.refine.dense_rms_before_px},
                              {"dense_rms_after_px", r.refine.dense_rms_after_px},
                              {"plane_fit_rms_before_um", r.refine.plane_fit_rms_before_um},
                              {"plane_fit_rms_after_um", r.refine.plane_fit_rms_after_um},
                              {"target_plane_rms_before_um", r.refine.target_plane_rms_before_um},
                              {"target_plane_rms_after_um", r.refine.target_plane_rms_after_um}};
  }
  s["depth_range_mm"] = {cal.depth_min_mm, cal.depth_max_mm};
}

// The summary printed with --json and the head of report.json (also for a failed calibration).
json Summary(const d3d::CalibrationTarget& target, size_t image_count,
             const d3d::SystemCalibrationResult& r, bool global_refinement) {
  json summary{{"ok", r.ok},
               {"target", target.ToString()},
               {"images", image_count},
               {"views_used", r.views_used}};
  if (!r.ok) summary["reason"] = r.reason;
  if (r.ok || r.camera.ok) {
    const auto& c = r.ok ? r.calibration.camera : r.camera.camera;
    summary["rms_px"] = r.camera_rms_px;
    summary["fx"] = c.fx;
    summary["fy"] = c.fy;
    summary["cx"] = c.cx;
    summary["cy"] = c.cy;
    summary["k1"] = c.k1;
    summary["k2"] = c.k2;
    summary["p1"] = c.p1;
    summary["p2"] = c.p2;
    summary["k3"] = c.k3;
    summary["step3_camera_only"] = {{"rms_px", r.camera.rms_px},
                                    {"tsai_start_f_px", r.camera.initial.fx},
                                    {"tsai_start_rms_px", r.camera.initial_rms_px},
                                    {"sigma", r.camera.sigma},
                                    {"reciprocal_condition", r.camera.reciprocal_condition},
                                    {"camera", CameraJson(r.camera.camera)}};
    if (target.IsCircles()) {
      summary["circle_diameter_mm"] = r.circle_diameter_mm;
      summary["circle_diameter_estimated"] = r.circle_diameter_estimated;
    }
  }
  if (r.has_projector) AddProjectorSummary(r, global_refinement, &summary);
  return summary;
}

// --report: report.json (summary, per image, every feature's residuals), residuals_<image>.png
// of the used images, rejected.txt. Returns false (after printing why) when the folder cannot be
// created.
bool WriteReport(const std::string& report_dir, const json& summary,
                 const d3d::SystemCalibrationResult& r,
                 const std::vector<d3d::CalibrationImage>& images) {
  std::error_code ec;
  fs::create_directories(report_dir, ec);
  if (ec) {
    std::fprintf(stderr, "d3d-calibrate: cannot create '%s': %s\n", report_dir.c_str(),
                 ec.message().c_str());
    return false;
  }
  json report = summary;
  report["per_image"] = PerImageJson(r);
  json residuals = json::array();
  for (size_t i = 0; i < r.images.size(); ++i) {
    const auto& im = r.images[i];
    json pts = json::array();
    for (size_t k = 0; k < im.camera_px.size(); ++k) {
      json p{{"camera_px", Vec(im.camera_px[k])}};
      if (k < im.camera_residuals_px.size())
        p["camera_residual_px"] = Vec(im.camera_residuals_px[k]);
      if (k < im.projector_px.size()) p["projector_px"] = Vec(im.projector_px[k]);
      if (k < im.projector_residuals_px.size())
        p["projector_residual_px"] = Vec(im.projector_residuals_px[k]);
      pts.push_back(p);
    }
    residuals.push_back({{"image", im.name}, {"features", pts}});
    if (im.used) {
      const std::string file =
          (fs::path(report_dir) / ("residuals_" + fs::path(im.name).stem().string() + ".png"))
              .string();
      if (!cv::imwrite(file, ResidualPicture(images[i].white, im)))
        std::fprintf(stderr, "d3d-calibrate: cannot write %s\n", file.c_str());
    }
  }
  report["residuals"] = residuals;
  std::ofstream(fs::path(report_dir) / "report.json") << report.dump(2) << "\n";
  std::ofstream rej(fs::path(report_dir) / "rejected.txt");
  for (const auto& im : r.images)
    if (!im.used) rej << im.name << ": " << im.rejected << "\n";
  return true;
}

// One line per image on stderr: used, quality, residuals, why rejected.
void PrintImageTable(const d3d::SystemCalibrationResult& r) {
  std::fprintf(stderr, "%-16s %6s %8s %8s %7s %9s %9s  %s\n", "image", "used", "blur_px", "noise",
               "cam_px", "proj_px", "plane_um", "rejected");
  for (const auto& im : r.images)
    std::fprintf(stderr, "%-16s %6s %8.2f %8.2f %7.3f %9.3f %4.1f>%4.1f  %s\n", im.name.c_str(),
                 im.used ? "yes" : "no", im.quality.edge_blur_px, im.quality.noise_dn,
                 im.camera_rms_px, im.projector_rms_px, im.plane_rms_before_um,
                 im.plane_rms_after_um, im.rejected.c_str());
}

// Writes the calibration to `out_path`: a probe calibration with the projector; camera only, a
// d3dscan.camera-calibration document (no projector, so not written as a probe calibration).
d3d::Status SaveCalibration(const d3d::SystemCalibrationResult& r, const std::string& out_path) {
  if (r.has_projector) return r.calibration.Save(out_path);
  const auto& c = r.calibration.camera;
  const json cam{{"format", "d3dscan.camera-calibration"},
                 {"version", 1},
                 {"source", "d3d-calibrate"},
                 {"units", {{"image", "px"}}},
                 {"camera",
                  {{"model", "pinhole-brown-conrady"},
                   {"width", c.width},
                   {"height", c.height},
                   {"K", {{c.fx, 0.0, c.cx}, {0.0, c.fy, c.cy}, {0.0, 0.0, 1.0}}},
                   {"distortion", {c.k1, c.k2, c.p1, c.p2, c.k3}}}},
                 {"rms_px", r.camera_rms_px},
                 {"views_used", r.views_used}};
  std::ofstream f(out_path);
  f << cam.dump(2) << "\n";
  return f ? d3d::Status::Ok() : d3d::IoError("cannot write '" + out_path + "'");
}

// The calibrated models on stderr, and where they were written.
void PrintResult(const d3d::SystemCalibrationResult& r, bool global_refinement,
                 const std::string& out_path) {
  const auto& c = r.calibration.camera;
  std::fprintf(stderr,
               "camera: fx %.3f fy %.3f cx %.3f cy %.3f k1 %.5f k2 %.5f p1 %.6f p2 %.6f k3 %.5f  "
               "rms %.4f px (%d views)\n",
               c.fx, c.fy, c.cx, c.cy, c.k1, c.k2, c.p1, c.p2, c.k3, r.camera_rms_px, r.views_used);
  if (r.has_projector) {
    const auto& p = r.calibration.projector;
    const Eigen::Vector3d t = r.calibration.cam_from_proj.translation();
    std::fprintf(stderr,
                 "projector: fx %.3f fy %.3f cx %.3f cy %.3f  rms %.4f px; cam_from_proj t (%.4f, "
                 "%.4f, %.4f) mm, angle %.3f deg\n",
                 p.fx, p.fy, p.cx, p.cy, r.projector_rms_px, t.x(), t.y(), t.z(),
                 r.calibration.TriangulationAngleRad() * 180 / M_PI);
    if (global_refinement)
      std::fprintf(stderr,
                   "multi-plane refinement: plane fit %.2f -> %.2f um, target plane %.2f -> %.2f "
                   "um (%d samples)\n",
                   r.refine.plane_fit_rms_before_um, r.refine.plane_fit_rms_after_um,
                   r.refine.target_plane_rms_before_um, r.refine.target_plane_rms_after_um,
                   r.refine.samples);
  }
  std::fprintf(stderr, "d3d-calibrate: wrote %s\n", out_path.c_str());
}

}  // namespace

int main(int argc, char** argv) {
  d3d::OptionRegistry options(
      "d3d-calibrate: calibrates the probe's camera (and, with phase images, its projector and "
      "cam_from_proj) "
      "from images of a planar target: pre-treatment, target features (chessboard corners or "
      "moment-based "
      "circle centres), Tsai's radial alignment constraint + nonlinear refinement, the projector "
      "as an inverse "
      "camera, bundle adjustment, global multi-plane refinement. Writes calibration.json "
      "(d3dscan.calibration v1).");
  ToolOptions o;
  DeclareOptions(&options, &o);
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;

  d3d::CalibrationTarget target;
  if (const d3d::Status s = d3d::ParseTarget(o.target_text, &target); !s.ok()) {
    std::fprintf(stderr, "d3d-calibrate: %s\n", s.message().c_str());
    return 2;
  }
  d3d::SystemCalibrationOptions& opt = o.calibration;
  opt.camera.fix_aspect_ratio = o.fix_aspect;
  opt.camera.fix_k3 = !o.free_k3;
  opt.projector.fix_k3 = !o.free_k3;
  opt.global_refinement = !o.no_refine;
  std::vector<d3d::CalibrationImage> images;
  if (const d3d::Status s = d3d::LoadCalibrationImages(o.images_dir, o.phase_dir, &images, &opt);
      !s.ok()) {
    std::fprintf(stderr, "d3d-calibrate: %s\n", s.ToString().c_str());
    if (o.json_out)
      std::printf("%s\n", json{{"ok", false}, {"reason", s.message()}}.dump().c_str());
    return 1;
  }
  if (!o.quiet)
    std::fprintf(stderr, "d3d-calibrate: %zu images%s, target %s\n", images.size(),
                 o.phase_dir.empty() ? "" : " with phase sets", target.ToString().c_str());
  d3d::SystemCalibrationResult r;
  try {
    r = d3d::CalibrateSystem(target, images, opt);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-calibrate: %s\n", e.what());
    return 2;
  }

  // The report (also for a failed calibration: which images were rejected and why).
  const json summary = Summary(target, images.size(), r, opt.global_refinement);
  if (!o.report_dir.empty() && !WriteReport(o.report_dir, summary, r, images)) return 1;
  if (!o.quiet) PrintImageTable(r);
  if (!r.ok) {
    std::fprintf(stderr, "d3d-calibrate: calibration failed: %s\n", r.reason.c_str());
    if (o.json_out) std::printf("%s\n", summary.dump().c_str());
    return 1;
  }
  if (const d3d::Status saved = SaveCalibration(r, o.out_path); !saved.ok()) {
    std::fprintf(stderr, "d3d-calibrate: %s\n", saved.ToString().c_str());
    return 1;
  }
  if (!o.quiet) PrintResult(r, opt.global_refinement, o.out_path);
  if (o.json_out) std::printf("%s\n", summary.dump().c_str());
  return 0;
}
