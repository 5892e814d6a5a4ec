#include "sim/patterns/patterns.h"

#include <cmath>
#include <sstream>

namespace d3d {
namespace {

int AxisLength(char axis, int w, int h) { return axis == 'y' ? h : w; }

uint8_t ToDmd(double p) {
  return static_cast<uint8_t>(std::lround(std::clamp(p, 0.0, 1.0) * 255.0));
}

std::vector<std::string> Split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string tok;
  while (std::getline(ss, tok, sep)) out.push_back(tok);
  return out;
}

bool ParseAxis(const std::vector<std::string>& parts, size_t index, char* axis) {
  if (parts.size() <= index) return true;
  if (parts[index] != "x" && parts[index] != "y") return false;
  *axis = parts[index][0];
  return true;
}

}  // namespace

cv::Mat ProjectorFrame::ToImage(int projector_width, int projector_height) const {
  cv::Mat img(projector_height, projector_width, CV_8U);
  for (int r = 0; r < projector_height; ++r) {
    auto* row = img.ptr<uint8_t>(r);
    for (int c = 0; c < projector_width; ++c)
      row[c] = axis == 'y' ? dmd[static_cast<size_t>(r)] : dmd[static_cast<size_t>(c)];
  }
  return img;
}

PatternSet MakePhaseShiftSet(const FringePatternSpec& spec, int projector_width,
                             int projector_height) {
  spec.Check();
  const int n = AxisLength(spec.axis, projector_width, projector_height);
  PatternSet set;
  set.id = spec.name;
  for (int f = 0; f < spec.steps; ++f) {
    ProjectorFrame frame{spec.name + "/" + std::to_string(f), spec.axis,
                         std::vector<uint8_t>(static_cast<size_t>(n))};
    for (int c = 0; c < n; ++c) frame.dmd[static_cast<size_t>(c)] = ToDmd(spec.PatternValue(f, c));
    set.frames.push_back(std::move(frame));
  }
  if (spec.texture_frame) {
    set.frames.push_back({"texture", spec.axis, std::vector<uint8_t>(static_cast<size_t>(n), 255)});
  }
  return set;
}

PatternSet MakeMultiFrequencySet(char axis, int steps, const std::vector<double>& periods_px,
                                 int projector_width, int projector_height) {
  D3D_CHECK_MSG(!periods_px.empty(), "multi-frequency set needs at least one period");
  PatternSet set;
  set.id = "multifreq";
  for (double period : periods_px) {
    FringePatternSpec spec;
    spec.name = "phase" + std::to_string(steps) + "-T" + std::to_string(period);
    spec.axis = axis;
    spec.steps = steps;
    spec.fringe_period_px = period;
    spec.marker_frame = -1;
    spec.texture_frame = false;
    PatternSet one = MakePhaseShiftSet(spec, projector_width, projector_height);
    for (auto& f : one.frames) set.frames.push_back(std::move(f));
  }
  return set;
}

PatternSet MakeGrayCodeSet(char axis, int cell_px, bool with_inverse, int projector_width,
                           int projector_height) {
  D3D_CHECK_MSG(axis == 'x' || axis == 'y', "axis must be x or y");
  D3D_CHECK_MSG(cell_px >= 1, "Gray code cell must be ≥ 1 px");
  const int n = AxisLength(axis, projector_width, projector_height);
  const int cells = (n + cell_px - 1) / cell_px;
  int bits = 0;
  while ((1 << bits) < cells) ++bits;
  PatternSet set;
  set.id = std::string("gray-") + axis;
  for (int b = bits - 1; b >= 0; --b) {
    for (int inverse = 0; inverse <= (with_inverse ? 1 : 0); ++inverse) {
      ProjectorFrame frame{set.id + "/" + std::to_string(bits - 1 - b) + (inverse ? "i" : ""), axis,
                           std::vector<uint8_t>(static_cast<size_t>(n))};
      for (int c = 0; c < n; ++c) {
        const int cell = c / cell_px;
        const int gray = cell ^ (cell >> 1);
        const bool on = ((gray >> b) & 1) != inverse;
        frame.dmd[static_cast<size_t>(c)] = on ? 255 : 0;
      }
      set.frames.push_back(std::move(frame));
    }
  }
  return set;
}

PatternSet MakeUniformSet(uint8_t level, int projector_width, int /*projector_height*/) {
  PatternSet set;
  set.id = level == 0 ? "black" : (level == 255 ? "white" : "uniform");
  set.frames.push_back(
      {set.id, 'x', std::vector<uint8_t>(static_cast<size_t>(projector_width), level)});
  return set;
}

Status ParsePatternSet(const std::string& text, const ProbeCalibration& calibration,
                       PatternSet* out) {
  const int w = calibration.projector.width, h = calibration.projector.height;
  const auto parts = Split(text, ':');
  if (parts.empty()) return InvalidArgument("empty pattern set");
  const std::string& kind = parts[0];
  try {
    if (kind == "burst" && parts.size() == 1) {
      *out = MakePhaseShiftSet(calibration.pattern, w, h);
    } else if (kind == "white" || kind == "black") {
      *out = MakeUniformSet(kind == "white" ? 255 : 0, w, h);
    } else if (kind == "phase" && (parts.size() == 3 || parts.size() == 4)) {
      FringePatternSpec spec;
      spec.steps = std::stoi(parts[1]);
      spec.fringe_period_px = std::stod(parts[2]);
      spec.marker_frame = -1;
      spec.texture_frame = false;
      spec.name = "phase" + parts[1];
      if (!ParseAxis(parts, 3, &spec.axis))
        return InvalidArgument("pattern axis must be x or y in '" + text + "'");
      *out = MakePhaseShiftSet(spec, w, h);
    } else if (kind == "multifreq" && (parts.size() == 3 || parts.size() == 4)) {
      std::vector<double> periods;
      for (const auto& p : Split(parts[2], ',')) periods.push_back(std::stod(p));
      char axis = 'x';
      if (!ParseAxis(parts, 3, &axis))
        return InvalidArgument("pattern axis must be x or y in '" + text + "'");
      *out = MakeMultiFrequencySet(axis, std::stoi(parts[1]), periods, w, h);
    } else if (kind == "gray" && (parts.size() == 2 || parts.size() == 3)) {
      char axis = 'x';
      if (!ParseAxis(parts, 2, &axis))
        return InvalidArgument("pattern axis must be x or y in '" + text + "'");
      *out = MakeGrayCodeSet(axis, std::stoi(parts[1]), true, w, h);
    } else {
      return InvalidArgument("unknown pattern set '" + text +
                             "' (burst | phase:N:PERIOD[:x|y] | multifreq:N:P1,P2[:x|y] | "
                             "gray:CELL[:x|y] | white | black)");
    }
  } catch (const std::invalid_argument& e) {
    return InvalidArgument("pattern set '" + text + "': " + e.what());
  } catch (const std::out_of_range& e) {
    return InvalidArgument("pattern set '" + text + "': number out of range");
  }
  return Status::Ok();
}

}  // namespace d3d
