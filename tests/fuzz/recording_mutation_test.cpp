// Deterministic stand-in for the recording fuzzer in every CTest run (GCC, no libFuzzer): seeded
// mutations of a valid recording and of valid codec payloads never crash, throw or yield an
// inconsistent result (FuzzRecordingOnce aborts on inconsistency).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>

#include "common/recording/recording.h"
#include "protocol/codec.h"
#include "tests/fuzz/recording_fuzz.h"

namespace d3d {
namespace {

std::string ValidRecording() {
  const auto p = std::filesystem::temp_directory_path() / "d3d_recording_seed.d3drec";
  RecordingHeader h;
  h.channels = {{0, "a", "x"}, {1, "b", "y"}};
  RecordingWriter w;
  RecordingWriterOptions o;
  o.chunk_bytes = 256;
  EXPECT_TRUE(w.Open(p.string(), h, o).ok());
  for (int k = 0; k < 12; ++k)
    EXPECT_TRUE(
        w.Add(static_cast<uint16_t>(k % 2), k, std::string(40 + k, static_cast<char>('a' + k)))
            .ok());
  EXPECT_TRUE(w.Close().ok());
  std::ifstream f(p, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(f)), {});
}

std::string ValidBurst() {
  proto::BurstMsg b;
  b.serial = "S";
  b.width = 3;
  b.height = 2;
  b.frames.resize(4);
  for (auto& f : b.frames) f.pixels.assign(6, 9);
  std::string s;
  proto::Encode(b, &s);
  return s;
}

TEST(RecordingFuzz, SeededMutationsNeverCrash) {
  std::string seeds[4];
  const std::string bodies[4] = {ValidRecording(), ValidBurst(),
                                 [] {
                                   std::string s;
                                   proto::Encode(proto::InfoMsg{}, &s);
                                   return s;
                                 }(),
                                 [] {
                                   std::string s;
                                   proto::Encode(proto::StatusMsg{}, &s);
                                   return s;
                                 }()};
  for (int i = 0; i < 4; ++i) {
    seeds[i].push_back(static_cast<char>(i));
    seeds[i].append(bodies[i]);
  }
  std::mt19937 rng(20261122);
  int intact = 0;
  for (int i = 0; i < 3000; ++i) {
    std::string s = seeds[i % 4];
    const int edits = 1 + static_cast<int>(rng() % 4);
    for (int e = 0; e < edits && s.size() > 1; ++e) {
      const size_t pos = 1 + rng() % (s.size() - 1);
      switch (rng() % 3) {
        case 0:
          s[pos] = static_cast<char>(s[pos] ^ (1 << (rng() % 8)));
          break;
        case 1:
          s.resize(pos);
          break;
        default:
          s.insert(pos, std::string(1 + rng() % 4, static_cast<char>(rng())));
          break;
      }
    }
    EXPECT_NO_THROW(FuzzRecordingOnce(reinterpret_cast<const uint8_t*>(s.data()), s.size())) << i;
    if (i % 4 == 0) {
      std::unique_ptr<RecordingReader> r;
      intact += RecordingReader::Open(MemorySource(s.substr(1)), &r).ok() && !r->chunks().empty();
    }
  }
  EXPECT_GT(intact, 0) << "some mutated recordings still yield chunks";
}

}  // namespace
}  // namespace d3d
