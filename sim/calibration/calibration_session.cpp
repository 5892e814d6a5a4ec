#include "sim/calibration/calibration_session.h"

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <random>

#include "common/core/progress.h"
#include "sim/patterns/patterns.h"
#include "sim/render/virtual_probe.h"

namespace d3d {
namespace {

namespace fs = std::filesystem;
constexpr int kRingPerSide = 16;  // boundary points per cell side: circles are 64-gons

Material Matte(double albedo) {
  Material m;
  m.albedo = albedo;
  m.subsurface_fraction = 0.0;
  m.subsurface_sigma_mm = 0.0;
  m.specular_r0 = 0.0;
  m.mottle_amplitude = 0.0;
  m.stain_amplitude = 0.0;
  return m;
}

nlohmann::json PoseJson(const Rigid3d& p) {
  const Eigen::Matrix3d R = p.linear();
  const Eigen::Vector3d t = p.translation();
  return {{"R",
           {{R(0, 0), R(0, 1), R(0, 2)}, {R(1, 0), R(1, 1), R(1, 2)}, {R(2, 0), R(2, 1), R(2, 2)}}},
          {"t_mm", {t.x(), t.y(), t.z()}}};
}

// Adds triangle (a, b, c) facing −z (toward the probe).
void AddFace(TriangleMesh* m, int a, int b, int c, SurfaceLabel label) {
  const Eigen::Vector3d n =
      (m->vertices[static_cast<size_t>(b)] - m->vertices[static_cast<size_t>(a)])
          .cross(m->vertices[static_cast<size_t>(c)] - m->vertices[static_cast<size_t>(a)]);
  if (n.z() > 0) std::swap(b, c);
  m->faces.emplace_back(a, b, c);
  m->face_labels.push_back(label);
}

bool CircleAt(const CalibrationTarget& t, int ix, int iy) {
  if (t.kind == TargetKind::kAsymmetricCircleGrid) {
    if (iy < 0 || iy >= t.rows || ((ix - iy) % 2 + 2) % 2 != 0) return false;
    const int c = (ix - iy % 2) / 2;
    return c >= 0 && c < t.cols;
  }
  return ix >= 0 && ix < t.cols && iy >= 0 && iy < t.rows;
}

}  // namespace

void CalibrationSessionOptions::Check() const {
  D3D_CHECK_MSG(poses >= 1 && poses <= 1000, "poses must be in [1, 1000]");
  D3D_CHECK_MSG(steps >= 3, "phase steps must be ≥ 3");
  D3D_CHECK_MSG(!periods_px.empty(), "at least one fringe period");
  for (double p : periods_px) D3D_CHECK_MSG(p >= 2.0, "fringe periods must be ≥ 2 projector px");
  D3D_CHECK_MSG(white_supersample == 1 || white_supersample == 2,
                "white_supersample must be 1 or 2");
  D3D_CHECK_MSG(paper_albedo > ink_albedo && ink_albedo > 0 && paper_albedo <= 1,
                "need 0 < ink < paper ≤ 1");
  D3D_CHECK_MSG(min_distance_mm > 0 && max_distance_mm >= min_distance_mm, "bad distance range");
  D3D_CHECK_MSG(min_tilt_deg >= 0 && max_tilt_deg >= min_tilt_deg && max_tilt_deg < 80,
                "bad tilt range");
  D3D_CHECK_MSG(max_roll_deg >= 0 && max_roll_deg <= 180, "bad roll range");
  D3D_CHECK_MSG(threads >= 0, "threads must be ≥ 0");
}

TriangleMesh MakeCalibrationTargetMesh(const CalibrationTarget& target, double margin_mm) {
  target.Check();
  D3D_CHECK_MSG(margin_mm >= 0, "margin must be ≥ 0");
  const double s = target.spacing_mm;
  const auto [lo, hi] = target.FeatureBounds();
  TriangleMesh m;
  if (target.kind == TargetKind::kChessboard) {
    const int i0 = static_cast<int>(std::floor((lo.x() - s - margin_mm) / s)),
              i1 = static_cast<int>(std::ceil((hi.x() + s + margin_mm) / s));
    const int j0 = static_cast<int>(std::floor((lo.y() - s - margin_mm) / s)),
              j1 = static_cast<int>(std::ceil((hi.y() + s + margin_mm) / s));
    const int nx = i1 - i0 + 1;
    for (int j = j0; j <= j1; ++j)
      for (int i = i0; i <= i1; ++i) m.vertices.emplace_back(i * s, j * s, 0.0);
    auto v = [&](int i, int j) { return (j - j0) * nx + (i - i0); };
    for (int j = j0; j < j1; ++j)
      for (int i = i0; i < i1; ++i) {
        const bool on_board = i >= -1 && i <= target.cols - 1 && j >= -1 && j <= target.rows - 1;
        const SurfaceLabel label =
            on_board && (i + j) % 2 == 0 ? SurfaceLabel::kGingiva : SurfaceLabel::kTooth;
        AddFace(&m, v(i, j), v(i + 1, j), v(i + 1, j + 1), label);
        AddFace(&m, v(i, j), v(i + 1, j + 1), v(i, j + 1), label);
      }
    return m;
  }
  D3D_CHECK_MSG(
      target.circle_diameter_mm > 0 && target.circle_diameter_mm < s,
      "the target mesh needs a circle diameter in (0, spacing): add :d=DIAM to the target");
  const double r = 0.5 * target.circle_diameter_mm;
  const int ix0 = static_cast<int>(std::floor((lo.x() - margin_mm) / s)) - 1,
            ix1 = static_cast<int>(std::ceil((hi.x() + margin_mm) / s)) + 1;
  const int iy0 = static_cast<int>(std::floor((lo.y() - margin_mm) / s)) - 1,
            iy1 = static_cast<int>(std::ceil((hi.y() + margin_mm) / s)) + 1;
  const int K = kRingPerSide;
  const int gw = (ix1 - ix0 + 1) * K + 1, gh = (iy1 - iy0 + 1) * K + 1;
  std::vector<int> grid(static_cast<size_t>(gw) * static_cast<size_t>(gh), -1);
  auto gv = [&](int gx, int gy) {
    int& id = grid[static_cast<size_t>(gy) * static_cast<size_t>(gw) + static_cast<size_t>(gx)];
    if (id < 0) {
      id = static_cast<int>(m.vertices.size());
      m.vertices.emplace_back((ix0 - 0.5) * s + gx * s / K, (iy0 - 0.5) * s + gy * s / K, 0.0);
    }
    return id;
  };
  for (int iy = iy0; iy <= iy1; ++iy)
    for (int ix = ix0; ix <= ix1; ++ix) {
      const int gx0 = (ix - ix0) * K, gy0 = (iy - iy0) * K;
      std::vector<int> ring;  // counter-clockwise in (x, y)
      for (int k = 0; k < K; ++k) ring.push_back(gv(gx0 + k, gy0));
      for (int k = 0; k < K; ++k) ring.push_back(gv(gx0 + K, gy0 + k));
      for (int k = 0; k < K; ++k) ring.push_back(gv(gx0 + K - k, gy0 + K));
      for (int k = 0; k < K; ++k) ring.push_back(gv(gx0, gy0 + K - k));
      const Eigen::Vector3d centre(ix * s, iy * s, 0.0);
      const int c = static_cast<int>(m.vertices.size());
      m.vertices.push_back(centre);
      const int n = static_cast<int>(ring.size());
      if (!CircleAt(target, ix, iy)) {
        for (int k = 0; k < n; ++k)
          AddFace(&m, c, ring[static_cast<size_t>(k)], ring[static_cast<size_t>((k + 1) % n)],
                  SurfaceLabel::kTooth);
        continue;
      }
      std::vector<int> poly;
      for (int k = 0; k < n; ++k) {
        const Eigen::Vector3d d =
            (m.vertices[static_cast<size_t>(ring[static_cast<size_t>(k)])] - centre).normalized();
        poly.push_back(static_cast<int>(m.vertices.size()));
        m.vertices.push_back(centre + r * d);
      }
      for (int k = 0; k < n; ++k) {
        const int k1 = (k + 1) % n;
        AddFace(&m, c, poly[static_cast<size_t>(k)], poly[static_cast<size_t>(k1)],
                SurfaceLabel::kGingiva);
        AddFace(&m, poly[static_cast<size_t>(k)], ring[static_cast<size_t>(k)],
                ring[static_cast<size_t>(k1)], SurfaceLabel::kTooth);
        AddFace(&m, poly[static_cast<size_t>(k)], ring[static_cast<size_t>(k1)],
                poly[static_cast<size_t>(k1)], SurfaceLabel::kTooth);
      }
    }
  return m;
}

Status MakeCalibrationPoses(const CalibrationSessionOptions& o, const CalibrationTarget& target,
                            const ProbeCalibration& calib, double margin_px,
                            std::vector<Rigid3d>* out) {
  o.Check();
  const auto [lo, hi] = target.FeatureBounds();
  const double s = target.spacing_mm;
  const Eigen::Vector3d centre(0.5 * (lo.x() + hi.x()), 0.5 * (lo.y() + hi.y()), 0.0);
  const std::vector<Eigen::Vector3d> corners = {{lo.x() - s, lo.y() - s, 0},
                                                {hi.x() + s, lo.y() - s, 0},
                                                {hi.x() + s, hi.y() + s, 0},
                                                {lo.x() - s, hi.y() + s, 0}};
  const Rigid3d proj_from_cam = calib.cam_from_proj.inverse();
  auto inside = [&](const PinholeBrownConrady& dev, const Rigid3d& dev_from_target) {
    for (const auto& p : corners) {
      const auto uv = dev.Project(dev_from_target * p);
      if (!uv || uv->x() < margin_px || uv->y() < margin_px ||
          uv->x() > dev.width - 1 - margin_px || uv->y() > dev.height - 1 - margin_px)
        return false;
    }
    return true;
  };
  std::mt19937_64 rng(o.seed * 0x9E3779B97F4A7C15ull + 17);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  out->clear();
  const double deg = M_PI / 180.0;
  for (int i = 0; i < o.poses; ++i) {
    bool found = false;
    for (int attempt = 0; attempt < 2000 && !found; ++attempt) {
      // Tilt axes spread evenly over the views (a well-conditioned set), jittered.
      const double axis_angle = 2.0 * M_PI * (i + u01(rng)) / o.poses;
      const double tilt = (o.min_tilt_deg + (o.max_tilt_deg - o.min_tilt_deg) * u01(rng)) * deg;
      const double roll = o.max_roll_deg * (2.0 * u01(rng) - 1.0) * deg;
      const double z = o.min_distance_mm + (o.max_distance_mm - o.min_distance_mm) * u01(rng);
      const Eigen::Vector3d axis(std::cos(axis_angle), std::sin(axis_angle), 0.0);
      Rigid3d pose = Rigid3d::Identity();
      pose.linear() =
          (Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(tilt, axis))
              .toRotationMatrix();
      const Eigen::Vector3d shift(1.0 * (2.0 * u01(rng) - 1.0), 0.8 * (2.0 * u01(rng) - 1.0), z);
      pose.translation() = shift - pose.linear() * centre;
      found = inside(calib.camera, pose) && inside(calib.projector, proj_from_cam * pose);
      if (found) out->push_back(pose);
    }
    if (!found) {
      return InvalidArgument("target " + target.ToString() +
                             " does not fit the camera's and projector's view at pose " +
                             std::to_string(i) + " (make it smaller or reduce the tilt range)");
    }
  }
  return Status::Ok();
}

Status RenderCalibrationSession(const CalibrationSessionOptions& options,
                                const std::string& out_dir, bool progress,
                                CalibrationSessionResult* out) {
  options.Check();
  const auto start = std::chrono::steady_clock::now();
  CalibrationTarget target;
  D3D_RETURN_IF_ERROR(ParseTarget(options.target, &target));
  if (target.IsCircles() &&
      !(target.circle_diameter_mm > 0 && target.circle_diameter_mm < target.spacing_mm)) {
    return InvalidArgument(
        "calibration session: the circle target needs :d=DIAM with DIAM < spacing, got '" +
        options.target + "'");
  }
  ProbeDesign design = MakeDefaultProbeDesign(options.camera_width, options.camera_height);
  design.enamel = Matte(options.paper_albedo);
  design.gingiva = Matte(options.ink_albedo);
  design.calibration.source = "virtual-probe";
  if (!options.gamma) design.calibration.projector_gamma = 1.0;
  const ProbeCalibration& truth = design.calibration;
  std::vector<Rigid3d> poses;
  D3D_RETURN_IF_ERROR(MakeCalibrationPoses(options, target, truth, 10.0, &poses));

  const auto [lo, hi] = target.FeatureBounds();
  const double half = 0.5 * std::max(hi.x() - lo.x(), hi.y() - lo.y());
  const TriangleMesh mesh =
      MakeCalibrationTargetMesh(target, std::max(2.0 * target.spacing_mm, 20.0 - half));
  RenderOptions ro;
  ro.noise = options.noise;
  ro.gamma = options.gamma;
  ro.texture = false;
  ro.specular = false;
  ro.subsurface = false;
  ro.threads = options.threads;
  VirtualProbe probe(mesh, design, ro);
  // The anti-aliasing probe: twice the resolution, same optics, no noise, 16 bits.
  const int ss = options.white_supersample;
  std::unique_ptr<VirtualProbe> fine;
  if (ss > 1) {
    ProbeDesign d2 = design;
    PinholeBrownConrady& c = d2.calibration.camera;
    c.width *= ss;
    c.height *= ss;
    c.fx *= ss;
    c.fy *= ss;
    c.cx = ss * c.cx + 0.5 * (ss - 1);
    c.cy = ss * c.cy + 0.5 * (ss - 1);
    d2.sensor.bits = 16;
    RenderOptions r2 = ro;
    r2.noise = false;
    fine = std::make_unique<VirtualProbe>(mesh, d2, r2);
  }
  const auto& proj = truth.projector;
  const PatternSet white = MakeUniformSet(255, proj.width, proj.height);
  std::vector<std::pair<char, PatternSet>> phase_sets;
  for (char axis : {'x', 'y'})
    phase_sets.emplace_back(axis, MakeMultiFrequencySet(axis, options.steps, options.periods_px,
                                                        proj.width, proj.height));

  std::error_code ec;
  fs::create_directories(fs::path(out_dir) / "images", ec);
  fs::create_directories(fs::path(out_dir) / "phase", ec);
  if (ec) return IoError("cannot create '" + out_dir + "': " + ec.message());
  D3D_RETURN_IF_ERROR(truth.Save((fs::path(out_dir) / "calibration.json").string()));
  {
    nlohmann::json pj{{"format", "d3dscan.phase-sets"},
                      {"version", 1},
                      {"projector_width", proj.width},
                      {"projector_height", proj.height},
                      {"steps", options.steps},
                      {"periods_px", options.periods_px},
                      {"axes", {"x", "y"}},
                      {"phase_origin_px", 0.0},
                      {"frames", "AXIS_PERIODINDEX_STEP.png, e.g. x_0_0.png"},
                      {"pattern",
                       "frame S of period T: 1/2 + 1/2 cos(2 pi c / T - 2 pi S / N), before the "
                       "projector's gamma"}};
    std::ofstream f(fs::path(out_dir) / "phase" / "phase.json");
    f << pj.dump(2) << "\n";
    if (!f) return IoError("cannot write phase.json in '" + out_dir + "'");
  }
  const int frames_per_pose = 1 + 2 * options.steps * static_cast<int>(options.periods_px.size());
  ProgressBar bar("calibration session", static_cast<int64_t>(poses.size()) * frames_per_pose,
                  progress);
  int64_t done = 0;
  CalibrationSessionResult result;
  result.truth = truth;
  result.target = target;
  const SensorModel& sensor = design.sensor;
  for (size_t i = 0; i < poses.size(); ++i) {
    char name[32];
    std::snprintf(name, sizeof(name), "pose_%02zu", i);
    const Rigid3d world_from_probe = poses[i].inverse();  // world = target frame
    const PoseAtTime pose = [&](int64_t) { return world_from_probe; };
    BurstFrame frame;
    cv::Mat white_img;
    if (fine) {
      fine->RenderFrame(pose, 0, white.frames[0], 0, false, &frame);
      cv::Mat f32;
      frame.image.convertTo(f32, CV_32F, 1.0 / 65535.0);
      cv::Mat small;
      cv::resize(f32, small, cv::Size(truth.camera.width, truth.camera.height), 0, 0,
                 cv::INTER_AREA);
      // Sensor noise and 8-bit quantisation at the native resolution (SensorModel).
      std::mt19937_64 rng(FrameNoiseSeed(options.seed, 1000000 + i, 0));
      std::normal_distribution<double> n01(0.0, 1.0);
      white_img.create(small.size(), CV_8U);
      const double max_dn = std::ldexp(1.0, sensor.bits) - 1.0;
      for (int r = 0; r < small.rows; ++r)
        for (int c = 0; c < small.cols; ++c) {
          double e = std::max(0.0, static_cast<double>(small.at<float>(r, c))) * sensor.full_well_e;
          if (options.noise) e += std::sqrt(e) * n01(rng) + sensor.read_noise_e * n01(rng);
          const double dn = std::clamp(std::round(e * max_dn / sensor.full_well_e), 0.0, 255.0);
          white_img.at<uint8_t>(r, c) = static_cast<uint8_t>(dn);
        }
    } else {
      probe.RenderFrame(pose, 0, white.frames[0], FrameNoiseSeed(options.seed, i, 0), false,
                        &frame);
      white_img = frame.image;
    }
    if (!cv::imwrite((fs::path(out_dir) / "images" / (std::string(name) + ".png")).string(),
                     white_img))
      return IoError("cannot write the white image of " + std::string(name));
    bar.Update(++done);
    const fs::path pose_dir = fs::path(out_dir) / "phase" / name;
    fs::create_directories(pose_dir, ec);
    if (ec) return IoError("cannot create '" + pose_dir.string() + "'");
    int k = 1;
    for (const auto& [axis, set] : phase_sets) {
      for (size_t f = 0; f < set.frames.size(); ++f, ++k) {
        probe.RenderFrame(pose, 0, set.frames[f], FrameNoiseSeed(options.seed, i, k), false,
                          &frame);
        const size_t period = f / static_cast<size_t>(options.steps),
                     step = f % static_cast<size_t>(options.steps);
        const std::string file = std::string(1, axis) + "_" + std::to_string(period) + "_" +
                                 std::to_string(step) + ".png";
        if (!cv::imwrite((pose_dir / file).string(), frame.image))
          return IoError("cannot write " + (pose_dir / file).string());
        bar.Update(++done);
      }
    }
    result.views.push_back({name, poses[i]});
  }
  bar.Finish();
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  nlohmann::json views = nlohmann::json::array();
  for (const auto& v : result.views)
    views.push_back({{"name", v.name}, {"cam_from_target", PoseJson(v.cam_from_target)}});
  nlohmann::json sj{{"format", "d3dscan.calibration-session"},
                    {"version", 1},
                    {"target", target.ToString()},
                    {"circle_diameter_mm", target.circle_diameter_mm},
                    {"seed", options.seed},
                    {"poses", options.poses},
                    {"noise", options.noise},
                    {"gamma", options.gamma},
                    {"white_supersample", options.white_supersample},
                    {"paper_albedo", options.paper_albedo},
                    {"ink_albedo", options.ink_albedo},
                    {"views", views},
                    {"render_seconds", result.seconds}};
  std::ofstream f(fs::path(out_dir) / "session.json");
  f << sj.dump(2) << "\n";
  if (!f) return IoError("cannot write session.json in '" + out_dir + "'");
  if (out) *out = std::move(result);
  return Status::Ok();
}

}  // namespace d3d
