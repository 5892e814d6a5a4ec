// The offline chain (d3d-fuse as a process) over a short stretch of scan-path styles that break a
// scan (issue 50): no view may be fused at a wrong pose (wrong_fusions: off by > 0.2 mm or > 1°
// from the truth), and the scan must go on after the break: the views after it are placed on the
// model again (a re-entry, or a segment that joins), or kept apart in a segment of their own,
// never fused at a guess.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "firmware/sim/session/sim_session.h"

namespace fs = std::filesystem;

namespace d3d {
namespace {

const std::string kBin = D3D_BIN_DIR;
constexpr double kRateHz = 30;

// The burst index `seconds_before` before the first lift of `style` (seed), from the style's own
// plan (the same the virtual probe of d3d-fuse follows).
int64_t BurstBeforeFirstLift(const std::string& style, uint32_t seed, double seconds_before) {
  SimSessionOptions o;
  o.trajectory = style;
  o.seed = seed;
  std::unique_ptr<SimSession> session;
  const Status s = SimSession::Create(o, &session);
  EXPECT_TRUE(s.ok()) << s.ToString();
  if (!s.ok()) return -1;
  for (const ScanSegment& seg : session->segments())
    if (seg.phase == ScanPhase::kLift)
      return std::max<int64_t>(0, static_cast<int64_t>((static_cast<double>(seg.start_ns - session->trajectory().StartNs()) * 1e-9 -
                                                        seconds_before) * kRateHz));
  return -1;
}

nlohmann::json RunFuse(const std::string& style, uint32_t seed, int64_t first, int bursts, const fs::path& dir) {
  fs::remove_all(dir);
  const std::string cmd = kBin + "/d3d-fuse --sim typodont --trajectory " + style + " --seed " + std::to_string(seed) +
                          " --bin 2 --every 2 --first " + std::to_string(first) + " --max-bursts " + std::to_string(bursts) +
                          " --quiet --json --out " + dir.string() + " > " + dir.string() + ".json 2> " + dir.string() + ".log";
  const int rc = std::system(cmd.c_str());
  EXPECT_EQ(rc, 0) << cmd << " (see " << dir.string() << ".log)";
  std::ifstream f(dir / "report.json");
  nlohmann::json j;
  if (f) f >> j;
  return j;
}

TEST(ScanStylesFuse, ALiftOutIsNeverFusedAtAWrongPose) {
  // 3 s of scan before the first lift (the model to come back to), the lift, and what follows:
  // 150 views at 15 Hz.
  const int64_t first = BurstBeforeFirstLift("lifts", 1, 3.0);
  ASSERT_GE(first, 0);
  const fs::path dir = fs::temp_directory_path() / "d3d_scan_styles_lifts";
  const nlohmann::json j = RunFuse("lifts", 1, first, 150, dir);
  ASSERT_TRUE(j.contains("wrong_fusions")) << "no evaluation in " << (dir / "report.json");
  EXPECT_EQ(j["wrong_fusions"].get<int>(), 0) << j.dump(2);
  const int bursts = j["bursts"].get<int>();
  // The lift itself: 1–3 s without points (15–45 views); the views after it are placed again, on
  // the model (fused) or in a segment apart (kept and reported, not fused at a guess).
  const int placed = j["fused"].get<int>() + j["views_apart"].get<int>();
  EXPECT_GE(placed, bursts - 45 - 20) << j.dump(2);
  EXPECT_LT(j["trueness_rms_um"].get<double>(), 25.0);
}

// The glare style's scene: the same burst of the same path saturates more of the camera (the wet
// teeth's glints), and the rest of the picture is the same scene.
TEST(ScanStylesScene, GlareSaturatesMorePixels) {
  auto saturated = [](const std::string& style, int64_t* lit) {
    SimSessionOptions o;
    o.trajectory = style;
    std::unique_ptr<SimSession> session;
    EXPECT_TRUE(SimSession::Create(o, &session).ok());
    if (!session) return int64_t{0};
    const Burst b = session->RenderBurst(300, false);
    int64_t n = 0;
    *lit = 0;
    for (const BurstFrame& f : b.frames) {
      n += cv::countNonZero(f.image >= 255);  // 8-bit sensor (probe_design.h: SensorModel::bits)
      *lit += cv::countNonZero(f.image >= 40);
    }
    return n;
  };
  int64_t lit_dry = 0, lit_wet = 0;
  const int64_t dry = saturated("full-arch", &lit_dry), wet = saturated("glare", &lit_wet);
  EXPECT_GT(wet, dry + dry / 2 + 50) << "dry " << dry << ", wet " << wet;
  EXPECT_NEAR(static_cast<double>(lit_wet), static_cast<double>(lit_dry), 0.1 * static_cast<double>(lit_dry));
}

}  // namespace
}  // namespace d3d
