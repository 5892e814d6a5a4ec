// Pairwise registration of the Stanford bunny range scans from identity (initial alignment by
// features, then ICP) against the poses of bun.conf (convention in ../shared/data/README.md:
// p_world = R(q)ᵀ p + t). Every pair of views with real overlap (the pairs tools/bench/
// bench_register.cpp runs): FPFH for all of them; SIFT on the shaded range images for the two it
// solves (it finds no consensus for the others); SIFT with the FPFH fallback for all.
#include <gtest/gtest.h>

#include <filesystem>
#include <map>
#include <tuple>

#include "pipeline/register/pairwise.h"
#include "pipeline/register/range_grid_io.h"

namespace d3d {
namespace {

const std::string kDir = std::string(D3D_SHARED_DATA_DIR) + "/range_scans/stanford_bunny";

// Scans are read once per process (ASCII PLY, ~0.2 s each): once for the whole suite when the
// binary runs it all; under CTest each case is its own process and reads its two scans.
const cv::Mat& Scan(const std::string& name) {
  static std::map<std::string, cv::Mat> cache;
  auto it = cache.find(name);
  if (it == cache.end()) {
    cv::Mat m;
    if (!LoadRangeGridPly(kDir + "/" + name + ".ply", 1000.0, &m).ok()) m = cv::Mat();
    it = cache.emplace(name, m).first;
  }
  return it->second;
}

using Case = std::tuple<const char*, const char*, InitialAlignment>;
class Bunny : public ::testing::TestWithParam<Case> {};

TEST_P(Bunny, PairFromIdentityRecoversTheConfPose) {
  if (!std::filesystem::exists(kDir + "/bun.conf")) GTEST_SKIP() << "no bunny scans in " << kDir;
  std::map<std::string, Rigid3d> conf;
  ASSERT_TRUE(LoadRangeScanPoses(kDir + "/bun.conf", &conf).ok());
  const auto [src, dst, method] = GetParam();
  const cv::Mat &S = Scan(src), &T = Scan(dst);
  ASSERT_FALSE(S.empty() || T.empty()) << "cannot read " << src << " or " << dst;
  const PairwiseResult r =
      RegisterPair(S, cv::Mat(), T, cv::Mat(), RangeScanPairwiseOptions(method));
  ASSERT_TRUE(r.ok) << r.reason << " (matches " << r.initial.matches << ", inliers "
                    << r.initial.inliers << ")";
  const Rigid3d truth = conf.at(dst).inverse() * conf.at(src);
  const double deg = RotationAngleRad(r.target_from_source, truth) * 180 / M_PI;
  const double mm = TranslationDistanceMm(r.target_from_source, truth);
  const double init_deg = RotationAngleRad(r.initial.target_from_source, truth) * 180 / M_PI;
  const double init_mm = TranslationDistanceMm(r.initial.target_from_source, truth);
  std::printf(
      "%s -> %s [%s, used %s]: %d/%d inliers, initial %.2f deg %.2f mm, final %.3f deg %.3f mm "
      "(features %.0f ms, icp %.0f ms)\n",
      src, dst, ToString(method), ToString(r.initial_method), r.initial.inliers, r.initial.matches,
      init_deg, init_mm, deg, mm, r.ms_features, r.ms_icp);
  EXPECT_LE(deg, 1.0);
  EXPECT_LE(mm, 1.0);
}

std::string Name(const ::testing::TestParamInfo<Case>& info) {
  std::string s = std::get<0>(info.param);
  s.append("_to_").append(std::get<1>(info.param)).append("_");
  for (const char* c = ToString(std::get<2>(info.param)); *c; ++c)
    s.push_back(*c == '-' ? '_' : *c);
  return s;
}

constexpr InitialAlignment kFpfh = InitialAlignment::kFpfh;
constexpr InitialAlignment kSift = InitialAlignment::kSift;
constexpr InitialAlignment kBoth = InitialAlignment::kSiftThenFpfh;

INSTANTIATE_TEST_SUITE_P(
    StanfordBunnyFpfh, Bunny,
    ::testing::Values(Case{"bun045", "bun000", kFpfh}, Case{"bun315", "bun000", kFpfh},
                      Case{"bun090", "bun045", kFpfh}, Case{"bun270", "bun315", kFpfh},
                      Case{"bun180", "bun090", kFpfh}, Case{"bun180", "bun270", kFpfh}),
    Name);
INSTANTIATE_TEST_SUITE_P(StanfordBunnySift, Bunny,
                         ::testing::Values(Case{"bun045", "bun000", kSift},
                                           Case{"bun315", "bun000", kSift}),
                         Name);
INSTANTIATE_TEST_SUITE_P(StanfordBunnySiftThenFpfh, Bunny,
                         ::testing::Values(Case{"bun090", "bun045", kBoth}), Name);

}  // namespace
}  // namespace d3d
