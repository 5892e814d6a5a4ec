// Features on synthetic images with known truth: corners and centres against the projected
// target, and the perspective bias of circle centroids against the projected conic's centre.
#include "calib/features/detect.h"

#include <gtest/gtest.h>

#include "calib/features/synthetic_target.h"

namespace d3d {
namespace {

const PinholeBrownConrady kCam{640, 480, 900, 900, 322.5, 238.0, -0.1, 0.05, 0, 0, 0};

Rigid3d Pose(double ax, double ay, const Eigen::Vector3d& t) {
  Rigid3d p = Rigid3d::Identity();
  p.linear() = (Eigen::AngleAxisd(ax, Eigen::Vector3d::UnitX()) *
                Eigen::AngleAxisd(ay, Eigen::Vector3d::UnitY()))
                   .toRotationMatrix();
  p.translation() = t;
  return p;
}

// Centre of the image of a circle (centre c, radius r on the target plane) in the undistorted
// normalised plane: the pole of the line at infinity w.r.t. the projected dual conic.
Eigen::Vector2d ConicCentre(const Rigid3d& cam_from_target, const Eigen::Vector3d& c, double r) {
  Eigen::Matrix3d H;
  H.col(0) = cam_from_target.linear().col(0);
  H.col(1) = cam_from_target.linear().col(1);
  H.col(2) = cam_from_target.translation();
  Eigen::Matrix3d T = Eigen::Matrix3d::Identity();
  T(0, 2) = c.x();
  T(1, 2) = c.y();
  const Eigen::Matrix3d dual =
      H * T * Eigen::Vector3d(r * r, r * r, -1).asDiagonal() * T.transpose() * H.transpose();
  const Eigen::Vector3d e = dual.col(2);
  return e.head<2>() / e.z();
}

double RmsError(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b) {
  double s = 0;
  for (size_t i = 0; i < a.size(); ++i) s += (a[i] - b[i]).squaredNorm();
  return std::sqrt(s / static_cast<double>(a.size()));
}

TEST(DetectTarget, ChessboardCornersMatchTruth) {
  CalibrationTarget t;
  ASSERT_TRUE(ParseTarget("chessboard:9x6:10", &t).ok());
  const Rigid3d pose = Pose(0.35, -0.25, {-40, -25, 200});
  const cv::Mat img = RenderSyntheticTarget(t, kCam, pose);
  const DetectedFeatures f = DetectTarget(img, t);
  ASSERT_TRUE(f.found) << f.reason;
  std::vector<Eigen::Vector2d> truth, truth_rev;
  for (const auto& p : t.FeaturePoints()) truth.push_back(*kCam.Project(pose * p));
  truth_rev.assign(truth.rbegin(), truth.rend());
  const bool rev = RmsError(f.points_px, truth_rev) < RmsError(f.points_px, truth);
  const auto& ref = rev ? truth_rev : truth;
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (size_t i = 0; i < ref.size(); ++i)
    mean += (f.points_px[i] - ref[i]) / static_cast<double>(ref.size());
  const double rms = RmsError(f.points_px, ref);
  std::printf("chessboard corners vs truth: RMS %.4f px, mean (%.4f, %.4f) px\n", rms, mean.x(),
              mean.y());
  EXPECT_LT(rms, 0.1);  // cornerSubPix on a 45-px square under perspective: a few hundredths
  EXPECT_LT(mean.norm(), 0.03);  // no convention offset (pixel centres at integers)
}

TEST(DetectTarget, CircleCentroidsMatchProjectedConicCentres) {
  for (const char* spec : {"circles:9x7:10:d=5", "circles:4x11:6:asymmetric:d=5"}) {
    CalibrationTarget t;
    ASSERT_TRUE(ParseTarget(spec, &t).ok());
    const Rigid3d pose = Pose(0.5, 0.3, {-35, -35, 180});
    const cv::Mat img = RenderSyntheticTarget(t, kCam, pose);
    const DetectedFeatures f = DetectTarget(img, t);
    ASSERT_TRUE(f.found) << spec << ": " << f.reason;
    ASSERT_EQ(f.blob_area_px.size(), f.points_px.size());
    const auto pts = t.FeaturePoints();
    std::vector<Eigen::Vector2d> centre_truth, point_truth;
    for (const auto& p : pts) {
      const Eigen::Vector2d xy = kCam.Distort(ConicCentre(pose, p, 0.5 * t.circle_diameter_mm));
      centre_truth.emplace_back(kCam.fx * xy.x() + kCam.cx, kCam.fy * xy.y() + kCam.cy);
      point_truth.push_back(*kCam.Project(pose * p));
    }
    // Try the detector's order and its reverse (a grid seen upside down).
    std::vector<Eigen::Vector2d> rev(centre_truth.rbegin(), centre_truth.rend()),
        prev(point_truth.rbegin(), point_truth.rend());
    const bool reversed = RmsError(f.points_px, rev) < RmsError(f.points_px, centre_truth);
    const double rms_centre = RmsError(f.points_px, reversed ? rev : centre_truth);
    const double rms_point = RmsError(f.points_px, reversed ? prev : point_truth);
    EXPECT_LT(rms_centre, 0.03) << spec;
    // The perspective bias is real at this tilt: the plain projection of the centre is farther.
    EXPECT_GT(rms_point, 2.0 * rms_centre) << spec;
  }
}

TEST(DetectTarget, NotFoundIsAReasonNotACrash) {
  CalibrationTarget t;
  ASSERT_TRUE(ParseTarget("chessboard:9x6:10", &t).ok());
  const DetectedFeatures f = DetectTarget(cv::Mat(480, 640, CV_8U, cv::Scalar(100)), t);
  EXPECT_FALSE(f.found);
  EXPECT_NE(f.reason.find("not found"), std::string::npos);
  // A wrong target size on a real board image is not found either.
  CalibrationTarget wrong;
  ASSERT_TRUE(ParseTarget("chessboard:8x6:10", &wrong).ok());
  const cv::Mat img = RenderSyntheticTarget(t, kCam, Pose(0.2, 0.1, {-40, -25, 200}));
  EXPECT_FALSE(DetectTarget(img, wrong).found);
  EXPECT_THROW(DetectTarget(cv::Mat(10, 10, CV_32F), t), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
