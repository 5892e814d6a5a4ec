#include "protocol/codec.h"

#include <gtest/gtest.h>

#include <random>

namespace d3d::proto {
namespace {

BurstMsg MakeBurst(uint64_t seq, uint32_t w, uint32_t h, int frames) {
  BurstMsg b;
  b.serial = "SIM-0001";
  b.protocol_version = 101;
  b.burst_seq = seq;
  b.exposure_ns = 1'000'000;
  b.frame_interval_ns = 2'500'000;
  b.pattern_set = "phase4-marker";
  b.width = w;
  b.height = h;
  std::mt19937 rng(static_cast<uint32_t>(seq) + 7);
  for (int f = 0; f < frames; ++f) {
    FrameMsg fr;
    fr.pattern = "phase4-marker/" + std::to_string(f);
    fr.pattern_index = static_cast<uint16_t>(f);
    fr.timestamp_ns = 1'700'000'000'000'000'000LL + f * 2'500'000LL;
    fr.camera_frame_seq = seq * 4 + static_cast<uint64_t>(f);
    fr.pixels.resize(static_cast<size_t>(w) * h);
    for (auto& p : fr.pixels) p = static_cast<uint8_t>(rng());
    b.frames.push_back(std::move(fr));
  }
  return b;
}

TEST(Codec, BurstRoundTrip) {
  const BurstMsg b = MakeBurst(42, 16, 12, 4);
  std::string bytes;
  Encode(b, &bytes);
  BurstMsg d;
  ASSERT_TRUE(Decode(bytes, &d).ok());
  EXPECT_EQ(d, b);
}

TEST(Codec, InfoAndStatusRoundTrip) {
  InfoMsg i{"SIM-0001", 101, "0.1.0", "virtual-640x480",   "virtual-dmd", "sim",
            640,        480, 8,       "{\"format\":\"x\"}"};
  std::string bytes;
  Encode(i, &bytes);
  InfoMsg di;
  ASSERT_TRUE(Decode(bytes, &di).ok());
  EXPECT_EQ(di, i);
  StatusMsg s;
  s.serial = "SIM-0001";
  s.state = ProbeStateKind::kRecovering;
  s.bursts_published = 12;
  s.last_error = "camera timeout";
  bytes.clear();
  Encode(s, &bytes);
  StatusMsg ds;
  ASSERT_TRUE(Decode(bytes, &ds).ok());
  EXPECT_EQ(ds, s);
}

TEST(Codec, RejectsEveryTruncationAndTrailingBytes) {
  std::string bytes;
  Encode(MakeBurst(1, 4, 3, 4), &bytes);
  for (size_t n = 0; n < bytes.size(); ++n) {
    BurstMsg d;
    EXPECT_EQ(Decode(std::string_view(bytes).substr(0, n), &d).code(), StatusCode::kParseError)
        << n;
  }
  BurstMsg d;
  EXPECT_EQ(Decode(bytes + "x", &d).code(), StatusCode::kParseError);
}

TEST(Codec, RejectsInconsistentSizesAndNewerVersion) {
  BurstMsg b = MakeBurst(1, 4, 3, 4);
  b.frames[2].pixels.pop_back();  // a torn frame: 11 bytes for 4 × 3
  std::string bytes;
  Encode(b, &bytes);
  BurstMsg d;
  const Status s = Decode(bytes, &d);
  EXPECT_EQ(s.code(), StatusCode::kParseError);
  EXPECT_NE(s.message().find("frame size"), std::string::npos) << s.message();
  bytes.clear();
  Encode(MakeBurst(1, 4, 3, 4), &bytes);
  bytes[0] = static_cast<char>(kCodecVersion + 1);
  EXPECT_EQ(Decode(bytes, &d).code(), StatusCode::kUnsupported);
}

}  // namespace
}  // namespace d3d::proto
