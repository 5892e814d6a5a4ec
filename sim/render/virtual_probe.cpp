#include "sim/render/virtual_probe.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <atomic>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <thread>

#include "sim/render/albedo_texture.h"
#include "sim/render/scene_prep.h"

namespace d3d {

// Everything the shading of any projector frame needs at one pixel, computed once per pose.
struct VirtualProbe::PixelGeometry {
  float depth = std::numeric_limits<float>::quiet_NaN();  // camera z, mm
  float x = 0, y = 0, z = 0;                              // p_in_cam, mm
  float u = 0, v = 0;                                     // projector pixel (valid when vis == 2)
  int32_t face = -1;  // scene triangle, −1 for none or an analytic sphere
  uint8_t vis = 0;    // 0 none, 1 not lit, 2 lit
  uint8_t label = 0;
  float ambient = 0;      // v·ρ·E_amb
  float diffuse = 0;      // v·ρ·E_p
  float specular = 0;     // v·F·E_p
  float ss_fraction = 0;  // s
  float sigma_p = 0;      // projector blur, projector px
  float sigma_ss = 0;     // combined blur of the sub-surface part, projector px
  float sigma_cam = 0;    // camera blur, camera px
};

namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

uint64_t SplitMix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

// Φ⁻¹((i + ½)/2¹⁶) for i < 2¹⁶: a stratified, exact discretisation of N(0, 1) into 65 536
// equiprobable values (tails at |z| ≈ 4.3σ). Drawing a uniform index gives a standard normal
// without a log and a sincos per pixel (Box–Muller cost a fifth of the render time).
const std::vector<float>& NormalQuantiles() {
  static const std::vector<float> table = [] {
    std::vector<float> t(1u << 16);
    for (size_t i = 0; i < t.size(); ++i) {
      const double p = (static_cast<double>(i) + 0.5) / static_cast<double>(t.size());
      double lo = -10.0, hi = 10.0;  // bisection on Φ(z) = ½ erfc(−z/√2)
      for (int it = 0; it < 60; ++it) {
        const double mid = 0.5 * (lo + hi);
        (0.5 * std::erfc(-mid / std::sqrt(2.0)) < p ? lo : hi) = mid;
      }
      t[i] = static_cast<float>(0.5 * (lo + hi));
    }
    return t;
  }();
  return table;
}

// Counter-based generator: one independent stream per pixel, so results do not depend on threads.
class PixelRng {
 public:
  explicit PixelRng(uint64_t state) : state_(state) {}
  double Uniform() {  // (0, 1)
    state_ = SplitMix64(state_);
    return (static_cast<double>(state_ >> 11) + 0.5) * (1.0 / 9007199254740992.0);
  }
  // Two independent standard normals from one 64-bit draw: two indices into the quantile table.
  void Normal2(double* a, double* b) {
    state_ = SplitMix64(state_);
    const auto& table = NormalQuantiles();
    *a = table[state_ & 0xFFFF];
    *b = table[(state_ >> 16) & 0xFFFF];
  }
  // Poisson sample by Knuth's product of uniforms (for small means; larger ones use the normal
  // approximation in the caller).
  double PoissonSmall(double mean) {
    if (mean == 0.0) return 0.0;  // limit 1: no uniform in (0, 1) exceeds it (a dark pixel, no exp)
    const double limit = std::exp(-mean);  // Knuth's product of uniforms
    double p = Uniform();
    int k = 0;
    while (p > limit) {
      p *= Uniform();
      ++k;
    }
    return k;
  }

 private:
  uint64_t state_;
};

// Runs f(row) for every row on the probe's arena. Under ThreadSanitizer (GCC/clang define
// __SANITIZE_THREAD__) the rows go to plain std::threads that are joined: Debian's oneTBB is not
// instrumented, so TSan cannot see that a TBB parallel_for has finished and would report false
// races between successive loops. The per-row work, which is what could race, is the same.
template <typename F>
void ParallelRows(tbb::task_arena& arena, int rows, F&& f) {
#if defined(__SANITIZE_THREAD__)
  std::atomic<int> next{0};
  std::vector<std::thread> workers;
  for (int w = 0; w < std::max(1, arena.max_concurrency()); ++w) {
    workers.emplace_back([&] {
      for (int row = next.fetch_add(1); row < rows; row = next.fetch_add(1)) f(row);
    });
  }
  for (auto& t : workers) t.join();
  return;
#endif
  arena.execute([&] {
    tbb::parallel_for(tbb::blocked_range<int>(0, rows, 4), [&](const tbb::blocked_range<int>& r) {
      for (int row = r.begin(); row < r.end(); ++row) f(row);
    });
  });
}

// std::clamp(std::round(x), 0, max_dn) (round half away from zero) without the libm call for the
// x in (0, max_dn + 1) of a lit pixel: there the truncation is floor and x − floor(x) is exact.
double RoundToDn(double x, double max_dn) {
  if (x > 0.0 && x < max_dn + 1.0) {
    const auto i = static_cast<int64_t>(x);
    const double dn = static_cast<double>(i) + (x - static_cast<double>(i) >= 0.5 ? 1.0 : 0.0);
    return std::min(dn, max_dn);
  }
  return std::clamp(std::round(x), 0.0, max_dn);  // ≤ 0, saturated or NaN
}

// A conservative pre-test of Shade's specular gate n·ĥ > gate (ĥ the unit half vector of l and the
// unit view vector): false only where that test is false, so that the exact half vector (a square
// root and three divisions) is computed only near the lobe. Here h = l + v is unnormalised, v is
// the view vector scaled by a reciprocal; n·h/|h| is then within ~1e-15 of the exact n·ĥ (unit
// vectors), far inside the 1e-9 margin. A near-zero h (grazing, opposite l and v) goes to the exact
// test.
bool SpecularMayPass(const Eigen::Vector3d& n, const Eigen::Vector3d& point,
                     const Eigen::Vector3d& l, const Eigen::Vector3d& cam_centre, double gate) {
  const Eigen::Vector3d to_cam = cam_centre - point;
  const Eigen::Vector3d h = l + to_cam * (1.0 / to_cam.norm());
  const double h2 = h.squaredNorm();
  if (!(h2 > 1e-6)) return true;  // also NaN
  const double n_h = n.dot(h);
  const double g = gate - 1e-9;  // > 0: gate ≥ 1e-6
  return n_h > 0.0 && n_h * n_h > g * g * h2;
}

}  // namespace

void RenderOptions::Check() const {
  D3D_CHECK_MSG(motion_blur_samples >= 1 && motion_blur_samples <= 64,
                "motion_blur_samples must be in [1, 64]");
  D3D_CHECK_MSG(frame_interval_ns > 0, "frame interval must be positive");
  D3D_CHECK_MSG(threads >= 0, "threads must be ≥ 0");
}

uint64_t FrameNoiseSeed(uint64_t seed, uint64_t sequence, int frame_index) {
  return SplitMix64(seed ^
                    SplitMix64(sequence * 64 + static_cast<uint64_t>(frame_index) + 0x5EEDull));
}

VirtualProbe::VirtualProbe(const TriangleMesh& scene, const ProbeDesign& design,
                           const RenderOptions& options, std::vector<SceneSphere> spheres)
    : design_(design),
      options_(options),
      scene_(PrepareScene(scene, design, options.texture, options.texture_seed)),
      arena_(options.threads > 0 ? options.threads : tbb::task_arena::automatic),
      camera_blur_(design_.calibration.camera.fx, design_.optics.camera_pupil_mm,
                   design_.optics.camera_focus_mm, design_.optics.wavelength_nm),
      projector_blur_(design_.calibration.projector.fx, design_.optics.projector_pupil_mm,
                      design_.optics.projector_focus_mm, design_.optics.wavelength_nm) {
  design_.Check();
  options_.Check();
  if (!options_.gamma)
    design_.calibration.projector_gamma = 1.0;  // a linear projector, and its calibration says so
  caster_ = std::make_unique<RayCaster>(scene_.mesh, std::move(spheres));
  const auto& cam = design_.calibration.camera;
  const auto& proj = design_.calibration.projector;
  burst_patterns_ = MakePhaseShiftSet(design_.calibration.pattern, proj.width, proj.height);
  pixel_rays_.resize(static_cast<size_t>(cam.width) * static_cast<size_t>(cam.height));
  pixel_ray_valid_.assign(pixel_rays_.size(), 0);
  for (int r = 0; r < cam.height; ++r)
    for (int c = 0; c < cam.width; ++c) {
      const auto ray = cam.PixelRay(Eigen::Vector2d(c, r));
      const size_t i =
          static_cast<size_t>(r) * static_cast<size_t>(cam.width) + static_cast<size_t>(c);
      if (ray) {
        pixel_rays_[i] = *ray;
        pixel_ray_valid_[i] = 1;
      }
    }
  geometry_.resize(pixel_rays_.size());
  for (const SurfaceLabel label :
       {SurfaceLabel::kUnknown, SurfaceLabel::kGingiva, SurfaceLabel::kTooth}) {
    // (n·h)^m below 1e-6 of the lobe's peak is dropped: n·h < 1e-6^(1/m).
    specular_gate_[static_cast<size_t>(label)] =
        std::pow(1e-6, 1.0 / design_.MaterialOf(label).specular_exponent);
  }
  NormalQuantiles();  // build the table now, not inside the first parallel loop
  for (const auto& f : burst_patterns_.frames) RadianceFor(f);
}

VirtualProbe::~VirtualProbe() = default;

const ProjectorRadiance& VirtualProbe::RadianceFor(const ProjectorFrame& frame) {
  const auto& proj = design_.calibration.projector;
  std::string key(1, frame.axis);
  key.append(frame.dmd.begin(), frame.dmd.end());
  std::lock_guard<std::mutex> lock(radiance_mutex_);
  auto it = radiance_cache_.find(key);
  if (it == radiance_cache_.end()) {
    const double gamma = design_.calibration.projector_gamma;
    auto table = std::make_unique<ProjectorRadiance>(frame, gamma,
                                                     frame.axis == 'y' ? proj.height : proj.width);
    it = radiance_cache_.emplace(std::move(key), std::move(table)).first;
  }
  return *it->second;
}

const std::vector<VirtualProbe::PixelGeometry>& VirtualProbe::GeometryAt(
    const Rigid3d& world_from_probe, bool shade) {
  const bool same =
      geometry_valid_ && (geometry_shaded_ || !shade) && SameBits(geometry_pose_, world_from_probe);
  if (!same) {
    geometry_valid_ = false;
    GeometryPass(world_from_probe, shade, &geometry_);
    geometry_pose_ = world_from_probe;
    geometry_shaded_ = shade;
    geometry_valid_ = true;
  }
  return geometry_;
}

void VirtualProbe::GeometryPass(const Rigid3d& world_from_probe, bool shade,
                                std::vector<PixelGeometry>* out) {
  const ProbeCalibration& calib = design_.calibration;
  const int width = calib.camera.width, height = calib.camera.height;
  out->resize(pixel_rays_.size());
  const Eigen::Matrix3d R = world_from_probe.linear();
  const Eigen::Vector3d cam_centre = world_from_probe.translation();
  const Rigid3d world_from_proj = world_from_probe * calib.cam_from_proj;
  const Rigid3d proj_from_world = world_from_proj.inverse();
  const Eigen::Vector3d proj_centre = world_from_proj.translation();
  constexpr int kTile = 4;  // 4×4 pixel tiles: one coherent Embree packet of 16 rays
  ParallelRows(arena_, (height + kTile - 1) / kTile, [&](int tile_row) {
    size_t index[RayCaster::kPacket];
    Eigen::Vector3d dirs[RayCaster::kPacket], points[RayCaster::kPacket],
        p_in_proj[RayCaster::kPacket];
    Eigen::Vector3d to_proj_unit[RayCaster::kPacket];  // the shadow ray's direction: l in Shade
    double to_proj_dist[RayCaster::kPacket];
    SurfaceHit hits[RayCaster::kPacket];
    bool hit[RayCaster::kPacket], facing[RayCaster::kPacket], occluded[RayCaster::kPacket];
    Eigen::Vector2d uv[RayCaster::kPacket];
    for (int c0 = 0; c0 < width; c0 += kTile) {
      int n = 0;
      for (int r = tile_row * kTile; r < std::min(height, (tile_row + 1) * kTile); ++r)
        for (int c = c0; c < std::min(width, c0 + kTile); ++c) {
          const size_t i =
              static_cast<size_t>(r) * static_cast<size_t>(width) + static_cast<size_t>(c);
          (*out)[i] = PixelGeometry{};
          if (!pixel_ray_valid_[i]) continue;
          index[n] = i;
          dirs[n++] = R * pixel_rays_[i];  // (x, y, 1) rotated: t along it is the camera z
        }
      if (n == 0) continue;
      caster_->Intersect16(cam_centre, dirs, n, 0.0, hits, hit);
      for (int k = 0; k < n; ++k) {
        facing[k] = false;
        to_proj_dist[k] = 0.0;  // read (not used) by Shade where not lit
        if (!hit[k]) continue;
        points[k] = hits[k].point;
        p_in_proj[k] = proj_from_world * hits[k].point;
        const Eigen::Vector3d to_proj = proj_centre - hits[k].point;
        const std::optional<Eigen::Vector2d> pixel = calib.projector.Project(p_in_proj[k]);
        facing[k] =
            pixel && calib.projector.InImage(*pixel) && hits[k].geometric_normal.dot(to_proj) > 0.0;
        if (pixel) uv[k] = *pixel;
        if (facing[k]) {  // to_proj ≠ 0
          to_proj_dist[k] = to_proj.norm();
          to_proj_unit[k] = to_proj / to_proj_dist[k];
        }
      }
      caster_->OccludedToPoint16(points, to_proj_unit, to_proj_dist, facing, n, proj_centre, 1e-3,
                                 occluded);
      for (int k = 0; k < n; ++k) {
        if (!hit[k]) continue;
        const Eigen::Vector2d* lit_uv = facing[k] && !occluded[k] ? &uv[k] : nullptr;
        PixelGeometry* g = &(*out)[index[k]];
        HitTruth(hits[k], index[k], lit_uv, g);
        if (shade)
          Shade(hits[k], index[k], cam_centre, p_in_proj[k], lit_uv, to_proj_unit[k],
                to_proj_dist[k], g);
      }
    }
  });
}

void VirtualProbe::HitTruth(const SurfaceHit& hit, size_t pixel, const Eigen::Vector2d* uv,
                            PixelGeometry* g) const {
  const Eigen::Vector3d p_in_cam = pixel_rays_[pixel] * hit.t;
  g->depth = static_cast<float>(hit.t);
  g->x = static_cast<float>(p_in_cam.x());
  g->y = static_cast<float>(p_in_cam.y());
  g->z = static_cast<float>(p_in_cam.z());
  g->label = static_cast<uint8_t>(hit.label);
  g->face = hit.face >= 0 ? scene_.parent_face[static_cast<size_t>(hit.face)] : -1;
  g->vis = uv ? 2 : 1;
  if (uv) {
    g->u = static_cast<float>(uv->x());
    g->v = static_cast<float>(uv->y());
  }
}

void VirtualProbe::Shade(const SurfaceHit& hit, size_t pixel, const Eigen::Vector3d& cam_centre,
                         const Eigen::Vector3d& p_in_proj, const Eigen::Vector2d* uv,
                         const Eigen::Vector3d& l, double dist, PixelGeometry* g) const {
  const ProbeCalibration& calib = design_.calibration;
  const ProbeOptics& optics = design_.optics;
  const Eigen::Vector3d& ray = pixel_rays_[pixel];
  const Material& m = design_.MaterialOf(hit.label);
  const double vignetting =
      1.0 / (ray.squaredNorm() * ray.squaredNorm());  // cos⁴ α for ray = (x, y, 1)
  double albedo;
  if (hit.face >= 0) {  // baked at the corners (scene_prep.h), interpolated
    const float* a = &scene_.corner_albedo[3 * static_cast<size_t>(hit.face)];
    const double b1 = std::clamp(hit.b1, 0.0, 1.0), b2 = std::clamp(hit.b2, 0.0, 1.0 - b1);
    albedo = (1.0 - b1 - b2) * a[0] + b1 * a[1] + b2 * a[2];
  } else {
    albedo =
        m.albedo * (options_.texture ? AlbedoFactor(m, hit.point, options_.texture_seed) : 1.0);
  }
  g->ambient = static_cast<float>(vignetting * albedo * optics.ambient_irradiance);
  g->sigma_cam = static_cast<float>(camera_blur_.SigmaPx(hit.t));
  if (!uv) return;  // not lit by the projector
  const double cos_i = std::max(0.0, hit.shading_normal.dot(l));
  const double e_p = optics.projector_irradiance * cos_i * (optics.projector_focus_mm / dist) *
                     (optics.projector_focus_mm / dist);
  g->diffuse = static_cast<float>(vignetting * albedo * e_p);
  if (options_.specular && m.specular_r0 > 0.0 &&
      SpecularMayPass(hit.shading_normal, hit.point, l, cam_centre,
                      specular_gate_[static_cast<size_t>(hit.label)])) {
    const Eigen::Vector3d view = (cam_centre - hit.point).normalized();
    const double n_h = hit.shading_normal.dot((l + view).normalized());
    if (n_h > specular_gate_[static_cast<size_t>(hit.label)]) {
      const double f =
          m.specular_r0 * (m.specular_exponent + 8.0) / 8.0 * std::pow(n_h, m.specular_exponent);
      g->specular = static_cast<float>(vignetting * f * e_p);
    }
  }
  const double z_p = p_in_proj.z();
  const double sigma_p = options_.projector_defocus ? projector_blur_.SigmaPx(z_p) : 0.0;
  g->sigma_p = static_cast<float>(sigma_p);
  if (options_.subsurface && m.subsurface_fraction > 0.0) {
    const double ss = m.subsurface_sigma_mm * calib.projector.fx / z_p;
    g->ss_fraction = static_cast<float>(m.subsurface_fraction);
    g->sigma_ss = static_cast<float>(std::sqrt(sigma_p * sigma_p + ss * ss));
  }
}

void VirtualProbe::ShadePass(const std::vector<PixelGeometry>& geometry,
                             const ProjectorRadiance& radiance, float weight, cv::Mat* signal) {
  const int width = signal->cols;
  const bool along_v = radiance.axis() == 'y';
  ParallelRows(arena_, signal->rows, [&](int row) {
    float* out = signal->ptr<float>(row);
    for (int col = 0; col < width; ++col) {
      const PixelGeometry& g = geometry[static_cast<size_t>(row) * static_cast<size_t>(width) +
                                        static_cast<size_t>(col)];
      if (g.vis == 0) continue;
      float s = g.ambient;
      if (g.vis == 2) {
        const float c = along_v ? g.v : g.u;
        const float sharp = radiance.Sample(c, g.sigma_p);
        float diffuse = sharp;
        if (g.ss_fraction > 0.0f)
          diffuse = (1.0f - g.ss_fraction) * sharp + g.ss_fraction * radiance.Sample(c, g.sigma_ss);
        s += g.diffuse * diffuse + g.specular * sharp;
      }
      out[col] += weight * s;
    }
  });
}

void VirtualProbe::CameraDefocus(const std::vector<PixelGeometry>& geometry, cv::Mat* signal) {
  // Spatially varying Gaussian blur by interpolating between uniformly blurred copies (a gather
  // approximation: exact on surfaces of slowly varying depth).
  static constexpr float kLevels[] = {0.5f, 0.7f, 1.0f, 1.4f, 2.0f, 2.8f, 4.0f};
  constexpr int kCount = sizeof(kLevels) / sizeof(kLevels[0]);
  const float airy = static_cast<float>(ProbeOptics::BlurSigmaPx(
      design_.calibration.camera.fx, design_.optics.camera_pupil_mm, design_.optics.camera_focus_mm,
      design_.optics.wavelength_nm, design_.optics.camera_focus_mm));
  // Each pixel's σ (into a compact array: the geometry is read once) and the largest σ, by rows in
  // parallel. A pixel without a surface has sigma_cam 0 < airy, so the maximum is that of all
  // sigma_cam and airy as before; std::max from airy skips a NaN in any order: the same value.
  const int width = signal->cols;
  pixel_sigma_.resize(geometry.size());
  row_max_sigma_.assign(static_cast<size_t>(signal->rows), airy);
  ParallelRows(arena_, signal->rows, [&](int row) {
    float m = airy;
    const size_t first = static_cast<size_t>(row) * static_cast<size_t>(width);
    for (size_t i = first; i < first + static_cast<size_t>(width); ++i) {
      const PixelGeometry& g = geometry[i];
      pixel_sigma_[i] = g.vis ? g.sigma_cam : airy;
      m = std::max(m, pixel_sigma_[i]);
    }
    row_max_sigma_[static_cast<size_t>(row)] = m;
  });
  float max_sigma = airy;
  for (const float m : row_max_sigma_) max_sigma = std::max(max_sigma, m);
  int needed = 1;
  while (needed < kCount && kLevels[needed - 1] < max_sigma) ++needed;
  blur_levels_.resize(kCount);
  for (int k = 0; k < needed; ++k)
    cv::GaussianBlur(*signal, blur_levels_[k], cv::Size(0, 0), kLevels[k], kLevels[k],
                     cv::BORDER_REFLECT);
  const cv::Mat sharp = signal->clone();
  ParallelRows(arena_, signal->rows, [&](int row) {
    float* out = signal->ptr<float>(row);
    const float* s0 = sharp.ptr<float>(row);
    for (int col = 0; col < width; ++col) {
      const float sigma = pixel_sigma_[static_cast<size_t>(row) * static_cast<size_t>(width) +
                                       static_cast<size_t>(col)];
      if (sigma <= kLevels[0]) {
        const float w = sigma / kLevels[0];
        out[col] = s0[col] + w * (blur_levels_[0].ptr<float>(row)[col] - s0[col]);
        continue;
      }
      int k = 0;
      while (k + 1 < needed && kLevels[k + 1] < sigma) ++k;
      if (k + 1 >= needed) {
        out[col] = blur_levels_[needed - 1].ptr<float>(row)[col];
        continue;
      }
      const float w = (sigma - kLevels[k]) / (kLevels[k + 1] - kLevels[k]);
      const float a = blur_levels_[k].ptr<float>(row)[col],
                  b = blur_levels_[k + 1].ptr<float>(row)[col];
      out[col] = a + w * (b - a);
    }
  });
}

void VirtualProbe::SensorPass(const cv::Mat& signal, uint64_t frame_seed, cv::Mat* image) {
  const SensorModel& sensor = design_.sensor;
  const double max_dn = std::ldexp(1.0, sensor.bits) - 1.0;
  const double dn_per_e = max_dn / sensor.full_well_e;
  const bool eight = sensor.bits == 8;
  image->create(signal.rows, signal.cols, eight ? CV_8U : CV_16U);
  const int width = signal.cols;
  ParallelRows(arena_, signal.rows, [&](int row) {
    const float* s = signal.ptr<float>(row);
    for (int col = 0; col < width; ++col) {
      double electrons = std::max(0.0, static_cast<double>(s[col])) * sensor.full_well_e;
      if (options_.noise) {  // photon shot noise (Poisson) + read noise (Gaussian), in electrons
        PixelRng rng(SplitMix64(frame_seed + static_cast<uint64_t>(row) * 1315423911ull +
                                static_cast<uint64_t>(col)));
        double n1, n2;
        rng.Normal2(&n1, &n2);
        const double shot = electrons > 64.0 ? std::max(0.0, electrons + std::sqrt(electrons) * n1)
                                             : rng.PoissonSmall(electrons);
        electrons = shot + sensor.read_noise_e * n2;
      }
      const double dn = RoundToDn(electrons * dn_per_e, max_dn);
      if (eight)
        image->ptr<uint8_t>(row)[col] = static_cast<uint8_t>(dn);
      else
        image->ptr<uint16_t>(row)[col] = static_cast<uint16_t>(dn);
    }
  });
}

void VirtualProbe::FillTruth(const std::vector<PixelGeometry>& geometry, int width, int height,
                             FrameTruth* out) {
  out->depth_mm.create(height, width, CV_32F);
  out->points_in_cam.create(height, width, CV_32FC3);
  out->projector_uv.create(height, width, CV_32FC2);
  out->visibility.create(height, width, CV_8U);
  out->label.create(height, width, CV_8U);
  out->face_index.create(height, width, CV_32S);
  ParallelRows(arena_, height, [&](int r) {
    float* depth = out->depth_mm.ptr<float>(r);
    cv::Vec3f* points = out->points_in_cam.ptr<cv::Vec3f>(r);
    cv::Vec2f* uv = out->projector_uv.ptr<cv::Vec2f>(r);
    uint8_t* visibility = out->visibility.ptr<uint8_t>(r);
    uint8_t* label = out->label.ptr<uint8_t>(r);
    int32_t* face = out->face_index.ptr<int32_t>(r);
    for (int c = 0; c < width; ++c) {
      const auto& g =
          geometry[static_cast<size_t>(r) * static_cast<size_t>(width) + static_cast<size_t>(c)];
      const bool hit = g.vis != 0;
      depth[c] = hit ? g.depth : kNaN;
      points[c] = hit ? cv::Vec3f(g.x, g.y, g.z) : cv::Vec3f(kNaN, kNaN, kNaN);
      uv[c] = g.vis == 2 ? cv::Vec2f(g.u, g.v) : cv::Vec2f(kNaN, kNaN);
      visibility[c] = g.vis;
      label[c] = g.label;
      face[c] = g.face;
    }
  });
}

void VirtualProbe::RenderTruth(const Rigid3d& world_from_probe, FrameTruth* out) {
  FillTruth(GeometryAt(world_from_probe, false), design_.calibration.camera.width,
            design_.calibration.camera.height, out);
  out->world_from_probe = world_from_probe;
}

void VirtualProbe::RenderFrame(const PoseAtTime& pose, int64_t t_ns, const ProjectorFrame& frame,
                               uint64_t noise_seed, bool with_truth, BurstFrame* out) {
  const auto& cam = design_.calibration.camera;
  const ProjectorRadiance& radiance = RadianceFor(frame);
  out->pattern = frame.name;
  out->timestamp_ns = t_ns;
  const Rigid3d world_from_probe = pose(t_ns);
  cv::Mat signal(cam.height, cam.width, CV_32F, cv::Scalar(0));
  GeometryAt(world_from_probe, true);  // the pose at mid-exposure: truth and defocus
  const int samples = options_.motion_blur_samples;
  if (samples == 1) {
    ShadePass(geometry_, radiance, 1.0f, &signal);
  } else {
    const double exposure = static_cast<double>(design_.sensor.exposure_ns);
    for (int s = 0; s < samples; ++s) {
      const auto t =
          t_ns + static_cast<int64_t>(std::llround(exposure * ((s + 0.5) / samples - 0.5)));
      const Rigid3d sub_pose = pose(t);
      const bool still = SameBits(sub_pose, world_from_probe);  // geometry_ is at that pose
      if (!still) GeometryPass(sub_pose, true, &geometry_sub_);
      ShadePass(still ? geometry_ : geometry_sub_, radiance, 1.0f / static_cast<float>(samples),
                &signal);
    }
  }
  if (options_.camera_defocus) CameraDefocus(geometry_, &signal);
  SensorPass(signal, noise_seed, &out->image);
  out->truth = FrameTruth{};
  if (with_truth) FillTruth(geometry_, cam.width, cam.height, &out->truth);
  out->truth.world_from_probe = world_from_probe;
}

Burst VirtualProbe::RenderBurst(const PoseAtTime& pose, int64_t t0_ns, uint64_t sequence,
                                uint64_t seed, bool with_truth, const PatternSet* set) {
  const PatternSet& patterns = set ? *set : burst_patterns_;
  Burst burst;
  burst.sequence = sequence;
  burst.frames.resize(patterns.frames.size());
  for (size_t i = 0; i < patterns.frames.size(); ++i) {
    const int64_t t = t0_ns + static_cast<int64_t>(i) * options_.frame_interval_ns;
    RenderFrame(pose, t, patterns.frames[i], FrameNoiseSeed(seed, sequence, static_cast<int>(i)),
                with_truth, &burst.frames[i]);
  }
  burst.reference_ns = (burst.frames.front().timestamp_ns + burst.frames.back().timestamp_ns) / 2;
  if (with_truth) RenderTruth(pose(burst.reference_ns), &burst.reference_truth);
  return burst;
}

}  // namespace d3d
