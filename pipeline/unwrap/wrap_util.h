// Small inline helpers shared by the quality map and the unwrapper (internal).
#pragma once

#include <cmath>

namespace d3d::internal {

inline constexpr float kTwoPiF = 6.28318530717958647692f;
inline constexpr float kPiF = 3.14159265358979323846f;

// Wraps a difference of two values in [0, 2π), i.e. d ∈ (−2π, 2π), to [−π, π]. NaN stays NaN.
inline float WrapPi(float d) { return d > kPiF ? d - kTwoPiF : (d < -kPiF ? d + kTwoPiF : d); }

// Order increment across an edge: Φ(b) = Φ(a) + W(φb − φa) means k(b) = k(a) + StepOrder(φb − φa).
inline int StepOrder(float d) { return d > kPiF ? -1 : (d < -kPiF ? 1 : 0); }

// Any finite value → [0, 2π).
inline float WrapTo2Pi(float p) {
  if (p >= 0.0f && p < kTwoPiF) return p;
  float r = p - kTwoPiF * std::floor(p / kTwoPiF);
  if (r >= kTwoPiF || r < 0.0f) r = 0.0f;  // rounding at the period boundary
  return r;
}

}  // namespace d3d::internal
