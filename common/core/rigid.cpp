#include "common/core/rigid.h"

#include <cmath>
#include <cstdio>
#include <cstring>

#include "common/core/status.h"

namespace d3d {

Rigid3d RigidFromQuaternion(const Eigen::Quaterniond& q, const Eigen::Vector3d& t_mm) {
  Rigid3d T = Rigid3d::Identity();
  T.linear() = q.normalized().toRotationMatrix();
  T.translation() = t_mm;
  return T;
}

std::string TumPoseFields(const Rigid3d& pose) {
  const Eigen::Quaterniond q(pose.linear());
  const Eigen::Vector3d t = pose.translation();
  char buf[192];
  std::snprintf(buf, sizeof buf, "%.6f %.6f %.6f %.9f %.9f %.9f %.9f", t.x(), t.y(), t.z(), q.x(),
                q.y(), q.z(), q.w());
  return buf;
}

Rigid3d InterpolateRigid(const Rigid3d& a, const Rigid3d& b, double s) {
  const Eigen::Quaterniond qa(a.rotation());
  Eigen::Quaterniond qb(b.rotation());
  if (qa.dot(qb) < 0) qb.coeffs() *= -1.0;  // shortest arc
  Eigen::Quaterniond q;
  if (s >= 0.0 && s <= 1.0) {
    q = qa.slerp(s, qb);
  } else {  // extrapolate along the geodesic: q = qa * (qa⁻¹ qb)^s
    const Eigen::AngleAxisd d(qa.conjugate() * qb);
    q = qa * Eigen::Quaterniond(Eigen::AngleAxisd(d.angle() * s, d.axis()));
  }
  return RigidFromQuaternion(q, (1.0 - s) * a.translation() + s * b.translation());
}

double RotationAngleRad(const Rigid3d& a, const Rigid3d& b) {
  return Eigen::AngleAxisd(a.rotation() * b.rotation().transpose()).angle();
}

double TranslationDistanceMm(const Rigid3d& a, const Rigid3d& b) {
  return (a.translation() - b.translation()).norm();
}

bool SameBits(const Rigid3d& a, const Rigid3d& b) {
  return std::memcmp(a.data(), b.data(), sizeof(double) * static_cast<size_t>(a.matrix().size())) ==
         0;
}

Eigen::Matrix3d LookRotation(const Eigen::Vector3d& forward, const Eigen::Vector3d& right_hint) {
  const Eigen::Vector3d z = forward.normalized();
  Eigen::Vector3d x = right_hint - right_hint.dot(z) * z;
  D3D_CHECK_MSG(x.norm() > 1e-9 * right_hint.norm(),
                "LookRotation: right_hint parallel to forward");
  x.normalize();
  const Eigen::Vector3d y = z.cross(x);
  Eigen::Matrix3d R;
  R.col(0) = x;
  R.col(1) = y;
  R.col(2) = z;
  return R;
}

}  // namespace d3d
