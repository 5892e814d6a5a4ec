// Seeded random and mutated inputs through the firmware fuzz iterations (a quick, deterministic
// stand-in for the libFuzzer runs; also run under ASan + UBSan by tools/test.sh).
#include <gtest/gtest.h>

#include <random>

#include "firmware/update/test_images.h"
#include "tests/fuzz/firmware_fuzz.h"

namespace d3d {
namespace {

TEST(FirmwareFuzz, MutatedImagesAndRecords) {
  std::mt19937 rng(8);
  const auto key = fw::testing::MakeTestKey(1);
  const auto img = fw::testing::MakeImage(&key, {1, 1, 0}, 1, 1, 1500, 3);
  for (int i = 0; i < 3000; ++i) {
    std::vector<uint8_t> in;
    in.push_back(static_cast<uint8_t>(i % 3));
    if (i % 3 == 0) {
      in.insert(in.end(), img.begin(), img.end());
      const int flips = 1 + static_cast<int>(rng() % 4);
      for (int f = 0; f < flips; ++f)
        in[1 + rng() % img.size()] ^= static_cast<uint8_t>(1 << (rng() % 8));
      if (rng() % 4 == 0) in.resize(1 + rng() % in.size());
    } else {
      const size_t n = rng() % 200;
      for (size_t k = 0; k < n; ++k) in.push_back(static_cast<uint8_t>(rng()));
    }
    FuzzFirmwareImageOnce(in.data(), in.size());
  }
  std::vector<uint8_t> ok = {0};
  ok.insert(ok.end(), img.begin(), img.end());
  FuzzFirmwareImageOnce(ok.data(), ok.size());  // the valid image passes the consistency checks
}

TEST(FirmwareFuzz, RandomDfuRequestScriptsNeverLeaveTheProbeUnbootable) {
  // Scripts that mostly follow a correct update (DETACH, reset, per block DNLOAD + 2 GETSTATUS,
  // zero-length DNLOAD, GETSTATUS through manifestation, reset) with random requests, resets and
  // clock steps injected, so that both deep paths and broken sequences are exercised.
  std::mt19937 rng(9);
  const std::vector<uint8_t> kGetStatus = {0, 1, 3, 0, 0, 0, 0, 6, 0};  // type index 1 = class IN
  int updated = 0;
  for (int i = 0; i < 400; ++i) {
    std::vector<uint8_t> in = {
        static_cast<uint8_t>(i % 3)};  // healthy / unhealthy / silent; no busy times
    std::vector<std::vector<uint8_t>> steps = {{0, 0, 0, 0xE8, 3, 0, 0, 0, 0},
                                               {2}};  // DETACH, bus reset
    for (int b = 0; b < 8; ++b) {  // 7 blocks of the valid image, then the zero-length DNLOAD
      steps.push_back({4});
      steps.push_back(kGetStatus);
      steps.push_back(kGetStatus);
    }
    steps.push_back(kGetStatus);
    steps.push_back({2});
    const double inject = (i % 4) * 0.04;
    std::uniform_real_distribution<double> u(0, 1);
    for (const auto& step : steps) {
      if (u(rng) < inject) {
        const size_t n = 1 + rng() % 12;
        for (size_t k = 0; k < n; ++k) in.push_back(static_cast<uint8_t>(rng()));
      }
      in.insert(in.end(), step.begin(), step.end());
    }
    updated += FuzzDfuRequestsOnce(in.data(), in.size()) == 2;
  }
  EXPECT_GT(updated, 0);  // some scripts got the whole valid image through manifestation and reboot
  EXPECT_LT(updated, 400);  // and some did not (refused, aborted, rolled back)
  RecordProperty("updated", updated);
}

}  // namespace
}  // namespace d3d
