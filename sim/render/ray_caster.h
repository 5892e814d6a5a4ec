// Ray casting of a scene (a triangle mesh plus optional analytic spheres) with Embree 3.
//
// Embree finds the hit in single precision; the hit is then refined in double precision on the
// primitive Embree found (Möller–Trumbore for triangles, the quadratic for spheres), so surface
// points and depths are exact to ~1e-9 mm rather than float's ~1e-5 mm at 50 mm.
// Thread safety: Intersect/Occluded are const and may be called from any number of threads.
#pragma once

#include <embree3/rtcore.h>

#include <Eigen/Geometry>
#include <memory>
#include <optional>
#include <vector>

#include "common/mesh/mesh.h"

namespace d3d {

// An analytic sphere (tests with analytic ground truth).
struct SceneSphere {
  Eigen::Vector3d centre_mm = Eigen::Vector3d::Zero();
  double radius_mm = 1.0;
  SurfaceLabel label = SurfaceLabel::kTooth;
};

struct SurfaceHit {
  double t = 0.0;                    // ray parameter: point = origin + t · direction
  Eigen::Vector3d point;             // world, mm
  Eigen::Vector3d geometric_normal;  // unit, faces the ray origin
  Eigen::Vector3d
      shading_normal;  // unit (interpolated vertex normals if present), faces the origin
  SurfaceLabel label = SurfaceLabel::kUnknown;
  uint8_t tooth_id = 0;
  int face = -1;              // triangle index, or -1 for a sphere
  double b1 = 0.0, b2 = 0.0;  // barycentrics of corners 1 and 2 (triangles)
};

class RayCaster {
 public:
  // Copies the geometry into Embree. Throws std::invalid_argument for an empty scene or an invalid
  // mesh, std::runtime_error if Embree cannot be initialised.
  RayCaster(const TriangleMesh& mesh, std::vector<SceneSphere> spheres = {});
  ~RayCaster();
  RayCaster(const RayCaster&) = delete;
  RayCaster& operator=(const RayCaster&) = delete;

  // First surface along origin + t·direction, t in (t_min, ∞). `direction` need not be unit.
  std::optional<SurfaceHit> Intersect(const Eigen::Vector3d& origin,
                                      const Eigen::Vector3d& direction, double t_min = 0.0) const;
  // True if anything lies along origin + t·direction for t in (t_min, t_max).
  bool Occluded(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, double t_min,
                double t_max) const;

  // Packet versions (Embree's rtcIntersect16/rtcOccluded16; coherent rays, e.g. a 4×4 pixel tile,
  // are several times faster than one by one). Same results as the single-ray calls.
  static constexpr int kPacket = 16;
  // count ≤ 16 rays from one origin; hit[i] is false where ray i meets nothing (t > t_min).
  void Intersect16(const Eigen::Vector3d& origin, const Eigen::Vector3d* directions, int count,
                   double t_min, SurfaceHit* hits, bool* hit) const;
  // Shadow rays from origins[i] (where active[i]) toward `target`; occluded[i] is true if anything
  // lies strictly between, more than t_min (mm) from both ends. Inactive rays report false.
  void OccludedToPoint16(const Eigen::Vector3d* origins, const bool* active, int count,
                         const Eigen::Vector3d& target, double t_min, bool* occluded) const;
  // The same with the rays as that call computes them, from a caller that has them already: for
  // each active ray, distance[i] = (target − origins[i]).norm() > 0 and unit[i] = (target −
  // origins[i]) / distance[i].
  void OccludedToPoint16(const Eigen::Vector3d* origins, const Eigen::Vector3d* unit,
                         const double* distance, const bool* active, int count,
                         const Eigen::Vector3d& target, double t_min, bool* occluded) const;

  const TriangleMesh& mesh() const { return mesh_; }

 private:
  bool RefineTriangle(int face, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                      SurfaceHit* hit) const;
  bool RefineSphere(int index, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                    SurfaceHit* hit) const;

  TriangleMesh mesh_;
  // Unit geometric normal of each face, e1 × e2 normalised as RefineTriangle would compute it per
  // hit (the same operations once per face at set-up: the same bits, one sqrt and division less).
  std::vector<Eigen::Vector3d> face_normals_;
  std::vector<SceneSphere> spheres_;
  RTCDevice device_ = nullptr;
  RTCScene scene_ = nullptr;
  unsigned mesh_geom_id_ = RTC_INVALID_GEOMETRY_ID;
  unsigned sphere_geom_id_ = RTC_INVALID_GEOMETRY_ID;
};

}  // namespace d3d
