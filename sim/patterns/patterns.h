// Projector pattern sets: what the probe's DMD displays, frame by frame. Every pattern here varies
// along one projector axis only (fringes, marker stripes, Gray codes, uniform frames), so a frame
// is stored as one 8-bit DMD value per projector column (axis 'x') or row (axis 'y').
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "calib/model/probe_calibration.h"
#include "common/core/status.h"

namespace d3d {

struct ProjectorFrame {
  std::string name;          // e.g. "phase4-marker/3", "gray-x/2", "white"
  char axis = 'x';           // the axis the values vary along
  std::vector<uint8_t> dmd;  // 8-bit DMD values: size = projector width (x) or height (y)

  // The full projector image (height × width CV_8U) for display or for a real projector driver.
  cv::Mat ToImage(int projector_width, int projector_height) const;
};

struct PatternSet {
  std::string id;
  std::vector<ProjectorFrame> frames;
};

// The probe's burst: the N phase-shift frames of `spec` (marker in spec.marker_frame), then a
// uniform white texture frame if spec.texture_frame. Values round(255 · p) (see FringePatternSpec).
PatternSet MakePhaseShiftSet(const FringePatternSpec& spec, int projector_width,
                             int projector_height);
// N-step sets at several fringe periods (projector px), one after the other, no marker.
PatternSet MakeMultiFrequencySet(char axis, int steps, const std::vector<double>& periods_px,
                                 int projector_width, int projector_height);
// Binary-reflected Gray code of the projector coordinate along `axis` in cells of `cell_px`
// pixels, most significant bit first, each bit followed by its inverse when `with_inverse`.
PatternSet MakeGrayCodeSet(char axis, int cell_px, bool with_inverse, int projector_width,
                           int projector_height);
// One uniform frame of the given DMD level (255 = white, 0 = black).
PatternSet MakeUniformSet(uint8_t level, int projector_width, int projector_height);

// Parses a pattern-set description for tools:
//   "burst"                      the probe's own set (calibration.pattern)
//   "phase:N:PERIOD[:x|y]"       N-step phase shift
//   "multifreq:N:P1,P2,...[:x|y]"
//   "gray:CELL[:x|y]"            Gray code with inverses
//   "white", "black"
// INVALID_ARGUMENT naming the problem for anything else.
[[nodiscard]] Status ParsePatternSet(const std::string& text, const ProbeCalibration& calibration,
                                     PatternSet* out);

}  // namespace d3d
