#include "sim/render/projector_radiance.h"

#include <gtest/gtest.h>

#include <cmath>

namespace d3d {
namespace {

TEST(ProjectorRadiance, UniformFrameIsFlatInsideAndDarkOutside) {
  const ProjectorFrame white{"white", 'x', std::vector<uint8_t>(912, 255)};
  const ProjectorRadiance r(white, 2.2, 912);
  EXPECT_NEAR(r.Sample(400.3f, 0.25f), 1.0f, 1e-5);
  EXPECT_NEAR(r.Sample(400.3f, 20.0f), 1.0f, 1e-4);
  EXPECT_NEAR(r.Sample(-0.5f, 0.25f), 0.5f, 0.02f);  // the DMD's edge, blurred symmetrically
  EXPECT_NEAR(r.Sample(-0.5f, 8.0f), 0.5f, 0.02f);
  EXPECT_NEAR(r.Sample(-8.5f, 8.0f), 0.16f, 0.01f);  // light spilled one σ beyond the edge
  EXPECT_EQ(r.Sample(-5.0f, 0.25f), 0.0f);
  EXPECT_EQ(r.Sample(-2000.0f, 90.0f), 0.0f);
  const ProjectorFrame grey{"grey", 'x', std::vector<uint8_t>(912, 128)};
  EXPECT_NEAR(ProjectorRadiance(grey, 2.2, 912).Sample(300.0f, 1.0f), std::pow(128 / 255.0, 2.2),
              1e-5);
  EXPECT_NEAR(ProjectorRadiance(grey, 1.0, 912).Sample(300.0f, 1.0f), 128 / 255.0, 1e-5);
  EXPECT_THROW(ProjectorRadiance(grey, 2.2, 1140), std::invalid_argument);
}

TEST(ProjectorRadiance, BlurAttenuatesFringesAsAGaussian) {
  // A sinusoid of period T blurred by σ keeps its phase and loses contrast by exp(−2π²σ²/T²)
  // (times the DMD pixel's box: sinc(π/T), ≈ 1 here).
  const double T = 48.0;
  FringePatternSpec spec;
  spec.fringe_period_px = T;
  spec.marker_frame = -1;
  const ProjectorFrame f{"f", 'x', [&] {
                           std::vector<uint8_t> v(912);
                           for (int c = 0; c < 912; ++c)
                             v[c] =
                                 static_cast<uint8_t>(std::lround(255 * spec.PatternValue(0, c)));
                           return v;
                         }()};
  const ProjectorRadiance r(f, 1.0, 912);
  for (float sigma : {1.0f, 4.0f, 8.0f}) {
    float lo = 1, hi = 0;
    for (float c = 300; c < 300 + T; c += 0.25f) {
      lo = std::min(lo, r.Sample(c, sigma));
      hi = std::max(hi, r.Sample(c, sigma));
    }
    const double box = std::sin(M_PI / T) / (M_PI / T);
    const double expected = box * std::exp(-2 * M_PI * M_PI * sigma * sigma / (T * T));
    EXPECT_NEAR((hi - lo), expected, 0.02) << sigma;
  }
}

}  // namespace
}  // namespace d3d
