// The virtual probe: renders, from a scene and a hand trajectory, the frames the probe's camera
// would capture under each projector frame, with the ground truth of every pixel.
//
// Photometric model (per camera pixel whose ray meets the surface at X with shading normal n,
// in units of the sensor's full well; see probe_design.h for parameter values and sources):
//   S = v · ρ(X) · E_amb
//     + v · ρ(X) · E_p · [(1 − s) · P(c, σ_p) + s · P(c, √(σ_p² + σ_ss²))]      (diffuse +
//     sub-surface)
//     + v · F(n, l, h) · E_p · P(c, σ_p)                                          (specular, wet)
//   E_p = projector_irradiance · max(0, n·l) · (z_f / d)²    (Lambert, inverse square; d = distance
//         to the projector centre, z_f its focus distance), only where the projector sees X
//         (in its image, front-facing, not shadowed; Embree shadow ray)
//   F  = R0 · (m + 8)/8 · max(0, n·h)^m                         (normalised Blinn–Phong)
//   v  = cos⁴ α                                                 (natural vignetting, α = ray angle)
//   P(c, σ) = projector radiance of the frame at projector coordinate c (u for x-coded frames,
//         v for y-coded) through a Gaussian blur σ (projector_radiance.h); σ_p from defocus and
//         diffraction at the point's projector depth, σ_ss = subsurface_sigma_mm · f_p / z_p.
// Then: motion blur (mean of S over `motion_blur_samples` poses spread over the exposure), camera
// defocus (per-pixel Gaussian σ from the depth), photon shot noise (Poisson in electrons), read
// noise (Gaussian), quantisation to `bits` with clipping at full scale (saturation).
//
// Timing: frame i of a burst starting at t0 has its exposure centred on t0 + i·frame_interval_ns;
// its ground truth is taken at that instant.
//
// Threads: Render* calls are not reentrant (one caller thread; they own scratch buffers); each call
// runs its per-pixel work in parallel on an internal oneTBB arena of `threads` workers. Output is
// identical for identical inputs and seed, whatever the thread count.
#pragma once

#include <tbb/task_arena.h>

#include <array>
#include <functional>
#include <memory>
#include <mutex>
#include <opencv2/core.hpp>
#include <string>
#include <unordered_map>
#include <vector>

#include "common/burst/burst.h"
#include "common/core/rigid.h"
#include "sim/patterns/patterns.h"
#include "sim/render/probe_design.h"
#include "sim/render/projector_radiance.h"
#include "sim/render/ray_caster.h"
#include "sim/render/scene_prep.h"

namespace d3d {

struct RenderOptions {
  bool noise = true;              // shot + read noise (quantisation and saturation always apply)
  bool gamma = true;              // projector gamma as calibrated (false: a linear projector; the
                                  // probe's calibration then says projector_gamma = 1)
  bool camera_defocus = true;     // camera blur from depth (false: no camera blur at all)
  bool projector_defocus = true;  // projector blur from depth (false: DMD pixels only)
  bool subsurface = true;         // sub-surface blur of the pattern on translucent materials
  bool specular = true;           // wet glints
  bool texture = true;            // procedural albedo texture
  int motion_blur_samples = 1;    // poses averaged over the exposure (1: the pose at mid-exposure)
  int64_t frame_interval_ns = 2'500'000;  // between frames of a burst
  int threads = 0;                        // worker threads, 0 = all cores
  uint64_t texture_seed = 1;              // the albedo texture of the scene (not noise)
  void Check() const;                     // throws std::invalid_argument
};

// world_from_probe at time t (ns): a Trajectory, or a constant pose.
using PoseAtTime = std::function<Rigid3d(int64_t t_ns)>;

class VirtualProbe {
 public:
  // Throws std::invalid_argument on an invalid design/options or an empty scene. The mesh is
  // prepared once (scene_prep.h: subdivision of coarse meshes, baked albedo texture).
  VirtualProbe(const TriangleMesh& scene, const ProbeDesign& design, const RenderOptions& options,
               std::vector<SceneSphere> spheres = {});
  ~VirtualProbe();
  VirtualProbe(const VirtualProbe&) = delete;
  VirtualProbe& operator=(const VirtualProbe&) = delete;

  const ProbeDesign& design() const { return design_; }
  const ProbeCalibration& calibration() const { return design_.calibration; }
  const RenderOptions& options() const { return options_; }
  const RayCaster& ray_caster() const { return *caster_; }
  // The scene as rendered: the input mesh, subdivided if coarse (face_index maps refer to the
  // input).
  const TriangleMesh& rendered_mesh() const { return scene_.mesh; }
  // The probe's own burst pattern set (calibration.pattern).
  const PatternSet& burst_patterns() const { return burst_patterns_; }

  // Renders frame `frame` at time t_ns. `noise_seed` selects the noise realisation. out->truth gets
  // the pose always and the truth maps when with_truth.
  void RenderFrame(const PoseAtTime& pose, int64_t t_ns, const ProjectorFrame& frame,
                   uint64_t noise_seed, bool with_truth, BurstFrame* out);
  // Renders all frames of `set` (default: the probe's burst set), frame i at t0 + i·interval.
  // The noise of frame i is seeded from (seed, sequence, i). With truth, also the truth at the
  // burst's reference time (Burst::reference_ns, the middle of the first and last exposure).
  Burst RenderBurst(const PoseAtTime& pose, int64_t t0_ns, uint64_t sequence, uint64_t seed,
                    bool with_truth, const PatternSet* set = nullptr);
  // Ground truth only (no shading, no noise) at a pose: cheap visibility/coverage queries.
  void RenderTruth(const Rigid3d& world_from_probe, FrameTruth* out);

 private:
  struct PixelGeometry;  // per-pixel hit and shading terms (virtual_probe.cpp)
  // shade = false fills only what FillTruth reads (RenderTruth).
  void GeometryPass(const Rigid3d& world_from_probe, bool shade, std::vector<PixelGeometry>* out);
  // geometry_ at world_from_probe, shaded if `shade`: reused when the last pass was at the same
  // pose (bit for bit; a still probe, the reference truth of a still burst), else computed.
  const std::vector<PixelGeometry>& GeometryAt(const Rigid3d& world_from_probe, bool shade);
  // The truth fields of g (what FillTruth reads) from a camera ray's hit; uv: the projector pixel
  // if lit, nullptr if not.
  void HitTruth(const SurfaceHit& hit, size_t pixel, const Eigen::Vector2d* uv,
                PixelGeometry* g) const;
  // The shading fields of g; uv as for HitTruth, and where lit, l and dist: the unit vector and the
  // distance from the hit to the projector's centre.
  void Shade(const SurfaceHit& hit, size_t pixel, const Eigen::Vector3d& cam_centre,
             const Eigen::Vector3d& p_in_proj, const Eigen::Vector2d* uv, const Eigen::Vector3d& l,
             double dist, PixelGeometry* g) const;
  void ShadePass(const std::vector<PixelGeometry>& geometry, const ProjectorRadiance& radiance,
                 float weight, cv::Mat* signal);
  void CameraDefocus(const std::vector<PixelGeometry>& geometry, cv::Mat* signal);
  void SensorPass(const cv::Mat& signal, uint64_t frame_seed, cv::Mat* image);
  void FillTruth(const std::vector<PixelGeometry>& geometry, int width, int height,
                 FrameTruth* out);
  const ProjectorRadiance& RadianceFor(const ProjectorFrame& frame);

  ProbeDesign design_;
  RenderOptions options_;
  PreparedScene scene_;
  std::unique_ptr<RayCaster> caster_;
  PatternSet burst_patterns_;
  tbb::task_arena arena_;
  std::vector<Eigen::Vector3d> pixel_rays_;  // (x, y, 1) per pixel in the camera frame, row-major
  std::vector<uint8_t> pixel_ray_valid_;
  DeviceBlur camera_blur_, projector_blur_;  // ProbeOptics::BlurSigmaPx of each device
  std::array<double, 3> specular_gate_{};  // per SurfaceLabel: smallest n·h worth a specular term
  std::mutex radiance_mutex_;
  std::unordered_map<std::string, std::unique_ptr<ProjectorRadiance>> radiance_cache_;
  // Scratch owned by the caller thread of Render* (see class comment).
  std::vector<PixelGeometry> geometry_;
  Rigid3d geometry_pose_;         // the pose geometry_ was computed at,
  bool geometry_valid_ = false;   // if any,
  bool geometry_shaded_ = false;  // and whether with the shading terms
  std::vector<PixelGeometry> geometry_sub_;
  std::vector<cv::Mat> blur_levels_;
  std::vector<float> pixel_sigma_, row_max_sigma_;  // CameraDefocus
};

// Frame seed used by RenderBurst: splitmix64 of (seed, sequence, frame index).
uint64_t FrameNoiseSeed(uint64_t seed, uint64_t sequence, int frame_index);

}  // namespace d3d
