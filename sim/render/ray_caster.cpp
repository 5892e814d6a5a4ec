#include "sim/render/ray_caster.h"

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "common/core/status.h"

namespace d3d {
namespace {

RTCRay MakeRay(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min, double t_max) {
  RTCRay r;
  r.org_x = static_cast<float>(o.x());
  r.org_y = static_cast<float>(o.y());
  r.org_z = static_cast<float>(o.z());
  r.dir_x = static_cast<float>(d.x());
  r.dir_y = static_cast<float>(d.y());
  r.dir_z = static_cast<float>(d.z());
  r.tnear = static_cast<float>(t_min);
  r.tfar = t_max == std::numeric_limits<double>::infinity() ? std::numeric_limits<float>::infinity()
                                                            : static_cast<float>(t_max);
  r.time = 0.0f;
  r.mask = 0xFFFFFFFFu;
  r.id = 0;
  r.flags = 0;
  return r;
}

Eigen::Vector3d FacingOrigin(const Eigen::Vector3d& n, const Eigen::Vector3d& d) {
  return n.dot(d) > 0 ? -n : n;
}

}  // namespace

RayCaster::RayCaster(const TriangleMesh& mesh, std::vector<SceneSphere> spheres)
    : mesh_(mesh), spheres_(std::move(spheres)) {
  mesh_.Check();
  D3D_CHECK_MSG(!mesh_.faces.empty() || !spheres_.empty(),
                "the scene is empty (no triangles, no spheres)");
  for (const auto& s : spheres_) D3D_CHECK_MSG(s.radius_mm > 0, "sphere radius must be positive");
  face_normals_.resize(mesh_.faces.size());
  for (size_t i = 0; i < mesh_.faces.size(); ++i) {
    const Eigen::Vector3i& f = mesh_.faces[i];
    const Eigen::Vector3d& a = mesh_.vertices[static_cast<size_t>(f[0])];
    const Eigen::Vector3d e1 = mesh_.vertices[static_cast<size_t>(f[1])] - a;
    const Eigen::Vector3d e2 = mesh_.vertices[static_cast<size_t>(f[2])] - a;
    face_normals_[i] = e1.cross(e2).normalized();
  }
  device_ = rtcNewDevice("verbose=0");
  if (!device_)
    throw std::runtime_error("Embree: rtcNewDevice failed (error " +
                             std::to_string(rtcGetDeviceError(nullptr)) + ")");
  scene_ = rtcNewScene(device_);
  rtcSetSceneBuildQuality(scene_, RTC_BUILD_QUALITY_HIGH);
  if (!mesh_.faces.empty()) {
    RTCGeometry g = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_TRIANGLE);
    // rtcSetNewGeometryBuffer allocates with the padding Embree needs after the last vertex.
    auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(
        g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), mesh_.vertices.size()));
    for (size_t i = 0; i < mesh_.vertices.size(); ++i)
      for (int k = 0; k < 3; ++k) v[3 * i + k] = static_cast<float>(mesh_.vertices[i][k]);
    auto* f = static_cast<unsigned*>(rtcSetNewGeometryBuffer(
        g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), mesh_.faces.size()));
    for (size_t i = 0; i < mesh_.faces.size(); ++i)
      for (int k = 0; k < 3; ++k) f[3 * i + k] = static_cast<unsigned>(mesh_.faces[i][k]);
    rtcCommitGeometry(g);
    mesh_geom_id_ = rtcAttachGeometry(scene_, g);
    rtcReleaseGeometry(g);
  }
  if (!spheres_.empty()) {
    RTCGeometry g = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_SPHERE_POINT);
    auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(
        g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, 4 * sizeof(float), spheres_.size()));
    for (size_t i = 0; i < spheres_.size(); ++i) {
      for (int k = 0; k < 3; ++k) v[4 * i + k] = static_cast<float>(spheres_[i].centre_mm[k]);
      v[4 * i + 3] = static_cast<float>(spheres_[i].radius_mm);
    }
    rtcCommitGeometry(g);
    sphere_geom_id_ = rtcAttachGeometry(scene_, g);
    rtcReleaseGeometry(g);
  }
  rtcCommitScene(scene_);
  if (rtcGetDeviceError(device_) != RTC_ERROR_NONE)
    throw std::runtime_error("Embree: scene build failed");
}

RayCaster::~RayCaster() {
  if (scene_) rtcReleaseScene(scene_);
  if (device_) rtcReleaseDevice(device_);
}

bool RayCaster::RefineTriangle(int face, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                               SurfaceHit* hit) const {
  // Möller & Trumbore 1997, "Fast, minimum storage ray-triangle intersection", in double.
  const Eigen::Vector3i& f = mesh_.faces[static_cast<size_t>(face)];
  const Eigen::Vector3d& a = mesh_.vertices[static_cast<size_t>(f[0])];
  const Eigen::Vector3d e1 = mesh_.vertices[static_cast<size_t>(f[1])] - a;
  const Eigen::Vector3d e2 = mesh_.vertices[static_cast<size_t>(f[2])] - a;
  const Eigen::Vector3d p = d.cross(e2);
  const double det = e1.dot(p);
  if (std::abs(det) < 1e-300) return false;
  const double inv = 1.0 / det;
  const Eigen::Vector3d s = o - a;
  const double b1 = s.dot(p) * inv;
  const Eigen::Vector3d q = s.cross(e1);
  const double b2 = d.dot(q) * inv;
  const double t = e2.dot(q) * inv;
  hit->t = t;
  hit->point = o + t * d;
  hit->geometric_normal = FacingOrigin(face_normals_[static_cast<size_t>(face)], d);
  if (!mesh_.vertex_normals.empty()) {
    // Barycentrics may stray slightly outside [0,1] where Embree's float hit was on an edge.
    const double c1 = std::clamp(b1, 0.0, 1.0), c2 = std::clamp(b2, 0.0, 1.0 - c1);
    const Eigen::Vector3d ns = (1.0 - c1 - c2) * mesh_.vertex_normals[static_cast<size_t>(f[0])] +
                               c1 * mesh_.vertex_normals[static_cast<size_t>(f[1])] +
                               c2 * mesh_.vertex_normals[static_cast<size_t>(f[2])];
    hit->shading_normal =
        ns.squaredNorm() > 0 ? FacingOrigin(ns.normalized(), d) : hit->geometric_normal;
  } else {
    hit->shading_normal = hit->geometric_normal;
  }
  hit->label = mesh_.Label(face);
  hit->tooth_id =
      mesh_.face_tooth_ids.empty() ? 0 : mesh_.face_tooth_ids[static_cast<size_t>(face)];
  hit->face = face;
  hit->b1 = b1;
  hit->b2 = b2;
  return true;
}

bool RayCaster::RefineSphere(int index, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                             SurfaceHit* hit) const {
  const SceneSphere& s = spheres_[static_cast<size_t>(index)];
  const Eigen::Vector3d oc = o - s.centre_mm;
  const double a = d.squaredNorm(), b = oc.dot(d), c = oc.squaredNorm() - s.radius_mm * s.radius_mm;
  const double disc = b * b - a * c;
  if (disc < 0) return false;
  const double sq = std::sqrt(disc);
  // Numerically stable roots (Press et al., Numerical Recipes §5.6).
  const double qq = -(b + std::copysign(sq, b));
  double t0 = qq / a, t1 = c / qq;
  if (t0 > t1) std::swap(t0, t1);
  const double t = t0 > 0 ? t0 : t1;
  hit->t = t;
  hit->point = o + t * d;
  const Eigen::Vector3d n = (hit->point - s.centre_mm).normalized();
  hit->geometric_normal = FacingOrigin(n, d);
  hit->shading_normal = hit->geometric_normal;
  hit->label = s.label;
  hit->tooth_id = 0;
  hit->face = -1;
  return true;
}

std::optional<SurfaceHit> RayCaster::Intersect(const Eigen::Vector3d& origin,
                                               const Eigen::Vector3d& direction,
                                               double t_min) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh;
  rh.ray = MakeRay(origin, direction, t_min, std::numeric_limits<double>::infinity());
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(scene_, &ctx, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return std::nullopt;
  SurfaceHit hit;
  const bool ok = rh.hit.geomID == mesh_geom_id_
                      ? RefineTriangle(static_cast<int>(rh.hit.primID), origin, direction, &hit)
                      : RefineSphere(static_cast<int>(rh.hit.primID), origin, direction, &hit);
  if (!ok || !(hit.t > t_min)) return std::nullopt;
  return hit;
}

bool RayCaster::Occluded(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                         double t_min, double t_max) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRay r = MakeRay(origin, direction, t_min, t_max);
  rtcOccluded1(scene_, &ctx, &r);
  return r.tfar < 0.0f;  // Embree sets tfar = -inf on a hit
}

}  // namespace d3d

namespace d3d {

void RayCaster::Intersect16(const Eigen::Vector3d& origin, const Eigen::Vector3d* directions,
                            int count, double t_min, SurfaceHit* hits, bool* hit) const {
  RTCRayHit16 rh;
  alignas(64) int valid[kPacket];
  for (int i = 0; i < kPacket; ++i) {
    const bool on = i < count;
    valid[i] = on ? -1 : 0;
    const Eigen::Vector3d& d = directions[on ? i : 0];
    rh.ray.org_x[i] = static_cast<float>(origin.x());
    rh.ray.org_y[i] = static_cast<float>(origin.y());
    rh.ray.org_z[i] = static_cast<float>(origin.z());
    rh.ray.dir_x[i] = static_cast<float>(d.x());
    rh.ray.dir_y[i] = static_cast<float>(d.y());
    rh.ray.dir_z[i] = static_cast<float>(d.z());
    rh.ray.tnear[i] = static_cast<float>(t_min);
    rh.ray.tfar[i] = std::numeric_limits<float>::infinity();
    rh.ray.time[i] = 0.0f;
    rh.ray.mask[i] = 0xFFFFFFFFu;
    rh.ray.id[i] = static_cast<unsigned>(i);
    rh.ray.flags[i] = 0;
    rh.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
  }
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  rtcIntersect16(valid, scene_, &ctx, &rh);
  for (int i = 0; i < count; ++i) {
    hit[i] = false;
    if (rh.hit.geomID[i] == RTC_INVALID_GEOMETRY_ID) continue;
    const int prim = static_cast<int>(rh.hit.primID[i]);
    const bool ok = rh.hit.geomID[i] == mesh_geom_id_
                        ? RefineTriangle(prim, origin, directions[i], &hits[i])
                        : RefineSphere(prim, origin, directions[i], &hits[i]);
    hit[i] = ok && hits[i].t > t_min;
  }
}

void RayCaster::OccludedToPoint16(const Eigen::Vector3d* origins, const bool* active, int count,
                                  const Eigen::Vector3d& target, double t_min,
                                  bool* occluded) const {
  Eigen::Vector3d unit[kPacket];
  double distance[kPacket];
  for (int i = 0; i < count; ++i) {
    if (!active[i]) continue;
    unit[i] = target - origins[i];
    distance[i] = unit[i].norm();
    if (distance[i] > 0) unit[i] /= distance[i];
  }
  OccludedToPoint16(origins, unit, distance, active, count, target, t_min, occluded);
}

void RayCaster::OccludedToPoint16(const Eigen::Vector3d* origins, const Eigen::Vector3d* unit,
                                  const double* distance, const bool* active, int count,
                                  const Eigen::Vector3d& target, double t_min,
                                  bool* occluded) const {
  RTCRay16 r;
  alignas(64) int valid[kPacket];
  for (int i = 0; i < kPacket; ++i) {
    const bool on = i < count && active[i];
    valid[i] = on ? -1 : 0;
    // An inactive ray starts at the target with a zero direction.
    const Eigen::Vector3d& o = on ? origins[i] : target;
    const Eigen::Vector3d d = on ? unit[i] : Eigen::Vector3d::Zero();
    const double dist = on ? distance[i] : 0.0;
    r.org_x[i] = static_cast<float>(o.x());
    r.org_y[i] = static_cast<float>(o.y());
    r.org_z[i] = static_cast<float>(o.z());
    r.dir_x[i] = static_cast<float>(d.x());
    r.dir_y[i] = static_cast<float>(d.y());
    r.dir_z[i] = static_cast<float>(d.z());
    r.tnear[i] = static_cast<float>(t_min);
    r.tfar[i] = static_cast<float>(std::max(dist - t_min, t_min));
    r.time[i] = 0.0f;
    r.mask[i] = 0xFFFFFFFFu;
    r.id[i] = static_cast<unsigned>(i);
    r.flags[i] = 0;
  }
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  rtcOccluded16(valid, scene_, &ctx, &r);
  for (int i = 0; i < count; ++i) occluded[i] = valid[i] != 0 && r.tfar[i] < 0.0f;
}

}  // namespace d3d
