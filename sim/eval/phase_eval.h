// Evaluation of the phase stage on virtual-probe renders against their ground truth (tests, the
// benchmark's gamma table). Not part of the processing path.
#pragma once

#include <string>
#include <vector>

#include "common/burst/burst.h"
#include "pipeline/phase/phase.h"
#include "sim/render/virtual_probe.h"

namespace d3d::phase_eval {

// Scenes rendered at the identity pose: "plane" (tilted plane at 50 mm), "sphere" (a 4.5 mm
// enamel sphere at 54 mm before a plane at 62 mm, which it shadows), "typodont" (the procedural
// arch from a full-arch scan pose, burst `typodont_index`).
struct RenderSpec {
  std::string scene = "plane";
  double projector_gamma = 2.2;
  bool noise = true;
  uint64_t seed = 1;
  int typodont_index = 300;
};

// Renders one burst with truth (frames[0].truth) and returns the calibration used.
Burst RenderScene(const RenderSpec& spec, ProbeCalibration* calibration);

struct AlgorithmScore {
  PhaseAlgorithm algorithm;
  double rms_outside = 0;  // rad, lit valid pixels ≥ 2 projector px from any marker stripe
  double rms_inside = 0;   // rad, lit valid pixels ≥ 2 projector px inside a stripe
  int n_outside = 0, n_inside = 0;
};

struct MarkerScore {
  double recall = 0;  // detected / lit stripe pixels ≥ 2 projector px from the stripe edges
  double false_positive = 0;  // detected / lit pixels ≥ 2 projector px outside every stripe
  double edge_detected = 0;   // detected share of the ±2 px transition band (informative)
  int n_core = 0, n_outside = 0;
};

struct Evaluation {
  std::vector<AlgorithmScore> algorithms;  // standard, lut-gamma, adaptive-harmonic
  MarkerScore marker;                      // of the adaptive-harmonic run
  double mean_kappa = 0;                   // mean κ over the scored pixels
};

// Runs the three algorithms on `burst` (phase from truth projector_uv of frame 0). Pixels are
// scored when lit in the truth, 2 px inside the lit region (no occlusion or shadow edges in the
// camera's blur), where the fringe period spans ≥ 8 camera px (the truth's projector-coordinate
// gradient), and valid for all three algorithms.
Evaluation Evaluate(const Burst& burst, const ProbeCalibration& calibration,
                    const PhaseOptions& base = {});

// "gamma  standard  lut-gamma  adaptive-harmonic" table lines for the given evaluations.
std::string FormatRow(const std::string& label, const Evaluation& e);

}  // namespace d3d::phase_eval
