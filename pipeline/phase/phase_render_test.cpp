// Render tests of the phase stage: virtual-probe bursts (noise, defocus, sub-surface scattering,
// glints, texture, the projector's gamma) against their ground truth. The numbers are printed so
// they can be quoted; d3d-bench-phase --gamma_table prints the full table on three scenes.
#include <gtest/gtest.h>

#include <iostream>
#include <map>

#include "sim/eval/phase_eval.h"

namespace d3d {
namespace {

using phase_eval::Evaluate;
using phase_eval::Evaluation;
using phase_eval::FormatRow;
using phase_eval::RenderScene;
using phase_eval::RenderSpec;

constexpr int kStd = 0, kLut = 1, kOurs = 2;

Evaluation RunScene(const std::string& scene, double gamma, bool noise) {
  RenderSpec rs;
  rs.scene = scene;
  rs.projector_gamma = gamma;
  rs.noise = noise;
  ProbeCalibration calibration;
  const Burst burst = RenderScene(rs, &calibration);
  EXPECT_EQ(calibration.projector_gamma, gamma);
  const Evaluation e = Evaluate(burst, calibration);
  std::cout << FormatRow(
                   scene + (noise ? " noisy g=" : " clean g=") + std::to_string(gamma).substr(0, 3),
                   e)
            << std::endl;
  return e;
}

double Out(const Evaluation& e, int k) { return e.algorithms[k].rms_outside; }
double In(const Evaluation& e, int k) { return e.algorithms[k].rms_inside; }

// Phase RMS (rad) of the three algorithms on a tilted enamel plane at projector gamma 1.0–2.8.
TEST(PhaseRender, GammaTableOnATiltedPlane) {
  std::map<double, Evaluation> noisy, clean;
  for (double g : {1.0, 1.6, 2.2, 2.8}) noisy[g] = RunScene("plane", g, true);
  for (double g : {2.2, 2.8}) clean[g] = RunScene("plane", g, false);

  for (const auto& [g, e] : noisy) {
    ASSERT_GT(e.algorithms[kOurs].n_outside, 100000);
    ASSERT_GT(e.algorithms[kOurs].n_inside, 10000);
    std::cout << "  gamma " << g << ": ours/standard " << Out(e, kOurs) / Out(e, kStd)
              << ", ours/lut " << Out(e, kOurs) / Out(e, kLut)
              << " (outside stripes); in stripes ours/standard " << In(e, kOurs) / In(e, kStd)
              << ", ours/lut " << In(e, kOurs) / In(e, kLut) << std::endl;
  }
  // A linear projector: ours is the standard estimator (κ cannot be measured, nothing to correct).
  EXPECT_LE(Out(noisy[1.0], kOurs), 1.02 * Out(noisy[1.0], kStd));
  EXPECT_LE(In(noisy[1.0], kOurs), 1.02 * In(noisy[1.0], kStd));
  // Ours beats plain N-step clearly at 2.2 and 2.8 (noise-free: the model error alone; with noise).
  EXPECT_LT(Out(clean[2.2], kOurs), 0.65 * Out(clean[2.2], kStd));
  EXPECT_LT(Out(clean[2.8], kOurs), 0.4 * Out(clean[2.8], kStd));
  EXPECT_LT(Out(noisy[2.2], kOurs), 0.92 * Out(noisy[2.2], kStd));
  EXPECT_LT(Out(noisy[2.8], kOurs), 0.6 * Out(noisy[2.8], kStd));
  for (double g : {2.2, 2.8}) {
    EXPECT_LT(In(noisy[g], kOurs), 0.2 * In(noisy[g], kStd)) << g;
    // Against the fixed LUT (Zhang & Yau): the claim "≤ 1/9" does not hold on our renders (see the
    // printed ratios); what holds: clearly better in the stripes, better outside at 2.8, and at the
    // 8-bit quantisation floor (≈ 0.004 rad) at 2.2 outside, where the LUT is too.
    EXPECT_LT(In(noisy[g], kOurs), 0.4 * In(noisy[g], kLut)) << g;
    EXPECT_LT(In(clean[g], kOurs), 0.3 * In(clean[g], kLut)) << g;
  }
  EXPECT_LT(Out(clean[2.8], kOurs), 0.9 * Out(clean[2.8], kLut));
  EXPECT_LT(Out(noisy[2.8], kOurs), 0.95 * Out(noisy[2.8], kLut));
  EXPECT_LT(Out(clean[2.2], kOurs), 0.006);
  // Ours measures the blur's attenuation of the harmonics (enamel: defocus + sub-surface).
  EXPECT_GT(noisy[2.2].mean_kappa, 0.6);
  EXPECT_LT(noisy[2.2].mean_kappa, 0.95);
}

// The marker with noise and gamma 2.2 on the plane, the sphere (shadow, curvature) and the
// typodont.
TEST(PhaseRender, MarkerRecallAndFalsePositivesAndPhaseInsideStripes) {
  for (const std::string scene : {"plane", "sphere", "typodont"}) {
    const Evaluation e = RunScene(scene, 2.2, true);
    SCOPED_TRACE(scene);
    ASSERT_GT(e.marker.n_core, 5000);
    EXPECT_GE(e.marker.recall, 0.95);
    EXPECT_LE(e.marker.false_positive, 0.001);
    std::cout << "  " << scene << ": marker recall " << e.marker.recall << ", false positives "
              << e.marker.false_positive << " of lit non-stripe pixels, transition band detected "
              << e.marker.edge_detected << "; ours phase RMS inside stripes " << In(e, kOurs)
              << " vs outside " << Out(e, kOurs) << std::endl;
    // φ inside the stripes comes from 3 frames whose phase response γ flattens (noise gain up to
    // 5× over part of the period): within 2× of the 4-frame phase outside.
    EXPECT_LT(In(e, kOurs), 2.0 * Out(e, kOurs));
  }
}

}  // namespace
}  // namespace d3d
