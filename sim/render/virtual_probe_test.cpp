#include "sim/render/virtual_probe.h"

#include <gtest/gtest.h>

#include <cmath>
#include <complex>
#include <cstring>

#include "sim/render/test_scenes.h"

namespace d3d {
namespace {

// A plane through `point` with unit normal `n` (world = probe frame at the identity pose),
// as a large quad; tilted so depth and projector coordinate vary over the image.
struct Plane {
  Eigen::Vector3d n;
  Eigen::Vector3d point;
};

TriangleMesh PlaneMesh(const Plane& p) { return ::d3d::PlaneMesh(p.n, p.point); }

RenderOptions Ideal() {  // every effect off: the bare photometric model
  RenderOptions o;
  o.noise = false;
  o.gamma = false;
  o.camera_defocus = false;
  o.projector_defocus = false;
  o.subsurface = false;
  o.specular = false;
  o.texture = false;
  return o;
}

PoseAtTime Static(const Rigid3d& pose) {
  return [pose](int64_t) { return pose; };
}

const Plane kTilted{Eigen::Vector3d(0.25, -0.15, -1.0).normalized(),
                    Eigen::Vector3d(0.0, 0.0, 50.0)};

// Checks every surface pixel's truth against an analytic intersection `surface(ray) → X`.
template <typename Surface>
void ExpectTruthMatchesAnalytic(VirtualProbe& probe, Surface&& surface, int* checked) {
  FrameTruth truth;
  probe.RenderTruth(Rigid3d::Identity(), &truth);
  const auto& calib = probe.calibration();
  const Rigid3d proj_from_cam = calib.cam_from_proj.inverse();
  double worst_depth = 0, worst_uv = 0, worst_reproj = 0;
  for (int r = 0; r < truth.depth_mm.rows; r += 3)
    for (int c = 0; c < truth.depth_mm.cols; c += 3) {
      const auto ray = calib.camera.PixelRay(Eigen::Vector2d(c, r));
      ASSERT_TRUE(ray.has_value());
      const std::optional<Eigen::Vector3d> X = surface(*ray);
      const float depth = truth.depth_mm.at<float>(r, c);
      ASSERT_EQ(X.has_value(), !std::isnan(depth)) << r << "," << c;
      if (!X) continue;
      ++*checked;
      worst_depth = std::max(worst_depth, std::abs(depth - X->z()));
      const cv::Vec3f p = truth.points_in_cam.at<cv::Vec3f>(r, c);
      worst_reproj = std::max(
          worst_reproj,
          (*calib.camera.Project(Eigen::Vector3d(p[0], p[1], p[2])) - Eigen::Vector2d(c, r))
              .norm());
      if (truth.visibility.at<uint8_t>(r, c) == 2) {
        const auto uv = calib.projector.Project(proj_from_cam * *X);
        const cv::Vec2f t = truth.projector_uv.at<cv::Vec2f>(r, c);
        worst_uv = std::max(worst_uv, (*uv - Eigen::Vector2d(t[0], t[1])).norm());
      }
    }
  EXPECT_LT(worst_depth, 1e-4) << "mm";
  EXPECT_LT(worst_uv, 1e-4) << "projector px";
  EXPECT_LT(worst_reproj, 1e-3) << "camera px (float32 storage of the points)";
}

TEST(VirtualProbeTruth, PlaneMatchesAnalyticDepthAndProjectorCoordinate) {
  VirtualProbe probe(PlaneMesh(kTilted), MakeDefaultProbeDesign(), Ideal());
  int checked = 0;
  ExpectTruthMatchesAnalytic(
      probe,
      [](const Eigen::Vector3d& ray) -> std::optional<Eigen::Vector3d> {
        const double t = kTilted.n.dot(kTilted.point) / kTilted.n.dot(ray);
        return ray * t;
      },
      &checked);
  EXPECT_GT(checked, 30000);
}

TEST(VirtualProbeTruth, SphereMatchesAnalyticDepthAndProjectorCoordinate) {
  const Eigen::Vector3d centre(0.8, -0.5, 54.0);
  const double radius = 4.5;
  TriangleMesh far_wall = PlaneMesh({Eigen::Vector3d(0, 0, -1), Eigen::Vector3d(0, 0, 90)});
  VirtualProbe probe(far_wall, MakeDefaultProbeDesign(), Ideal(),
                     {SceneSphere{centre, radius, SurfaceLabel::kTooth}});
  int checked = 0;
  ExpectTruthMatchesAnalytic(
      probe,
      [&](const Eigen::Vector3d& ray) -> std::optional<Eigen::Vector3d> {
        const double a = ray.squaredNorm(), b = -ray.dot(centre),
                     c = centre.squaredNorm() - radius * radius;
        const double disc = b * b - a * c;
        if (disc < 0) return ray * (90.0 / ray.z());  // the wall behind
        return ray * ((-b - std::sqrt(disc)) / a);
      },
      &checked);
  EXPECT_GT(checked, 8000);
  // Part of the wall lies in the sphere's projector shadow: visible but not lit.
  FrameTruth truth;
  probe.RenderTruth(Rigid3d::Identity(), &truth);
  EXPECT_GT(cv::countNonZero(truth.visibility == 1), 1000);
}

// The photometric model, term by term, on a uniformly lit tilted plane.
TEST(VirtualProbePhotometry, UniformFramesFollowTheModelWithAndWithoutGamma) {
  const ProbeDesign design = MakeDefaultProbeDesign();
  for (bool gamma : {false, true}) {
    RenderOptions o = Ideal();
    o.gamma = gamma;
    VirtualProbe probe(PlaneMesh(kTilted), design, o);
    const ProjectorFrame grey{"grey", 'x', std::vector<uint8_t>(912, 160)};
    BurstFrame f;
    probe.RenderFrame(Static(Rigid3d::Identity()), 0, grey, 1, true, &f);
    const Eigen::Vector3d proj_centre = design.calibration.cam_from_proj.translation();
    const double p = std::pow(160.0 / 255.0, gamma ? design.calibration.projector_gamma : 1.0);
    EXPECT_EQ(probe.calibration().projector_gamma, gamma ? 2.2 : 1.0);
    int n = 0;
    double worst = 0;
    for (int r = 5; r < 475; r += 7)
      for (int c = 5; c < 635; c += 7) {
        if (f.truth.visibility.at<uint8_t>(r, c) != 2) continue;
        const cv::Vec3f pc = f.truth.points_in_cam.at<cv::Vec3f>(r, c);
        const Eigen::Vector3d X(pc[0], pc[1], pc[2]);
        const Eigen::Vector3d to_proj = proj_centre - X;
        const double d = to_proj.norm();
        const double cos_i = std::abs(kTilted.n.dot(to_proj / d));
        const double cos_a = X.z() / X.norm();
        const double S = std::pow(cos_a, 4) * design.enamel.albedo *
                         (design.optics.ambient_irradiance +
                          design.optics.projector_irradiance * cos_i *
                              std::pow(design.optics.projector_focus_mm / d, 2) * p);
        worst = std::max(worst, std::abs(f.image.at<uint8_t>(r, c) - S * 255.0));
        ++n;
      }
    EXPECT_GT(n, 3000);
    EXPECT_LE(worst, 0.5 + 1e-3) << "DN, gamma " << gamma;  // quantisation only
  }
}

// 4-step phase φ of a pixel of the rendered burst (frames 0..3).
double FourStepPhase(const Burst& b, int r, int c) {
  double s = 0, co = 0;
  for (int k = 0; k < 4; ++k) {
    const double I = b.frames[k].image.at<uint8_t>(r, c);
    s += I * std::sin(M_PI / 2 * k);
    co += I * std::cos(M_PI / 2 * k);
  }
  return std::atan2(s, co);
}

// The 4-step phase error that a pure power law p^γ leaves at absolute phase Φ (no blur).
double PredictedGammaError(double gamma, double Phi) {
  double s = 0, co = 0;
  for (int k = 0; k < 4; ++k) {
    const double I = std::pow(0.5 + 0.5 * std::cos(Phi - M_PI / 2 * k), gamma);
    s += I * std::sin(M_PI / 2 * k);
    co += I * std::cos(M_PI / 2 * k);
  }
  return std::remainder(std::atan2(s, co) - Phi, 2 * M_PI);
}

TEST(VirtualProbePhotometry, FringesEncodeTheProjectorCoordinateAndGammaDistortsThemAsPredicted) {
  const ProbeDesign design = MakeDefaultProbeDesign();
  const auto& spec = design.calibration.pattern;
  for (double gamma : {1.0, 2.2, 2.8}) {
    ProbeDesign d = design;
    d.calibration.projector_gamma = gamma;
    RenderOptions o = Ideal();
    o.gamma = gamma != 1.0;
    o.projector_defocus = true;  // blur smooths the DMD's pixel steps, as in a real projector
    VirtualProbe probe(PlaneMesh(kTilted), d, o);
    const Burst b = probe.RenderBurst(Static(Rigid3d::Identity()), 0, 0, 1, true);
    ASSERT_EQ(b.frames.size(), 4u);  // 4 fringe frames (texture = their mean)
    double err2 = 0, residual2 = 0, predicted2 = 0;
    int n = 0;
    for (int r = 10; r < 470; r += 2)
      for (int c = 10; c < 630; c += 2) {
        if (b.frames[0].truth.visibility.at<uint8_t>(r, c) != 2) continue;
        const double u = b.frames[0].truth.projector_uv.at<cv::Vec2f>(r, c)[0];
        if (spec.InMarker(u - 2) || spec.InMarker(u + 2)) continue;
        const double Phi = spec.AbsolutePhase(u);
        const double err = std::remainder(FourStepPhase(b, r, c) - Phi, 2 * M_PI);
        const double predicted = o.gamma ? PredictedGammaError(gamma, Phi) : 0.0;
        err2 += err * err;
        residual2 += (err - predicted) * (err - predicted);
        predicted2 += predicted * predicted;
        ++n;
      }
    ASSERT_GT(n, 50000);
    const double rms = std::sqrt(err2 / n), residual = std::sqrt(residual2 / n),
                 predicted = std::sqrt(predicted2 / n);
    // What is left beyond the gamma error: 8-bit DMD and camera quantisation (≈ 0.003 rad).
    EXPECT_LT(residual, 0.005) << "gamma " << gamma << ": rms " << rms << " predicted "
                               << predicted;
    if (gamma == 2.8) {
      EXPECT_GT(rms, 0.02) << "a strong gamma must show its phase error";
    }
  }
}

TEST(VirtualProbePhotometry, MarkerStripeBreaksFourStepConsistencyOnly) {
  VirtualProbe probe(PlaneMesh(kTilted), MakeDefaultProbeDesign(), Ideal());
  const Burst b = probe.RenderBurst(Static(Rigid3d::Identity()), 0, 0, 1, true);
  const auto& spec = probe.calibration().pattern;
  double in = 0, out = 0;
  int n_in = 0, n_out = 0;
  for (int r = 0; r < 480; r += 2)
    for (int c = 0; c < 640; c += 2) {
      if (b.frames[0].truth.visibility.at<uint8_t>(r, c) != 2) continue;
      const double u = b.frames[0].truth.projector_uv.at<cv::Vec2f>(r, c)[0];
      auto I = [&](int k) { return static_cast<double>(b.frames[k].image.at<uint8_t>(r, c)); };
      const double residual = std::abs(I(0) + I(2) - I(1) - I(3));
      const double amplitude = I(0) + I(2);  // 2·ambient + the full projector signal
      if (spec.InMarker(u - 1.5) && spec.InMarker(u + 1.5)) {
        in += residual / amplitude;
        ++n_in;
      } else if (!spec.InMarker(u - 3) && !spec.InMarker(u + 3)) {
        out += residual / amplitude;
        ++n_out;
      }
    }
  ASSERT_GT(n_in, 500);
  EXPECT_NEAR(in / n_in, 0.5, 0.06);
  EXPECT_LT(out / n_out, 0.02);
}

TEST(VirtualProbeNoise, StatisticsMatchShotReadAndQuantisation) {
  RenderOptions o = Ideal();
  o.noise = true;
  const ProbeDesign design = MakeDefaultProbeDesign();
  VirtualProbe probe(PlaneMesh({Eigen::Vector3d(0, 0, -1), Eigen::Vector3d(0, 0, 50)}), design, o);
  const ProjectorFrame grey{"grey", 'x', std::vector<uint8_t>(912, 100)};
  // Noise-free reference from the model, then 40 noisy realisations.
  RenderOptions clean = Ideal();
  VirtualProbe reference(PlaneMesh({Eigen::Vector3d(0, 0, -1), Eigen::Vector3d(0, 0, 50)}), design,
                         clean);
  const cv::Rect roi(200, 150, 100, 80);
  constexpr int kRuns = 40;
  cv::Mat sum(roi.size(), CV_64F, cv::Scalar(0)), sum2(roi.size(), CV_64F, cv::Scalar(0));
  cv::Mat first;
  for (int k = 0; k < kRuns; ++k) {
    BurstFrame f;
    probe.RenderFrame(Static(Rigid3d::Identity()), 0, grey, 1000 + k, false, &f);
    cv::Mat x;
    f.image(roi).convertTo(x, CV_64F);
    sum += x;
    sum2 += x.mul(x);
    if (k == 0) first = f.image.clone();
  }
  // The signal S of each pixel, from a noise-free float render is not exposed; use the model's
  // mean: E[DN] ≈ S·255 and Var[DN] = (S·FW + σ_r²)·(255/FW)² + 1/12.
  const double gain = 255.0 / design.sensor.full_well_e;
  double ratio_sum = 0, mean_err = 0;
  int n = 0;
  BurstFrame ref;
  reference.RenderFrame(Static(Rigid3d::Identity()), 0, grey, 1, true, &ref);
  for (int r = 0; r < roi.height; ++r)
    for (int c = 0; c < roi.width; ++c) {
      const double mean = sum.at<double>(r, c) / kRuns;
      const double var = (sum2.at<double>(r, c) - kRuns * mean * mean) / (kRuns - 1);
      const double S_dn = ref.image(roi).at<uint8_t>(r, c);  // noise-free, ±0.5 DN
      const double expected_var =
          (S_dn / gain + std::pow(design.sensor.read_noise_e, 2)) * gain * gain + 1.0 / 12;
      ratio_sum += var / expected_var;
      mean_err += mean - S_dn;
      ++n;
    }
  EXPECT_NEAR(ratio_sum / n, 1.0, 0.08) << "variance measured / expected";
  EXPECT_NEAR(mean_err / n, 0.0, 0.3) << "DN bias";
  // Determinism: the same seed gives the same image, another seed another one.
  BurstFrame again, other;
  probe.RenderFrame(Static(Rigid3d::Identity()), 0, grey, 1000, false, &again);
  probe.RenderFrame(Static(Rigid3d::Identity()), 0, grey, 1001, false, &other);
  EXPECT_EQ(cv::norm(first, again.image, cv::NORM_INF), 0.0);
  EXPECT_GT(cv::norm(first, other.image, cv::NORM_L1), 0.0);
}

TEST(VirtualProbeNoise, IdenticalOutputForAnyThreadCount) {
  RenderOptions one;
  one.threads = 1;
  RenderOptions two;
  two.threads = 2;
  const TriangleMesh plane = PlaneMesh(kTilted);
  VirtualProbe a(plane, MakeDefaultProbeDesign(), one), b(plane, MakeDefaultProbeDesign(), two);
  const Burst x = a.RenderBurst(Static(Rigid3d::Identity()), 0, 7, 42, false);
  const Burst y = b.RenderBurst(Static(Rigid3d::Identity()), 0, 7, 42, false);
  for (size_t i = 0; i < x.frames.size(); ++i)
    EXPECT_EQ(cv::norm(x.frames[i].image, y.frames[i].image, cv::NORM_INF), 0.0);
}

// Moving probe: each frame has its own pose, and motion blur within the exposure averages the
// fringe over the phases it sweeps (modulation × |mean of e^{iφ_k}| over the sub-exposures).
bool SameBytes(const cv::Mat& a, const cv::Mat& b) {  // NaN included
  return a.size() == b.size() && a.type() == b.type() && a.isContinuous() && b.isContinuous() &&
         std::memcmp(a.data, b.data, a.total() * a.elemSize()) == 0;
}

// A still probe's frames reuse one geometry pass (bit-identical poses); the reuse must give the
// bits of frames rendered by a probe that moved (other poses, a truth-only pass) in between.
TEST(VirtualProbeReuse, AStillProbeRendersTheBitsOfAProbeThatMovedInBetween) {
  const TriangleMesh plane = PlaneMesh(kTilted);
  const Rigid3d still = Rigid3d::Identity();
  Rigid3d other = Rigid3d::Identity();
  other.translation() = Eigen::Vector3d(0.3, -0.2, 1.0);
  VirtualProbe a(plane, MakeDefaultProbeDesign(), RenderOptions{}),
      b(plane, MakeDefaultProbeDesign(), RenderOptions{});
  const Burst x = a.RenderBurst(Static(still), 0, 7, 42, true);
  for (size_t i = 0; i < x.frames.size(); ++i) {
    FrameTruth elsewhere;
    b.RenderTruth(other, &elsewhere);  // a truth-only pass at another pose
    BurstFrame f;
    b.RenderFrame(Static(other), 0, b.burst_patterns().frames[(i + 1) % x.frames.size()], 1, false,
                  &f);
    b.RenderFrame(Static(still), x.frames[i].timestamp_ns, b.burst_patterns().frames[i],
                  FrameNoiseSeed(42, 7, static_cast<int>(i)), true, &f);
    EXPECT_TRUE(SameBytes(x.frames[i].image, f.image)) << i;
    EXPECT_TRUE(SameBytes(x.frames[i].truth.points_in_cam, f.truth.points_in_cam)) << i;
  }
  FrameTruth reference;
  b.RenderTruth(still, &reference);  // after a shaded pass at that pose: reused
  EXPECT_TRUE(SameBytes(x.reference_truth.projector_uv, reference.projector_uv));
  EXPECT_TRUE(SameBytes(x.reference_truth.visibility, reference.visibility));
}

TEST(VirtualProbeMotion, FramesHaveTheirOwnPosesAndMotionBlurAttenuatesAsPredicted) {
  // The fringes travel with the probe, so only depth changes move them on a plane: move along z,
  // 150 mm/s with an 8 ms exposure (a deliberate, large blur: ~2.8 rad swept).
  const double speed_mm_per_ns = 150.0 * 1e-9;
  const PoseAtTime moving = [&](int64_t t) {
    Rigid3d p = Rigid3d::Identity();
    p.translation() = Eigen::Vector3d(0, 0, speed_mm_per_ns * static_cast<double>(t));
    return p;
  };
  const TriangleMesh plane = PlaneMesh({Eigen::Vector3d(0, 0, -1), Eigen::Vector3d(0, 0, 50)});
  ProbeDesign design = MakeDefaultProbeDesign();
  design.sensor.exposure_ns = 8'000'000;
  RenderOptions sharp_opt = Ideal();
  RenderOptions blur_opt = Ideal();
  blur_opt.motion_blur_samples = 16;
  VirtualProbe sharp(plane, design, sharp_opt), blurred(plane, design, blur_opt);
  const int64_t t0 = -5'000'000;  // the plane at ≈ 50 mm during the burst
  const Burst a = sharp.RenderBurst(moving, t0, 0, 1, true);
  const Burst b = blurred.RenderBurst(moving, t0, 0, 1, true);
  for (size_t i = 0; i < a.frames.size(); ++i) {
    EXPECT_EQ(a.frames[i].timestamp_ns, t0 + static_cast<int64_t>(i) * 2'500'000);
    EXPECT_NEAR(a.frames[i].truth.world_from_probe.translation().z(),
                speed_mm_per_ns * a.frames[i].timestamp_ns, 1e-12);
  }
  // Predicted attenuation from the truth: phase swept by a pixel during the exposure.
  const int r = 240, c = 320;
  const auto& spec = design.calibration.pattern;
  const int64_t e = design.sensor.exposure_ns;
  std::complex<double> mean(0, 0);
  for (int s = 0; s < 16; ++s) {
    FrameTruth t;
    blurred.RenderTruth(moving(t0 + static_cast<int64_t>(std::llround(e * ((s + 0.5) / 16 - 0.5)))),
                        &t);
    mean += std::polar(1.0, spec.AbsolutePhase(t.projector_uv.at<cv::Vec2f>(r, c)[0])) / 16.0;
  }
  const double predicted = std::abs(mean);
  ASSERT_LT(predicted, 0.9) << "the test must sweep a sizeable phase";
  // Measured modulation (4-step amplitude) in a window around the pixel, blurred / sharp.
  auto modulation = [&](const Burst& burst) {
    double acc = 0;
    int n = 0;
    for (int rr = r - 10; rr <= r + 10; ++rr)
      for (int cc = c - 10; cc <= c + 10; ++cc) {
        const double u = burst.frames[0].truth.projector_uv.at<cv::Vec2f>(rr, cc)[0];
        if (spec.InMarker(u - 3) || spec.InMarker(u + 3)) continue;
        double s = 0, co = 0;
        for (int k = 0; k < 4; ++k) {
          const double I = burst.frames[k].image.at<uint8_t>(rr, cc);
          s += I * std::sin(M_PI / 2 * k);
          co += I * std::cos(M_PI / 2 * k);
        }
        acc += std::hypot(s, co) / 2;
        ++n;
      }
    return acc / n;
  };
  EXPECT_NEAR(modulation(b) / modulation(a), predicted, 0.03);
}

TEST(VirtualProbeOptions, ChecksRefuseNonsense) {
  RenderOptions o;
  o.motion_blur_samples = 0;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  EXPECT_THROW(MakeDefaultProbeDesign(800, 600), std::invalid_argument);
  ProbeDesign d = MakeDefaultProbeDesign();
  d.optics.camera_pupil_mm = 0;
  EXPECT_THROW(VirtualProbe(PlaneMesh(kTilted), d, RenderOptions{}), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
