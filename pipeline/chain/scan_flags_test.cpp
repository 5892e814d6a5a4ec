#include "pipeline/chain/scan_flags.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace d3d {
namespace {

// Declares the scan flags on a fresh registry, parses `args`, and returns the exit code (-1: run).
int Parse(std::vector<std::string> args, ScanFlags* flags, ScanOptions* options) {
  OptionRegistry r("scan flags test");
  DeclareScanFlags(&r, flags, options);
  args.insert(args.begin(), "tool");
  std::vector<const char*> argv;
  for (const std::string& a : args) argv.push_back(a.c_str());
  int code = 0;
  return r.Parse(static_cast<int>(argv.size()), argv.data(), &code) ? -1 : code;
}

TEST(ScanFlags, DefaultsAreTheLiveProfileAtBinTwo) {
  ScanFlags flags;
  ScanOptions o;
  ASSERT_EQ(Parse({}, &flags, &o), -1);
  ASSERT_TRUE(ApplyScanFlags(flags, 6, &o).ok());
  const ScanOptions want = ScanOptionsForBin(LiveScanProfile([] {
                                               ScanOptions s;
                                               s.tracker = TrackerOptionsForStep(s.tracker, 6);
                                               return s;
                                             }()),
                                             2);
  EXPECT_EQ(o.bin, 2);
  EXPECT_EQ(o.tracker.keyframes.reuse_radius_mm, want.tracker.keyframes.reuse_radius_mm);
  EXPECT_EQ(o.tracker.odometry.icp.levels[0].max_samples,
            want.tracker.odometry.icp.levels[0].max_samples);
  EXPECT_EQ(o.tracker.odometry.icp.levels[0].max_distance_mm,
            want.tracker.odometry.icp.levels[0].max_distance_mm);
  EXPECT_EQ(o.tracker.motion.max_step_mm, want.tracker.motion.max_step_mm);
  EXPECT_EQ(o.tracker.odometry.sample_stride, want.tracker.odometry.sample_stride);
  EXPECT_EQ(o.tracker.odometry.icp.max_rmse_mm,
            ScanOptions{}.tracker.odometry.icp.max_rmse_mm);  // µm and back
  EXPECT_EQ(o.refuse_min_correction_mm, 0.01);
  EXPECT_TRUE(o.tracker.keyframes.detect_loops);
  EXPECT_EQ(o.tsdf.voxel_mm, ScanOptions{}.tsdf.voxel_mm);
}

TEST(ScanFlags, EachFlagSetsItsField) {
  ScanFlags flags;
  ScanOptions o;
  ASSERT_EQ(Parse({"--profile",
                   "full",
                   "--bin",
                   "1",
                   "--association",
                   "kdtree",
                   "--max-rmse-um",
                   "40",
                   "--no-loops",
                   "--no-refuse",
                   "--no-free-space",
                   "--no-model-anchor",
                   "--voxel",
                   "0.1",
                   "--keyframe-max-views",
                   "30",
                   "--tracked-edge-factor",
                   "0.5",
                   "--live-voxel",
                   "0"},
                  &flags, &o),
            -1);
  ASSERT_TRUE(ApplyScanFlags(flags, 1, &o).ok());
  EXPECT_EQ(o.bin, 1);
  EXPECT_EQ(o.tracker.keyframes.reuse_radius_mm,
            ScanOptions{}.tracker.keyframes.reuse_radius_mm);  // not live
  EXPECT_EQ(o.tracker.odometry.association, Association::kKdTree);
  EXPECT_DOUBLE_EQ(o.tracker.odometry.icp.max_rmse_mm, 0.04);
  EXPECT_FALSE(o.tracker.keyframes.detect_loops);
  EXPECT_LT(o.refuse_min_correction_mm, 0);
  EXPECT_FALSE(flags.refuse);
  EXPECT_FALSE(o.free_space.enabled);
  EXPECT_FALSE(o.anchor.enabled);
  EXPECT_EQ(o.tsdf.voxel_mm, 0.1);
  EXPECT_EQ(o.tracker.keyframes.max_views, 30);
  EXPECT_EQ(o.tracker.keyframes.tracked_edge_information_factor, 0.5);
  EXPECT_EQ(flags.live_voxel_mm, 0.0);
}

TEST(ScanFlags, BadValuesAreUsageErrorsOrNamedByApply) {
  for (const std::vector<std::string>& bad : {std::vector<std::string>{"--bin", "0"},
                                              {"--association", "nearest"},
                                              {"--profile", "fast"},
                                              {"--tracked-edge-factor", "11"},
                                              {"--live-voxel", "-1"}}) {
    ScanFlags flags;
    ScanOptions o;
    EXPECT_EQ(Parse(bad, &flags, &o), 2) << bad[0];
  }
  ScanFlags flags;
  ScanOptions o;
  flags.association = "nearest";  // as a tool could set it without the registry
  const Status s = ApplyScanFlags(flags, 1, &o);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.ToString().find("--association"), std::string::npos) << s.ToString();
  flags = ScanFlags{};
  o.tsdf.voxel_mm = -1;  // a value ScanOptions::Check refuses
  EXPECT_FALSE(ApplyScanFlags(flags, 1, &o).ok());
  EXPECT_FALSE(ApplyScanFlags(ScanFlags{}, 0.5, &o).ok());
}

}  // namespace
}  // namespace d3d
