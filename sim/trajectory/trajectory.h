// Continuous-time rigid trajectory of the virtual probe: `world_from_probe(t)`, t in nanoseconds.
//
// Frames and units: the probe frame is the camera frame (OpenCV convention: origin at the optical
// centre, +z along the optical axis toward the scene, +x image right, +y image down). Positions are
// in millimetres, times in int64 nanoseconds, angles in radians. `world_from_probe` maps a point
// given in the probe frame into the world (scene) frame: p_world = world_from_probe * p_probe.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "common/core/rigid.h"
#include "common/core/status.h"

namespace d3d {

// One time-stamped key pose.
struct TimedPose {
  int64_t t_ns = 0;
  Rigid3d world_from_probe = Rigid3d::Identity();
};

// A C1-continuous rigid trajectory through time-stamped key poses.
//
// Interpolation on a segment [t_i, t_{i+1}] (h = t_{i+1} - t_i, s = (t - t_i) / h ∈ [0, 1]):
//  - Position: cubic Hermite spline (de Boor 1978, ch. IV) with the non-uniform Catmull-Rom tangent
//    v_i = ((p_{i+1}-p_i)/h_i · h_{i-1} + (p_i-p_{i-1})/h_{i-1} · h_i) / (h_{i-1} + h_i)
//    (the three-point derivative of the parabola through p_{i-1}, p_i, p_{i+1}); one-sided
//    differences at the first and last key. C1: velocity is continuous at the keys.
//  - Rotation: cubic Hermite in the exponential coordinates of the segment,
//    R(s) = R_i · Exp(φ(s)), φ(0) = 0, φ(1) = Log(R_iᵀ R_{i+1}),
//    φ'(0) = h ω_i, φ'(1) = h J_r⁻¹(φ(1)) ω_{i+1},
//    where ω_i is the body angular velocity at key i (same three-point estimate as positions, on
//    the relative rotations Log(R_{i-1}ᵀ R_i) and Log(R_iᵀ R_{i+1})) and J_r is the right Jacobian
//    of SO(3) (Chirikjian 2011, vol. 2, §10.6; Sola et al. 2018, "A micro Lie theory", eq. 143).
//    Since Rᵀ dR/ds = [J_r(φ) φ']×, the body angular velocity equals ω_i at s = 0 and ω_{i+1} at
//    s = 1: rotation is C1 as well, and it passes exactly through every key. Requires consecutive
//    keys less than π apart in rotation (always true for a sampled hand motion).
// Outside [StartNs(), EndNs()] the pose is clamped to the first / last key (zero velocity).
class Trajectory {
 public:
  // An empty trajectory (only useful as an output argument); WorldFromProbe on it throws.
  Trajectory() = default;
  // Throws std::invalid_argument unless there are ≥ 2 keys with strictly increasing times and
  // finite poses with proper rotations.
  explicit Trajectory(std::vector<TimedPose> keys);

  bool empty() const { return keys_.empty(); }
  const std::vector<TimedPose>& keys() const { return keys_; }
  int64_t StartNs() const;
  int64_t EndNs() const;
  int64_t DurationNs() const { return EndNs() - StartNs(); }

  // Pose of the probe at time t_ns (ns), clamped outside [StartNs(), EndNs()].
  Rigid3d WorldFromProbe(int64_t t_ns) const;

  // TUM RGB-D trajectory format (Sturm et al. 2012), one pose a line:
  //   timestamp tx ty tz qx qy qz qw
  // timestamp in seconds written with 9 decimals (exact ns), translation in MILLIMETRES (not the
  // metres of the original format), (qx, qy, qz, qw) the unit quaternion of world_from_probe's
  // rotation. Lines starting with '#' and blank lines are comments.
  [[nodiscard]] Status SaveTum(const std::string& path) const;
  // Reads a TUM file written by SaveTum (or any TUM file whose translations are in mm). Errors name
  // the file and the 1-based line: wrong field count, unparsable number, non-unit quaternion
  // (|q| off by more than 1e-3 is refused; smaller errors are normalised), times not increasing,
  // fewer than 2 poses. On error *out is left unchanged.
  static Status LoadTum(const std::string& path, Trajectory* out);

 private:
  // Index i of the segment [t_i, t_{i+1}] holding t (keys_.front().t_ns ≤ t < keys_.back().t_ns).
  size_t SegmentIndex(int64_t t_ns) const;

  std::vector<TimedPose> keys_;
  std::vector<Eigen::Vector3d> linear_velocity_;   // mm/ns at each key (world frame)
  std::vector<Eigen::Vector3d> angular_velocity_;  // rad/ns at each key (body frame)
  std::vector<Eigen::Vector3d> segment_log_;       // Log(R_iᵀ R_{i+1}) per segment, rad
};

// Finite-difference speeds at t (central difference over [t - step, t + step], clamped to the
// trajectory's span; one-sided at the ends). step_ns must be > 0.
// Linear speed of the probe's optical centre in mm/s.
double LinearSpeedMmPerS(const Trajectory& trajectory, int64_t t_ns, int64_t step_ns = 1'000'000);
// Angular speed of the probe's orientation in rad/s.
double AngularSpeedRadPerS(const Trajectory& trajectory, int64_t t_ns, int64_t step_ns = 1'000'000);

// SO(3) helpers used by the interpolation (exposed for tests). Rotation vectors in rad.
Eigen::Matrix3d ExpSO3(const Eigen::Vector3d& phi);
Eigen::Vector3d LogSO3(const Eigen::Matrix3d& R);
// Right Jacobian J_r(φ) and its inverse: Exp(φ + δ) ≈ Exp(φ) Exp(J_r(φ) δ).
Eigen::Matrix3d RightJacobianSO3(const Eigen::Vector3d& phi);
Eigen::Matrix3d RightJacobianInvSO3(const Eigen::Vector3d& phi);

}  // namespace d3d
