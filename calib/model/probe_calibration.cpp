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

// A field of the calibration document, read with its path in every error: "camera.K[0][2] is
// missing", "pattern.steps must be a whole number" (never the JSON library's own text).
struct FieldError : std::runtime_error {
  using std::runtime_error::runtime_error;
};
struct Field {
  const json& j;
  std::string path;
  Field At(const std::string& key) const {
    const std::string p = path.empty() ? key : path + "." + key;
    if (!j.is_object() || !j.contains(key)) throw FieldError(p + " is missing");
    return {j.at(key), p};
  }
  Field At(size_t i) const {
    const std::string p = path + "[" + std::to_string(i) + "]";
    if (!j.is_array() || i >= j.size()) throw FieldError(p + " is missing");
    return {j.at(i), p};
  }
  bool Has(const std::string& key) const { return j.is_object() && j.contains(key); }
  size_t Size() const {
    if (!j.is_array()) throw FieldError(path + " must be a list");
    return j.size();
  }
  double Number() const {
    if (!j.is_number()) throw FieldError(path + " must be a number");
    return j.get<double>();
  }
  int Integer() const {
    if (!j.is_number_integer()) throw FieldError(path + " must be a whole number");
    return j.get<int>();
  }
  bool Flag() const {
    if (!j.is_boolean()) throw FieldError(path + " must be true or false");
    return j.get<bool>();
  }
  std::string Text() const {
    if (!j.is_string()) throw FieldError(path + " must be a string");
    return j.get<std::string>();
  }
};

PinholeBrownConrady CameraFromJson(const Field& j) {
  PinholeBrownConrady c;
  c.width = j.At("width").Integer();
  c.height = j.At("height").Integer();
  const Field K = j.At("K");
  c.fx = K.At(0).At(0).Number();
  c.cx = K.At(0).At(2).Number();
  c.fy = K.At(1).At(1).Number();
  c.cy = K.At(1).At(2).Number();
  const Field d = j.At("distortion");
  if (d.Size() != 5) throw FieldError(d.path + " must have 5 values (k1, k2, p1, p2, k3)");
  c.k1 = d.At(0).Number();
  c.k2 = d.At(1).Number();
  c.p1 = d.At(2).Number();
  c.p2 = d.At(3).Number();
  c.k3 = d.At(4).Number();
  return c;
}

json PatternToJson(const FringePatternSpec& p) {
  return json{{"name", p.name},
              {"axis", std::string(1, p.axis)},
              {"steps", p.steps},
              {"fringe_period_px", p.fringe_period_px},
              {"phase_origin_px", p.phase_origin_px},
              {"marker",
               {{"frame", p.marker_frame},
                {"first_order", p.marker_first_order},
                {"spacing_orders", p.marker_spacing_orders},
                {"width_periods", p.marker_width_periods},
                {"kind", "half-offset"}}},
              {"texture_frame", p.texture_frame}};
}

FringePatternSpec PatternFromJson(const Field& j) {
  FringePatternSpec p;
  p.name = j.At("name").Text();
  const std::string axis = j.At("axis").Text();
  if (axis != "x" && axis != "y") throw FieldError(j.path + ".axis must be \"x\" or \"y\"");
  p.axis = axis[0];
  p.steps = j.At("steps").Integer();
  p.fringe_period_px = j.At("fringe_period_px").Number();
  p.phase_origin_px = j.Has("phase_origin_px") ? j.At("phase_origin_px").Number() : 0.0;
  const Field m = j.At("marker");
  p.marker_frame = m.At("frame").Integer();
  p.marker_first_order = m.At("first_order").Integer();
  p.marker_spacing_orders = m.At("spacing_orders").Integer();
  p.marker_width_periods = m.At("width_periods").Number();
  p.texture_frame = j.Has("texture_frame") && j.At("texture_frame").Flag();
  return p;
}

}  // namespace

void FringePatternSpec::Check() const {
  D3D_CHECK_MSG(axis == 'x' || axis == 'y',
                "pattern axis must be 'x' or 'y', got '" << axis << "'");
  D3D_CHECK_MSG(steps >= 3, "phase shift needs at least 3 steps, got " << steps);
  D3D_CHECK_MSG(fringe_period_px >= 2.0,
                "fringe period must be ≥ 2 projector px, got " << fringe_period_px);
  D3D_CHECK_MSG(marker_frame >= -1 && marker_frame < steps,
                "marker frame " << marker_frame << " not in [−1, steps)");
  D3D_CHECK_MSG(marker_spacing_orders >= 0, "marker spacing must be ≥ 0");
  D3D_CHECK_MSG(marker_width_periods > 0.0 && marker_width_periods <= 1.0,
                "marker width must be in (0, 1] periods");
}

double FringePatternSpec::AbsolutePhase(double coord_px) const {
  return kTwoPi * (coord_px - phase_origin_px) / fringe_period_px;
}

bool FringePatternSpec::InMarker(double coord_px) const {
  if (!HasMarker()) return false;
  const double turns = (coord_px - phase_origin_px) / fringe_period_px;  // Φ / 2π
  const double k = std::floor(turns);
  const double frac = turns - k;
  if (marker_width_periods < 1.0 && std::abs(frac - 0.5) >= 0.5 * marker_width_periods)
    return false;
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
  D3D_CHECK_MSG(
      (R * R.transpose() - Eigen::Matrix3d::Identity()).norm() < 1e-6 && R.determinant() > 0,
      "cam_from_proj rotation is not a proper rotation");
  D3D_CHECK_MSG(cam_from_proj.translation().norm() > 0.0,
                "camera and projector centres coincide (no baseline)");
  D3D_CHECK_MSG(projector_gamma > 0.1 && projector_gamma < 10.0,
                "projector gamma " << projector_gamma << " is implausible");
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
  json j{
      {"format", "d3dscan.calibration"},
      {"version", kFormatVersion},
      {"units", {{"length", "mm"}, {"angle", "rad"}, {"image", "px"}}},
      {"source", source},
      {"camera", CameraToJson(camera)},
      {"projector", CameraToJson(projector)},
      {"cam_from_proj",
       {{"R",
         {{R(0, 0), R(0, 1), R(0, 2)}, {R(1, 0), R(1, 1), R(1, 2)}, {R(2, 0), R(2, 1), R(2, 2)}}},
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
    const json doc = json::parse(text);
    const Field j{doc, ""};
    if (!j.Has("format") || !j.At("format").j.is_string() ||
        j.At("format").Text() != "d3dscan.calibration")
      return ParseError("calibration: not a d3dscan.calibration document (format)");
    const int version = j.At("version").Integer();
    if (version > kFormatVersion) {
      return Unsupported("calibration: format version " + std::to_string(version) +
                         " is newer than " + std::to_string(kFormatVersion));
    }
    // Lengths are read as millimetres: a document in other units is refused, not misread.
    if (j.Has("units") && j.At("units").Has("length") && j.At("units").At("length").Text() != "mm")
      return ParseError("calibration: units.length is '" + j.At("units").At("length").Text() +
                        "'; only mm is read");
    c.source = j.Has("source") ? j.At("source").Text() : "";
    c.camera = CameraFromJson(j.At("camera"));
    c.projector = CameraFromJson(j.At("projector"));
    const Field e = j.At("cam_from_proj");
    Eigen::Matrix3d R;
    for (size_t r = 0; r < 3; ++r)
      for (size_t k = 0; k < 3; ++k)
        R(static_cast<int>(r), static_cast<int>(k)) = e.At("R").At(r).At(k).Number();
    c.cam_from_proj = Rigid3d::Identity();
    c.cam_from_proj.linear() = R;
    c.cam_from_proj.translation() = Eigen::Vector3d(
        e.At("t_mm").At(0).Number(), e.At("t_mm").At(1).Number(), e.At("t_mm").At(2).Number());
    // Required: a missing gamma read as 1 (linear) gave wrong phases and no point, silently.
    c.projector_gamma = j.At("projector_gamma").Number();
    c.depth_min_mm = j.At("measurement_volume").At("depth_min_mm").Number();
    c.depth_max_mm = j.At("measurement_volume").At("depth_max_mm").Number();
    c.pattern = PatternFromJson(j.At("pattern"));
    c.Check();
  } catch (const FieldError& e) {
    return ParseError(std::string("calibration: ") + e.what());
  } catch (const json::parse_error& e) {
    return ParseError("calibration: not valid JSON (at byte " + std::to_string(e.byte) + ")");
  } catch (const json::exception&) {
    return ParseError("calibration: not valid JSON");
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
