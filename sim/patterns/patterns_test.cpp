#include "sim/patterns/patterns.h"

#include <gtest/gtest.h>

#include <cmath>

namespace d3d {
namespace {

ProbeCalibration Calib() {
  ProbeCalibration c;
  c.projector.width = 912;
  c.projector.height = 1140;
  return c;
}

TEST(Patterns, BurstHasFourFringeFramesAndTexture) {
  FringePatternSpec spec;
  spec.texture_frame = true;
  const PatternSet set = MakePhaseShiftSet(spec, 912, 1140);
  ASSERT_EQ(set.frames.size(), 5u);
  for (int f = 0; f < 4; ++f) {
    ASSERT_EQ(set.frames[f].dmd.size(), 912u);
    for (int c = 0; c < 912; c += 7) {
      EXPECT_NEAR(set.frames[f].dmd[c] / 255.0, spec.PatternValue(f, c), 0.5 / 255 + 1e-12);
    }
  }
  for (uint8_t v : set.frames[4].dmd) EXPECT_EQ(v, 255);
  const cv::Mat img = set.frames[1].ToImage(912, 1140);
  EXPECT_EQ(img.rows, 1140);
  EXPECT_EQ(img.at<uint8_t>(1000, 100), set.frames[1].dmd[100]);
}

TEST(Patterns, GrayCodeDecodesEveryCell) {
  const PatternSet set = MakeGrayCodeSet('x', 8, true, 912, 1140);
  ASSERT_EQ(set.frames.size(), 2u * 7u);  // 114 cells → 7 bits, each with its inverse
  for (int c = 0; c < 912; ++c) {
    int gray = 0;
    for (size_t f = 0; f < set.frames.size(); f += 2) {
      const bool bit = set.frames[f].dmd[c] > set.frames[f + 1].dmd[c];
      gray = (gray << 1) | (bit ? 1 : 0);
    }
    int binary = 0;
    for (int g = gray; g; g >>= 1) binary ^= g;
    EXPECT_EQ(binary, c / 8) << c;
  }
}

TEST(Patterns, ParseDescriptions) {
  PatternSet set;
  ASSERT_TRUE(ParsePatternSet("burst", Calib(), &set).ok());
  EXPECT_EQ(set.frames.size(), 4u);
  ASSERT_TRUE(ParsePatternSet("phase:6:32:y", Calib(), &set).ok());
  EXPECT_EQ(set.frames.size(), 6u);
  EXPECT_EQ(set.frames[0].axis, 'y');
  EXPECT_EQ(set.frames[0].dmd.size(), 1140u);
  ASSERT_TRUE(ParsePatternSet("multifreq:4:24,96,384", Calib(), &set).ok());
  EXPECT_EQ(set.frames.size(), 12u);
  ASSERT_TRUE(ParsePatternSet("black", Calib(), &set).ok());
  EXPECT_EQ(set.frames[0].dmd[5], 0);
  EXPECT_FALSE(ParsePatternSet("phase:x:32", Calib(), &set).ok());
  EXPECT_FALSE(ParsePatternSet("phase:4:32:z", Calib(), &set).ok());
  EXPECT_FALSE(ParsePatternSet("checkerboard", Calib(), &set).ok());
  EXPECT_THROW(MakeGrayCodeSet('x', 0, true, 912, 1140), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
