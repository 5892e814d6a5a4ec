#include "pipeline/register/odometry.h"

#include <gtest/gtest.h>

#include "pipeline/register/test_surfaces.h"

namespace d3d {
namespace {

using namespace d3d::testing;

class OdometryTest : public ::testing::Test {
 protected:
  OdometryTest() : hf_(31), cam_(TestCamera()) {}
  SyntheticView View(const Rigid3d& pose, uint32_t seed) const {
    return RenderHeightField(hf_, cam_, pose, 0.004, seed);
  }
  SurfacePoints Samples(const SyntheticView& v, int stride = 2) const {
    SurfacePoints s;
    SampleOrganised(v.points, v.normals, v.quality, stride, &s);
    return s;
  }
  HeightField hf_;
  PinholeBrownConrady cam_;
};

TEST(OdometryOptions, CheckRefusesWhatCannotWork) {
  EXPECT_NO_THROW(OdometryOptions().Check());
  OdometryOptions o;
  o.map_max_rmse_ratio = 0.5;  // a gate below the median would keep most views out
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = OdometryOptions();
  o.reregister_first_level = static_cast<int>(o.icp.levels.size());
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = OdometryOptions();
  o.sample_stride = 0;
  EXPECT_THROW(Odometry(TestCamera(), o), std::invalid_argument);
}

TEST(Odometry, SegmentOfAPointIsItsFrameAlongX) {
  EXPECT_EQ(SegmentOfPoint(Eigen::Vector3f(12, -40, 30)), 0);
  EXPECT_EQ(SegmentOfPoint(Eigen::Vector3f(kSegmentSpacingMm - 60, 0, 0)), 1);
  EXPECT_EQ(SegmentOfPoint(Eigen::Vector3f(3 * kSegmentSpacingMm + 60, 0, 0)), 3);
}

// A view registered from a start 0.4 mm and 1° off lands on its true pose, with every association,
// and in a segment's frame 2 m away as well as near the origin.
TEST_F(OdometryTest, RegistersAViewOntoTheModelFromAnOffsetStart) {
  for (const Association association :
       {Association::kGrid, Association::kKdTree, Association::kProjective}) {
    for (const double frame_x_mm : {0.0, 2 * kSegmentSpacingMm}) {
      if (association == Association::kProjective && frame_x_mm != 0)
        continue;  // rendered in float: near the origin only
      OdometryOptions o;
      o.association = association;
      Odometry odometry(cam_, o);
      Rigid3d frame = Rigid3d::Identity();
      frame.translation().x() = frame_x_mm;
      for (double x = -2; x <= 2.01; x += 1) {
        const SyntheticView v = View(LookDown(x, 0, 30), 10 + static_cast<uint32_t>(x + 2));
        odometry.Insert(v.points, v.normals, frame * LookDown(x, 0, 30));
      }
      const Rigid3d truth = frame * LookDown(0.5, 0.3, 30);
      Rigid3d start = truth;
      start.translation() += Eigen::Vector3d(0.3, -0.25, 0.1);
      start.linear() = start.linear() *
                       Eigen::AngleAxisd(M_PI / 180, Eigen::Vector3d::UnitZ()).toRotationMatrix();
      const IcpResult r =
          odometry.Register(Samples(View(LookDown(0.5, 0.3, 30), 99)), start, o.icp);
      ASSERT_TRUE(r.ok) << AssociationName(association) << ": " << r.reason;
      const double tolerance_mm = association == Association::kProjective ? 0.02 : 0.005;
      EXPECT_LT(TranslationDistanceMm(r.target_from_source, truth), tolerance_mm)
          << AssociationName(association) << " x " << frame_x_mm;
      EXPECT_LT(RotationAngleRad(r.target_from_source, truth) * 180 / M_PI, 0.02)
          << AssociationName(association);
    }
  }
}

TEST_F(OdometryTest, ADeferredInsertWaitsForCommit) {
  OdometryOptions o;
  o.defer_model_insert = true;
  Odometry odometry(cam_, o);
  const SyntheticView v = View(LookDown(0, 0, 30), 1);
  odometry.Insert(v.points, v.normals, LookDown(0, 0, 30));
  EXPECT_TRUE(odometry.insert_pending());
  EXPECT_TRUE(odometry.model().empty());
  EXPECT_GE(odometry.Commit(), 0.0);
  EXPECT_FALSE(odometry.insert_pending());
  EXPECT_FALSE(odometry.model().empty());
  const size_t n = odometry.model().size();
  EXPECT_EQ(odometry.Commit(), 0.0);  // nothing pending: nothing inserted
  EXPECT_EQ(odometry.model().size(), n);
}

// The map gate: a residual well above the recent median stays out of the model, but only for
// map_gate_max_run views in a row, only on a view lying mostly on the model, and only once the
// history holds 8 residuals; ForgetResiduals starts the history again.
TEST(OdometryGate, KeepsAnOutlyingResidualOutForAShortRunOnly) {
  OdometryOptions o;  // ratio 1.4, overlap 0.8, run 2
  Odometry odometry(TestCamera(), o);
  auto fit = [](double rmse_mm, double overlap) {
    IcpResult r;
    r.ok = true;
    r.rmse_mm = rmse_mm;
    r.overlap = overlap;
    return r;
  };
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> U(0.010, 0.012);
  double pushed = -1;
  EXPECT_TRUE(odometry.AdmitToModel(IcpResult{}, &pushed));  // the first view: no ICP, always in
  EXPECT_EQ(pushed, -1);
  for (int i = 0; i < 7; ++i) EXPECT_TRUE(odometry.AdmitToModel(fit(U(rng), 0.9), &pushed));
  EXPECT_TRUE(odometry.AdmitToModel(fit(0.030, 0.9), &pushed));  // 7 residuals: no gate yet
  EXPECT_DOUBLE_EQ(pushed, 0.030);
  for (int i = 0; i < 8; ++i) EXPECT_TRUE(odometry.AdmitToModel(fit(U(rng), 0.9), &pushed));
  EXPECT_TRUE(
      odometry.AdmitToModel(fit(0.030, 0.5), &pushed));  // off the model: it must grow there
  EXPECT_FALSE(odometry.AdmitToModel(fit(0.030, 0.9), &pushed));
  EXPECT_FALSE(odometry.AdmitToModel(fit(0.030, 0.9), &pushed));
  EXPECT_TRUE(odometry.AdmitToModel(fit(0.030, 0.9), &pushed));  // the third in a row enters
  EXPECT_TRUE(odometry.AdmitToModel(fit(0.0112, 0.9), &pushed));
  odometry.ForgetResiduals();
  EXPECT_TRUE(odometry.AdmitToModel(fit(0.050, 0.9), &pushed));  // a fresh history: no gate
  // Replayed bookkeeping gates the same way as the views themselves.
  for (int i = 0; i < 8; ++i) odometry.ReplayAdmission(0.011, true);
  EXPECT_FALSE(odometry.AdmitToModel(fit(0.030, 0.9), &pushed));
}

}  // namespace
}  // namespace d3d
