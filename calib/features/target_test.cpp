#include "calib/features/target.h"

#include <gtest/gtest.h>

namespace d3d {
namespace {

TEST(CalibrationTarget, ParsesAllForms) {
  CalibrationTarget t;
  ASSERT_TRUE(ParseTarget("chessboard:9x6:25", &t).ok());
  EXPECT_EQ(t.kind, TargetKind::kChessboard);
  EXPECT_EQ(t.cols, 9);
  EXPECT_EQ(t.rows, 6);
  EXPECT_DOUBLE_EQ(t.spacing_mm, 25.0);
  ASSERT_TRUE(ParseTarget("circles:9x7:1.2:d=0.6", &t).ok());
  EXPECT_EQ(t.kind, TargetKind::kCircleGrid);
  EXPECT_DOUBLE_EQ(t.circle_diameter_mm, 0.6);
  ASSERT_TRUE(ParseTarget("circles:4x11:2:asymmetric", &t).ok());
  EXPECT_EQ(t.kind, TargetKind::kAsymmetricCircleGrid);
  CalibrationTarget back;
  ASSERT_TRUE(ParseTarget(t.ToString(), &back).ok());
  EXPECT_EQ(back.ToString(), t.ToString());
}

TEST(CalibrationTarget, RejectsBadSpecsWithReason) {
  CalibrationTarget t;
  for (const char* bad : {"chessboard:9x6", "board:9x6:1", "chessboard:9by6:1", "chessboard:9x6:-1",
                          "chessboard:2x2:1", "circles:9x7:1:d=1.5", "circles:9x7:1:triangular",
                          "chessboard:9x6:1:asymmetric"}) {
    const Status s = ParseTarget(bad, &t);
    EXPECT_FALSE(s.ok()) << bad;
    EXPECT_NE(s.message().find(bad), std::string::npos) << s.message();
  }
}

TEST(CalibrationTarget, FeatureLayoutsFollowOpenCv) {
  CalibrationTarget t;
  ASSERT_TRUE(ParseTarget("circles:4x11:1:asymmetric", &t).ok());
  const auto p = t.FeaturePoints();
  ASSERT_EQ(p.size(), 44u);
  EXPECT_EQ(p[1], Eigen::Vector3d(2, 0, 0));  // row 0: x = 2c
  EXPECT_EQ(p[4], Eigen::Vector3d(1, 1, 0));  // row 1: x = 2c + 1
  EXPECT_NEAR(t.NearestFeatureDistanceMm(), std::sqrt(2.0), 1e-12);
  ASSERT_TRUE(ParseTarget("chessboard:9x6:2", &t).ok());
  const auto q = t.FeaturePoints();
  EXPECT_EQ(q[10], Eigen::Vector3d(2, 2, 0));  // row 1, col 1
  const auto [lo, hi] = t.FeatureBounds();
  EXPECT_EQ(hi, Eigen::Vector2d(16, 10));
  EXPECT_EQ(lo, Eigen::Vector2d(0, 0));
}

}  // namespace
}  // namespace d3d
