#include "calib/model/probe_calibration.h"

#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>

namespace d3d {
namespace {

ProbeCalibration TestCalibration() {
  ProbeCalibration c;
  c.camera = {640, 480, 2000, 2000, 319.5, 239.5, -0.05, 0.1, 0.0002, -0.0001, 0.0};
  c.projector = {912, 1140, 2280, 2280, 455.5, 569.5, 0.02, 0.0, 0.0, 0.0, 0.0};
  c.cam_from_proj = Rigid3d::Identity();
  c.cam_from_proj.linear() =
      Eigen::AngleAxisd(-12.0 * M_PI / 180.0, Eigen::Vector3d::UnitY()).toRotationMatrix();
  c.cam_from_proj.translation() = Eigen::Vector3d(10.63, 0, 0);
  c.depth_min_mm = 42;
  c.depth_max_mm = 58;
  c.projector_gamma = 2.2;
  c.source = "test";
  return c;
}

TEST(ProbeCalibration, JsonRoundTripIsExact) {
  const ProbeCalibration c = TestCalibration();
  ProbeCalibration back;
  ASSERT_TRUE(ProbeCalibration::FromJson(c.ToJson(), &back).ok());
  EXPECT_EQ(back.camera.fx, c.camera.fx);
  EXPECT_EQ(back.camera.k2, c.camera.k2);
  EXPECT_EQ(back.projector.height, 1140);
  EXPECT_TRUE(back.cam_from_proj.isApprox(c.cam_from_proj, 1e-15));
  EXPECT_EQ(back.pattern.fringe_period_px, c.pattern.fringe_period_px);
  EXPECT_EQ(back.projector_gamma, 2.2);
  EXPECT_EQ(back.pattern.marker_spacing_orders, c.pattern.marker_spacing_orders);
  EXPECT_NEAR(back.TriangulationAngleRad() * 180 / M_PI, 12.0, 1e-9);
}

TEST(ProbeCalibration, RefusesMalformedAndNewerFiles) {
  ProbeCalibration out;
  EXPECT_EQ(ProbeCalibration::FromJson("{not json", &out).code(), StatusCode::kParseError);
  EXPECT_EQ(ProbeCalibration::FromJson("{}", &out).code(), StatusCode::kParseError);
  auto j = nlohmann::json::parse(TestCalibration().ToJson());
  j["version"] = 99;
  EXPECT_EQ(ProbeCalibration::FromJson(j.dump(), &out).code(), StatusCode::kUnsupported);
  j = nlohmann::json::parse(TestCalibration().ToJson());
  j["camera"]["distortion"] = {0.1, 0.2};
  const Status s = ProbeCalibration::FromJson(j.dump(), &out);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message().find("distortion"), std::string::npos) << s.ToString();
  j = nlohmann::json::parse(TestCalibration().ToJson());
  j["measurement_volume"]["depth_max_mm"] = 10;
  EXPECT_EQ(ProbeCalibration::FromJson(j.dump(), &out).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(ProbeCalibration::Load("/nonexistent/calibration.json", &out).code(),
            StatusCode::kNotFound);
}

// Issue 55: a field missing or of the wrong kind is named by its path, never by the JSON library's
// own text; a missing projector gamma is an error (read as 1 it gave no point, silently); lengths
// in another unit than mm are refused, not misread.
TEST(ProbeCalibration, NamesTheFieldThatIsMissingOrWrong) {
  ProbeCalibration out;
  const auto refused = [&](const nlohmann::json& j, const std::string& says) {
    const Status s = ProbeCalibration::FromJson(j.dump(), &out);
    EXPECT_EQ(s.code(), StatusCode::kParseError) << s.ToString();
    EXPECT_NE(s.message().find(says), std::string::npos) << s.ToString();
    EXPECT_EQ(s.message().find("json.exception"), std::string::npos) << s.ToString();
  };
  const nlohmann::json good = nlohmann::json::parse(TestCalibration().ToJson());
  nlohmann::json j = good;
  j.erase("projector_gamma");
  refused(j, "projector_gamma is missing");
  j = good;
  j["projector"].erase("K");
  refused(j, "projector.K is missing");
  j = good;
  j["camera"]["K"][0][2] = "319.5";
  refused(j, "camera.K[0][2] must be a number");
  j = good;
  j["units"]["length"] = "m";
  refused(j, "units.length is 'm'");
  j = good;
  j["pattern"]["marker"].erase("frame");
  refused(j, "pattern.marker.frame is missing");
  const Status bad_json = ProbeCalibration::FromJson("{\"format\": ", &out);
  EXPECT_NE(bad_json.message().find("not valid JSON (at byte"), std::string::npos)
      << bad_json.ToString();
}

TEST(FringePattern, PhaseShiftFramesRecoverTheAbsolutePhase) {
  FringePatternSpec p;
  p.marker_frame = -1;
  for (double c = 0; c < 200; c += 0.37) {
    double s = 0, co = 0;
    for (int n = 0; n < p.steps; ++n) {
      const double d = 2 * M_PI * n / p.steps;
      s += p.PatternValue(n, c) * std::sin(d);
      co += p.PatternValue(n, c) * std::cos(d);
    }
    const double phi = std::atan2(s, co);
    const double expected = std::remainder(p.AbsolutePhase(c), 2 * M_PI);
    EXPECT_NEAR(std::remainder(phi - expected, 2 * M_PI), 0.0, 1e-12) << c;
  }
}

TEST(FringePattern, MarkerResidualIsHalfInStripesAndZeroElsewhere) {
  FringePatternSpec p;  // 4 steps, marker in frame 3, orders 4, 14, 24, ...
  int in_marker = 0;
  for (double c = 0.25; c < 912; c += 0.5) {
    const double r =
        p.PatternValue(0, c) + p.PatternValue(2, c) - p.PatternValue(1, c) - p.PatternValue(3, c);
    const long k = static_cast<long>(std::floor(c / p.fringe_period_px));
    const bool expected = k >= 4 && (k - 4) % 10 == 0;
    EXPECT_EQ(p.InMarker(c), expected) << c;
    if (expected) {
      ++in_marker;
      EXPECT_NEAR(std::abs(r), 0.5, 1e-12) << c;
    } else {
      EXPECT_NEAR(r, 0.0, 1e-12) << c;
    }
  }
  EXPECT_EQ(in_marker, 4 * 48);  // 4 stripes (orders 4, 14, 24, 34) of 24 px at 0.5 px steps
  p.marker_width_periods = 0.5;
  EXPECT_TRUE(p.InMarker(4 * 24 + 12));
  EXPECT_FALSE(p.InMarker(4 * 24 + 2));
}

}  // namespace
}  // namespace d3d
