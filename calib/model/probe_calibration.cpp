#include "calib/model/probe_calibration.h"

#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

namespace d3d {
namespace {

using nlohmann::json;
constexpr int kFormatVersion = 1;
constexpr double kTwoPi = 2.0 * M_PI;

json CameraToJson(const PinholeBrownConrady& c) {
  return json{{"model", "pinhole-brown-conrady"},
              {"width", c.width},
              {"height", c.height},
              {"K", {{c.fx, 0.0, c.cx}, {0.0, c.fy, c.cy}, {0.0, 0.0, 1.0}}},
              {"distortion", {c.k1, c.k2, c.p1, c.p2, c.k3}}};
}

PinholeBrownConrady CameraFromJson(const json& j) {
  PinholeBrownConrady c;
  c.width = j.at("width").get<int>();
  c.height = j.at("height").get<int>();
  const auto& K = j.at("K");
  c.fx = K.at(0).at(0).get<double>();
  c.cx = K.at(0).at(2).get<double>();
  c.fy = K.at(1).at(1).get<double>();
  c.cy = K.at(1).at(2).get<double>();
  const auto& d = j.at("distortion");
  if (d.size() != 5) throw std::runtime_error("distortion must have 5 values (k1,k2,p1,p2,k3)");
  c.k1 = d.at(0).get<double>();
  c.k2 = d.at(1).get<double>();
  c.p1 = d.at(2).get<double>();
  c.p2 = d.at(3).get<double>();
  c.k3 = d.at(4).get<double>();
  return c;
}

json PatternToJson(const FringePatternSpec& p) {
  return json{{"name", p.name},
              {"axis", std::string(1, p.axis)},
              {"steps", p.steps},
              {"fringe_period_px", p.fringe_period_px},
              {"phase_origin_px", p.phase_origin_px},
              {"marker", {{"frame", p.marker_frame},
                          {"first_order", p.marker_first_order},
                          {"spacing_orders", p.marker_spacing_orders},
                          {"width_periods", p.marker_width_periods},
                          {"kind", "half-offset"}}},
              {"texture_frame", p.texture_frame}};
}

FringePatternSpec PatternFromJson(const json& j) {
  FringePatternSpec p;
  p.name = j.at("name").get<std::string>();
  const std::string axis = j.at("axis").get<std::string>();
  if (axis.size() != 1) throw std::runtime_error("pattern axis must be \"x\" or \"y\"");
  p.axis = axis[0];
  p.steps = j.at("steps").get<int>();
  p.fringe_period_px = j.at("fringe_period_px").get<double>();
  p.phase_origin_px = j.value("phase_origin_px", 0.0);
  const auto& m = j.at("marker");
  p.marker_frame = m.at("frame").get<int>();
  p.marker_first_order = m.at("first_order").get<int>();
  p.marker_spacing_orders = m.at("spacing_orders").get<int>();
  p.marker_width_periods = m.at("width_periods").get<double>();
  p.texture_frame = j.value("texture_frame", false);
  return p;
}

}  // namespace

void FringePatternSpec::Check() const {
  D3D_CHECK_MSG(axis == 'x' || axis == 'y', "pattern axis must be 'x' or 'y', got '" << axis << "'");
  D3D_CHECK_MSG(steps >= 3, "phase shift needs at least 3 steps, got " << steps);
  D3D_CHECK_MSG(fringe_period_px >= 2.0, "fringe period must be ≥ 2 projector px, got " << fringe_period_px);
  D3D_CHECK_MSG(marker_frame >= -1 && marker_frame < steps, "marker frame " << marker_frame << " not in [−1, steps)");
  D3D_CHECK_MSG(marker_spacing_orders >= 0, "marker spacing must be ≥ 0");
  D3D_CHECK_MSG(marker_width_periods > 0.0 && marker_width_periods <= 1.0, "marker width must be in (0, 1] periods");
}

double FringePatternSpec::AbsolutePhase(double coord_px) const {
  return kTwoPi * (coord_px - phase_origin_px) / fringe_period_px;
}

bool FringePatternSpec::InMarker(double coord_px) const {
  if (!HasMarker()) return false;
  const double turns = (coord_px - phase_origin_px) / fringe_period_px;  // Φ / 2π
  const double k = std::floor(turns);
  const double frac = turns - k;
  if (marker_width_periods < 1.0 && std::abs(frac - 0.5) >= 0.5 * marker_width_periods) return false;
  const long long order = static_cast<long long>(k) - marker_first_order;
  if (marker_spacing_orders == 0) return order == 0;
  return order >= 0 && order % marker_spacing_orders == 0;
}

double FringePatternSpec::PatternValue(int frame, double coord_px) const {
  const double delta = kTwoPi * frame / steps;
  double p = 0.5 + 0.5 * std::cos(AbsolutePhase(coord_px) - delta);
  if (frame == marker_frame && InMarker(coord_px)) p = p < 0.5 ? p + 0.5 : p - 0.5;
  return p;
}

void ProbeCalibration::Check() const {
  camera.Check();
  projector.Check();
  pattern.Check();
  const Eigen::Matrix3d R = cam_from_proj.rotation();
  D3D_CHECK_MSG((R * R.transpose() - Eigen::Matrix3d::Identity()).norm() < 1e-6 && R.determinant() > 0,
                "cam_from_proj rotation is not a proper rotation");
  D3D_CHECK_MSG(cam_from_proj.translation().norm() > 0.0, "camera and projector centres coincide (no baseline)");
  D3D_CHECK_MSG(projector_gamma > 0.1 && projector_gamma < 10.0, "projector gamma " << projector_gamma << " is implausible");
  D3D_CHECK_MSG(depth_min_mm > 0.0 && depth_max_mm > depth_min_mm,
                "measurement volume [" << depth_min_mm << ", " << depth_max_mm << "] mm is empty");
}

double ProbeCalibration::TriangulationAngleRad() const {
  const Eigen::Vector3d proj_axis = cam_from_proj.rotation().col(2);
  return std::acos(std::clamp(proj_axis.z(), -1.0, 1.0));
}

std::string ProbeCalibration::ToJson() const {
  const Eigen::Matrix3d R = cam_from_proj.rotation();
  const Eigen::Vector3d t = cam_from_proj.translation();
  json j{{"format", "d3dscan.calibration"},
         {"version", kFormatVersion},
         {"units", {{"length", "mm"}, {"angle", "rad"}, {"image", "px"}}},
         {"source", source},
         {"camera", CameraToJson(camera)},
         {"projector", CameraToJson(projector)},
         {"cam_from_proj",
          {{"R", {{R(0, 0), R(0, 1), R(0, 2)}, {R(1, 0), R(1, 1), R(1, 2)}, {R(2, 0), R(2, 1), R(2, 2)}}},
           {"t_mm", {t.x(), t.y(), t.z()}}}},
         {"projector_gamma", projector_gamma},
         {"measurement_volume", {{"depth_min_mm", depth_min_mm}, {"depth_max_mm", depth_max_mm}}},
         {"triangulation_angle_deg", TriangulationAngleRad() * 180.0 / M_PI},
         {"pattern", PatternToJson(pattern)}};
  return j.dump(2) + "\n";
}

Status ProbeCalibration::FromJson(const std::string& text, ProbeCalibration* out) {
  ProbeCalibration c;
  try {
    const json j = json::parse(text);
    if (j.value("format", "") != "d3dscan.calibration") return ParseError("calibration: not a d3dscan.calibration document");
    const int version = j.at("version").get<int>();
    if (version > kFormatVersion) {
      return Unsupported("calibration: format version " + std::to_string(version) + " is newer than " +
                         std::to_string(kFormatVersion));
    }
    c.source = j.value("source", "");
    c.camera = CameraFromJson(j.at("camera"));
    c.projector = CameraFromJson(j.at("projector"));
    const auto& e = j.at("cam_from_proj");
    Eigen::Matrix3d R;
    for (int r = 0; r < 3; ++r)
      for (int k = 0; k < 3; ++k) R(r, k) = e.at("R").at(r).at(k).get<double>();
    c.cam_from_proj = Rigid3d::Identity();
    c.cam_from_proj.linear() = R;
    c.cam_from_proj.translation() = Eigen::Vector3d(e.at("t_mm").at(0).get<double>(), e.at("t_mm").at(1).get<double>(),
                                                    e.at("t_mm").at(2).get<double>());
    c.projector_gamma = j.value("projector_gamma", 1.0);
    c.depth_min_mm = j.at("measurement_volume").at("depth_min_mm").get<double>();
    c.depth_max_mm = j.at("measurement_volume").at("depth_max_mm").get<double>();
    c.pattern = PatternFromJson(j.at("pattern"));
    c.Check();
  } catch (const json::exception& e) {
    return ParseError(std::string("calibration: ") + e.what());
  } catch (const std::exception& e) {
    return InvalidArgument(std::string("calibration: ") + e.what());
  }
  *out = std::move(c);
  return Status::Ok();
}

Status ProbeCalibration::Save(const std::string& path) const {
  std::ofstream f(path, std::ios::trunc);
  if (!f) return IoError("cannot write '" + path + "'");
  f << ToJson();
  if (!f) return IoError("write failed for '" + path + "'");
  return Status::Ok();
}

Status ProbeCalibration::Load(const std::string& path, ProbeCalibration* out) {
  std::ifstream f(path);
  if (!f) return NotFound("cannot open calibration '" + path + "'");
  std::stringstream ss;
  ss << f.rdbuf();
  return FromJson(ss.str(), out);
}

ProbeCalibration BinnedCalibration(const ProbeCalibration& calibration, int factor) {
  ProbeCalibration b = calibration;
  b.camera = BinnedCamera(calibration.camera, factor);
  return b;
}

}  // namespace d3d
