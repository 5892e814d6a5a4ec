// Test helpers: deterministic keys and signed images (seeded; header-only, for tests and fuzzers).
#pragma once

#include <array>
#include <cstdint>
#include <random>
#include <vector>

#include "firmware/update/image_format.h"

namespace d3d::fw::testing {

struct TestKey {
  PublicKey pk;
  SecretKey sk;
};

// Key pair from a one-byte seed (seed 1 = "our" key, seed 2 = an untrusted key).
inline TestKey MakeTestKey(uint8_t seed) {
  std::array<uint8_t, 32> s{};
  s.fill(seed);
  TestKey k;
  KeyPairFromSeed(s, &k.pk, &k.sk);
  return k;
}

inline std::vector<uint8_t> MakePayload(size_t bytes, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<uint8_t> p(bytes);
  for (auto& b : p) b = static_cast<uint8_t>(rng());
  return p;
}

inline std::vector<uint8_t> MakeImage(const TestKey* key, SemVer version, uint32_t counter,
                                      uint32_t hw_id, size_t payload_bytes, uint32_t seed = 7) {
  ImageHeader h;
  h.hw_id = hw_id;
  h.version = version;
  h.security_counter = counter;
  const auto payload = MakePayload(payload_bytes, seed);
  return BuildImage(h, payload, key ? &key->sk : nullptr);
}

}  // namespace d3d::fw::testing
