// Rigid transforms. Convention: `target_from_source` maps a point expressed in `source` into
// `target`: p_in_world = world_from_probe * p_in_probe. Units: millimetres, radians.
#pragma once

#include <Eigen/Geometry>
#include <string>

namespace d3d {

using Rigid3d = Eigen::Isometry3d;

// Rigid transform from a unit quaternion (w, x, y, z) and a translation (mm).
Rigid3d RigidFromQuaternion(const Eigen::Quaterniond& q, const Eigen::Vector3d& t_mm);

// Geodesic interpolation between a (s = 0) and b (s = 1): slerp of the rotation, linear in the
// translation. s outside [0, 1] extrapolates.
Rigid3d InterpolateRigid(const Rigid3d& a, const Rigid3d& b, double s);

// Rotation angle of a·b⁻¹ (radians) and translation distance (mm): the pose error measures.
double RotationAngleRad(const Rigid3d& a, const Rigid3d& b);
double TranslationDistanceMm(const Rigid3d& a, const Rigid3d& b);

// The same pose bit for bit: a computation that is a function of the pose gives the same result
// (a pose equal as numbers but not as bits, −0 against +0, may not).
bool SameBits(const Rigid3d& a, const Rigid3d& b);

// The pose fields of a TUM trajectory line, "tx ty tz qx qy qz qw" (translation in mm to 1 nm,
// quaternion to 1e-9), space-separated with no leading or trailing space.
std::string TumPoseFields(const Rigid3d& pose);

// Rotation whose z axis is `forward` and whose x axis is as close as possible to `right_hint`
// (both in the target frame; they must not be parallel). Used to aim cameras and projectors.
Eigen::Matrix3d LookRotation(const Eigen::Vector3d& forward, const Eigen::Vector3d& right_hint);

}  // namespace d3d
