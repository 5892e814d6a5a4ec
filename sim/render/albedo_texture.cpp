#include "sim/render/albedo_texture.h"

#include <algorithm>
#include <cmath>

namespace d3d {
namespace {

uint64_t Mix(uint64_t x) {  // splitmix64 finaliser (Steele et al. 2014)
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

double Lattice(int64_t x, int64_t y, int64_t z, uint64_t seed) {
  const uint64_t h = Mix(seed ^ Mix(static_cast<uint64_t>(x) * 0x8DA6B343ull ^
                                    Mix(static_cast<uint64_t>(y) * 0xD8163841ull ^
                                        static_cast<uint64_t>(z) * 0xCB1AB31Full)));
  return static_cast<double>(h >> 11) * (2.0 / 9007199254740992.0) - 1.0;
}

double Smooth(double t) { return t * t * (3.0 - 2.0 * t); }

}  // namespace

double ValueNoise3(const Eigen::Vector3d& p, uint64_t seed) {
  const double fx = std::floor(p.x()), fy = std::floor(p.y()), fz = std::floor(p.z());
  const auto x = static_cast<int64_t>(fx), y = static_cast<int64_t>(fy),
             z = static_cast<int64_t>(fz);
  const double tx = Smooth(p.x() - fx), ty = Smooth(p.y() - fy), tz = Smooth(p.z() - fz);
  double c[2][2];
  for (int j = 0; j < 2; ++j)
    for (int k = 0; k < 2; ++k) {
      const double a = Lattice(x, y + j, z + k, seed), b = Lattice(x + 1, y + j, z + k, seed);
      c[j][k] = a + tx * (b - a);
    }
  const double e0 = c[0][0] + ty * (c[1][0] - c[0][0]);
  const double e1 = c[0][1] + ty * (c[1][1] - c[0][1]);
  return e0 + tz * (e1 - e0);
}

double AlbedoFactor(const Material& m, const Eigen::Vector3d& p_mm, uint64_t seed) {
  double factor = 1.0;
  if (m.mottle_amplitude > 0)
    factor *= 1.0 + m.mottle_amplitude * ValueNoise3(p_mm / m.mottle_scale_mm, seed);
  if (m.stain_amplitude > 0) {
    double fbm = 0.0, amp = 0.5, freq = 1.0;
    for (int o = 0; o < 3; ++o, amp *= 0.5, freq *= 2.0)
      fbm += amp * ValueNoise3(p_mm * (freq / m.stain_scale_mm), seed + 17 + o);
    const double t = std::clamp((fbm - 0.15) / 0.4, 0.0, 1.0);
    factor *= 1.0 - m.stain_amplitude * Smooth(t);
  }
  return factor;
}

}  // namespace d3d
