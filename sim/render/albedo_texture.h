// A mild procedural albedo texture (stains, enamel mottling, gingival stippling) defined in the
// world frame, so it moves with the teeth and gives registration some texture features.
// Value noise (Perlin 1985-style lattice noise with smoothstep interpolation) of our own.
#pragma once

#include <Eigen/Geometry>
#include <cstdint>

#include "sim/render/probe_design.h"

namespace d3d {

// Lattice value noise in [−1, 1] at p (lattice spacing 1), deterministic for a seed.
double ValueNoise3(const Eigen::Vector3d& p, uint64_t seed);

// Multiplicative albedo factor at world point p_mm for `material`:
//   (1 + a_m · n(p / s_m)) · (1 − a_s · smoothstep(0.15, 0.55, fbm(p / s_s)))
// with n, fbm value noise (fbm: 3 octaves, gain ½). Mean ≈ 1 − a_s/4; range ⊂ [1 − a_m − a_s, 1 +
// a_m].
double AlbedoFactor(const Material& material, const Eigen::Vector3d& p_mm, uint64_t seed);

}  // namespace d3d
