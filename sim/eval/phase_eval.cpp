#include "sim/eval/phase_eval.h"

#include <cmath>
#include <cstdio>
#include <memory>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "sim/session/sim_session.h"

namespace d3d::phase_eval {
namespace {

constexpr double kMinPeriodPx = 8.0;

TriangleMesh PlaneMesh(const Eigen::Vector3d& n, const Eigen::Vector3d& point, double half = 80.0) {
  const Eigen::Vector3d a = n.unitOrthogonal(), b = n.cross(a);
  TriangleMesh m;
  m.vertices = {point - half * a - half * b, point + half * a - half * b,
                point + half * a + half * b, point - half * a + half * b};
  m.faces = {{0, 1, 2}, {0, 2, 3}};
  m.face_labels = {SurfaceLabel::kTooth, SurfaceLabel::kTooth};
  return m;
}

}  // namespace

Burst RenderScene(const RenderSpec& spec, ProbeCalibration* calibration) {
  ProbeDesign design = MakeDefaultProbeDesign();
  design.calibration.projector_gamma = spec.projector_gamma;
  RenderOptions o;
  o.noise = spec.noise;
  o.gamma = true;
  o.threads = 2;
  const PoseAtTime identity = [](int64_t) { return Rigid3d::Identity(); };
  std::unique_ptr<VirtualProbe> probe;
  PoseAtTime pose = identity;
  if (spec.scene == "plane") {
    probe = std::make_unique<VirtualProbe>(
        PlaneMesh(Eigen::Vector3d(0.25, -0.15, -1.0).normalized(), Eigen::Vector3d(0, 0, 50)),
        design, o);
  } else if (spec.scene == "sphere") {
    probe = std::make_unique<VirtualProbe>(
        PlaneMesh(Eigen::Vector3d(0.1, 0.05, -1.0).normalized(), Eigen::Vector3d(0, 0, 57)), design,
        o, std::vector<SceneSphere>{{Eigen::Vector3d(0.8, -0.5, 50.0), 4.5, SurfaceLabel::kTooth}});
  } else if (spec.scene == "typodont") {
    static std::unique_ptr<SimSession> session;  // the arch and its scan path, built once
    if (!session) {
      SimSessionOptions so;
      so.render.threads = 2;
      const Status st = SimSession::Create(so, &session);
      if (!st.ok()) throw std::runtime_error(st.ToString());
    }
    const Rigid3d at =
        session->trajectory().WorldFromProbe(session->BurstStartNs(spec.typodont_index));
    pose = [at](int64_t) { return at; };
    probe = std::make_unique<VirtualProbe>(session->scene(), design, o);
  } else {
    throw std::invalid_argument("unknown scene " + spec.scene);
  }
  *calibration = probe->calibration();
  return probe->RenderBurst(pose, 0, 0, spec.seed, true);
}

Evaluation Evaluate(const Burst& burst, const ProbeCalibration& calibration,
                    const PhaseOptions& base) {
  const FringePatternSpec& spec = calibration.pattern;
  std::vector<cv::Mat> frames;
  for (int n = 0; n < spec.steps; ++n) frames.push_back(burst.frames[n].image);
  const FrameTruth& truth = burst.frames[0].truth;
  cv::Mat lit = truth.visibility == 2;
  cv::erode(lit, lit, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(5, 5)));

  Evaluation ev;
  std::vector<PhaseMaps> maps;
  for (auto a :
       {PhaseAlgorithm::kStandard, PhaseAlgorithm::kLutGamma, PhaseAlgorithm::kAdaptiveHarmonic}) {
    PhaseOptions o = base;
    o.algorithm = a;
    maps.emplace_back();
    const Status st = ComputePhase(frames, spec, calibration.projector_gamma, o, &maps.back());
    if (!st.ok()) throw std::runtime_error(st.ToString());
  }
  const int axis = spec.axis == 'y' ? 1 : 0;
  std::vector<double> s2_out(3, 0), s2_in(3, 0);
  int n_out = 0, n_in = 0, core = 0, core_hit = 0, outside = 0, outside_hit = 0, edge = 0,
      edge_hit = 0;
  double kappa_sum = 0;
  const PhaseMaps& ours = maps[2];
  for (int y = 0; y < lit.rows; ++y)
    for (int x = 0; x < lit.cols; ++x) {
      if (!lit.at<uint8_t>(y, x)) continue;
      bool valid = true;
      for (const auto& m : maps) valid = valid && m.valid.at<uint8_t>(y, x);
      if (!valid) continue;
      const double c = truth.projector_uv.at<cv::Vec2f>(y, x)[axis];
      // Fringes resolved by the camera: ≥ kMinPeriodPx camera px per period (steep or grazing
      // surfaces below that are limited by the camera's blur, not by the phase algorithm).
      if (x == 0 || y == 0 || x + 1 == lit.cols || y + 1 == lit.rows) continue;
      const double gx = 0.5 * (truth.projector_uv.at<cv::Vec2f>(y, x + 1)[axis] -
                               truth.projector_uv.at<cv::Vec2f>(y, x - 1)[axis]);
      const double gy = 0.5 * (truth.projector_uv.at<cv::Vec2f>(y + 1, x)[axis] -
                               truth.projector_uv.at<cv::Vec2f>(y - 1, x)[axis]);
      if (!(spec.fringe_period_px >= kMinPeriodPx * std::hypot(gx, gy))) continue;
      const bool in_core = spec.InMarker(c - 2) && spec.InMarker(c + 2);
      const bool out = !spec.InMarker(c - 2) && !spec.InMarker(c + 2);
      const double Phi = spec.AbsolutePhase(c);
      for (int k = 0; k < 3; ++k) {
        const double e = std::remainder(maps[k].phi.at<float>(y, x) - Phi, 2 * M_PI);
        (in_core ? s2_in : s2_out)[k] += in_core || out ? e * e : 0.0;
      }
      const bool hit = ours.marker.at<uint8_t>(y, x) != 0;
      if (in_core)
        ++n_in, ++core, core_hit += hit;
      else if (out)
        ++n_out, ++outside, outside_hit += hit;
      else
        ++edge, edge_hit += hit;
      if (!ours.kappa.empty()) kappa_sum += ours.kappa.at<float>(y, x);
    }
  for (int k = 0; k < 3; ++k) {
    AlgorithmScore s;
    s.algorithm = static_cast<PhaseAlgorithm>(k);
    s.rms_outside = std::sqrt(s2_out[k] / std::max(1, n_out));
    s.rms_inside = std::sqrt(s2_in[k] / std::max(1, n_in));
    s.n_outside = n_out;
    s.n_inside = n_in;
    ev.algorithms.push_back(s);
  }
  ev.marker.recall = core ? static_cast<double>(core_hit) / core : 0.0;
  ev.marker.false_positive = outside ? static_cast<double>(outside_hit) / outside : 0.0;
  ev.marker.edge_detected = edge ? static_cast<double>(edge_hit) / edge : 0.0;
  ev.marker.n_core = core;
  ev.marker.n_outside = outside;
  ev.mean_kappa = kappa_sum / std::max(1, n_in + n_out + edge);
  return ev;
}

std::string FormatRow(const std::string& label, const Evaluation& e) {
  char buf[512];
  std::snprintf(
      buf, sizeof buf,
      "%-22s outside: std %.4f  lut %.4f  ours %.4f | stripes: std %.4f  lut %.4f  ours %.4f | "
      "kappa %.2f | marker recall %.4f fp %.5f (n %d/%d)",
      label.c_str(), e.algorithms[0].rms_outside, e.algorithms[1].rms_outside,
      e.algorithms[2].rms_outside, e.algorithms[0].rms_inside, e.algorithms[1].rms_inside,
      e.algorithms[2].rms_inside, e.mean_kappa, e.marker.recall, e.marker.false_positive,
      e.marker.n_core, e.marker.n_outside);
  return buf;
}

}  // namespace d3d::phase_eval
