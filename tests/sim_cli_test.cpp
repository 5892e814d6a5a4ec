// d3d-sim, the virtual probe's command-line tool, end to end: one burst with and without ground
// truth. Without truth (--truth none) there is no true depth to show, so the preview picture holds
// the frames only (it aborted on the empty depth map before); with truth it adds the depth and
// surface maps below them.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>

namespace fs = std::filesystem;

namespace d3d {
namespace {

const std::string kBin = D3D_BIN_DIR;

// Runs d3d-sim for one burst into dir; returns its exit status.
int RunSim(const fs::path& dir, const std::string& truth) {
  fs::remove_all(dir);
  const std::string cmd = kBin + "/d3d-sim --frames 1 --index 200 --threads 2 --quiet --truth " +
                          truth + " --out " + dir.string() + " > " + dir.string() + ".log 2>&1";
  return std::system(cmd.c_str());
}

TEST(SimCli, PreviewWithoutTruthHoldsTheFramesOnly) {
  const fs::path base = fs::temp_directory_path() / "d3d_sim_cli_test";
  fs::create_directories(base);
  ASSERT_EQ(RunSim(base / "none", "none"), 0) << "see " << (base / "none.log");
  ASSERT_EQ(RunSim(base / "ref", "ref"), 0) << "see " << (base / "ref.log");
  const cv::Mat none = cv::imread((base / "none" / "preview.png").string());
  const cv::Mat ref = cv::imread((base / "ref" / "preview.png").string());
  ASSERT_FALSE(none.empty());
  ASSERT_FALSE(ref.empty());
  // Two 640×480 frames side by side; with truth, the depth and surface maps below them.
  EXPECT_EQ(none.cols, 1280);
  EXPECT_EQ(none.rows, 480);
  EXPECT_EQ(ref.cols, 1280);
  EXPECT_EQ(ref.rows, 960);
  // The same burst: the frames (top half, above the captions) are identical.
  const cv::Rect frames(0, 0, 1280, 400);
  EXPECT_EQ(cv::norm(none(frames), ref(frames), cv::NORM_INF), 0.0);
  EXPECT_TRUE(fs::exists(base / "none" / "bursts" / "000200" / "burst.json"));
  EXPECT_FALSE(fs::exists(base / "none" / "bursts" / "000200" / "truth_ref"));
}

// A negative count or index is refused before anything is rendered (it rendered the whole path).
TEST(SimCli, ANegativeFrameCountIsRefused) {
  const fs::path dir = fs::temp_directory_path() / "d3d_sim_cli_negative";
  fs::remove_all(dir);
  for (const std::string bad : {"--frames -1", "--index -5"}) {
    const std::string cmd = kBin + "/d3d-sim " + bad + " --quiet --out " + dir.string() + " > " +
                            dir.string() + ".log 2>&1";
    EXPECT_NE(std::system(cmd.c_str()), 0) << bad;
    EXPECT_FALSE(fs::exists(dir / "bursts")) << bad;
  }
}

}  // namespace
}  // namespace d3d
