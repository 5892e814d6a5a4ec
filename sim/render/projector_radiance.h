// Radiance that a projector frame casts, as a function of the projector coordinate and of the
// optical blur at the lit point. The DMD shows piecewise-constant pixels of radiance (DMD/255)^γ;
// the lens blurs them with a Gaussian whose σ depends on the point's distance (defocus,
// diffraction) plus, for translucent surfaces, sub-surface transport. Because every frame of our
// pattern sets varies along one axis only, the blur is 1-D along that axis (a Gaussian blur of a
// function constant along the other axis is that function blurred in 1-D).
//
// Implementation: the box-sampled DMD profile (4 samples per projector pixel) is blurred once per
// level σ_k = 0.25 · 2^(k/2) px, k = 0..17 (0.25 … 90 px); a lookup interpolates linearly in the
// coordinate and between the two levels around σ. Beyond the DMD the projector is dark; the table
// extends 3·σ_max past both ends so the blurred spill of light there is kept.
// Immutable after construction: Sample() may be called from any thread.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "sim/patterns/patterns.h"

namespace d3d {

class ProjectorRadiance {
 public:
  // gamma ≤ 0 is refused; gamma = 1 is a linear projector. axis_length = projector width (axis x)
  // or height (axis y); the frame's dmd must have that many values.
  ProjectorRadiance(const ProjectorFrame& frame, double gamma, int axis_length);

  char axis() const { return axis_; }
  // Radiance ∈ [0, 1] at projector coordinate `coord_px` (OpenCV convention: pixel i spans
  // [i − ½, i + ½)) seen through a Gaussian blur of σ = sigma_px projector pixels (clamped to the
  // table's range [0.25, 90]).
  float Sample(float coord_px, float sigma_px) const;

  static constexpr int kSamplesPerPixel = 4;
  static constexpr int kLevels = 18;
  static constexpr float kSigmaMin = 0.25f;

 private:
  float SampleLevel(int level, float index) const;
  char axis_;
  int pad_;                    // samples before the DMD's first pixel
  int length_;                 // samples per level (DMD + padding on both sides)
  std::vector<float> levels_;  // kLevels × length_
};

// Inline: called per lit pixel and frame (ShadePass).
inline float ProjectorRadiance::SampleLevel(int level, float index) const {
  const float* row = levels_.data() + static_cast<size_t>(level) * static_cast<size_t>(length_);
  if (!(index >= 0.0f) || index >= static_cast<float>(length_ - 1))
    return 0.0f;  // far outside: dark
  const int i = static_cast<int>(index);
  const float f = index - static_cast<float>(i);
  return row[i] + f * (row[i + 1] - row[i]);
}

inline float ProjectorRadiance::Sample(float coord_px, float sigma_px) const {
  // Sample j sits at coordinate (j + ½)/s − ½ for s samples per pixel.
  const float index = (coord_px + 0.5f) * kSamplesPerPixel - 0.5f + static_cast<float>(pad_);
  const float s = std::max(sigma_px, kSigmaMin);
  float level = 2.0f * std::log2(s / kSigmaMin);
  level = std::min(level, static_cast<float>(kLevels - 1));
  const int l0 = static_cast<int>(level);
  const int l1 = std::min(l0 + 1, kLevels - 1);
  const float w = level - static_cast<float>(l0);
  const float a = SampleLevel(l0, index);
  return w > 0.0f ? a + w * (SampleLevel(l1, index) - a) : a;
}

}  // namespace d3d
