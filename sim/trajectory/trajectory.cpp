#include "sim/trajectory/trajectory.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>

namespace d3d {
namespace {

constexpr double kNsPerS = 1e9;

Eigen::Matrix3d Hat(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}

double SecondsBetween(int64_t a_ns, int64_t b_ns) {
  return static_cast<double>(b_ns - a_ns) / kNsPerS;
}

// Three-point derivative at a key from the slopes of its two neighbouring segments, weighted by the
// opposite interval (the derivative of the parabola through the three keys; Catmull-Rom when the
// intervals are equal).
Eigen::Vector3d ThreePointDerivative(const Eigen::Vector3d& slope_prev, double h_prev,
                                     const Eigen::Vector3d& slope_next, double h_next) {
  return (slope_next * h_prev + slope_prev * h_next) / (h_prev + h_next);
}

// Cubic Hermite basis functions (s ∈ [0, 1]).
struct HermiteBasis {
  double h00, h10, h01, h11;
  explicit HermiteBasis(double s) {
    const double s2 = s * s, s3 = s2 * s;
    h00 = 2 * s3 - 3 * s2 + 1;
    h10 = s3 - 2 * s2 + s;
    h01 = -2 * s3 + 3 * s2;
    h11 = s3 - s2;
  }
};

bool IsProperRotation(const Eigen::Matrix3d& R) {
  return R.allFinite() && (R.transpose() * R - Eigen::Matrix3d::Identity()).norm() < 1e-6 &&
         std::abs(R.determinant() - 1.0) < 1e-6;
}

// "12.000000345" (seconds, 9 decimals, exact) for a time in ns.
std::string FormatSeconds(int64_t t_ns) {
  const bool negative = t_ns < 0;
  // Work with the magnitude in unsigned arithmetic so INT64_MIN does not overflow.
  const uint64_t mag =
      negative ? static_cast<uint64_t>(-(t_ns + 1)) + 1u : static_cast<uint64_t>(t_ns);
  char buf[48];
  std::snprintf(buf, sizeof(buf), "%s%llu.%09llu", negative ? "-" : "",
                static_cast<unsigned long long>(mag / 1'000'000'000u),
                static_cast<unsigned long long>(mag % 1'000'000'000u));
  return buf;
}

bool ParseDouble(const std::string& token, double* value) {
  if (token.empty()) return false;
  errno = 0;
  char* end = nullptr;
  const double v = std::strtod(token.c_str(), &end);
  if (end != token.c_str() + token.size() || errno == ERANGE || !std::isfinite(v)) return false;
  *value = v;
  return true;
}

// Seconds as written by SaveTum ("[-]digits[.digits]") are converted exactly; anything else that
// strtod accepts (exponents) goes through a double.
bool ParseSecondsToNs(const std::string& token, int64_t* t_ns) {
  size_t i = 0;
  bool negative = false;
  if (i < token.size() && (token[i] == '-' || token[i] == '+')) negative = token[i++] == '-';
  const size_t int_begin = i;
  while (i < token.size() && std::isdigit(static_cast<unsigned char>(token[i]))) ++i;
  const size_t int_end = i;
  size_t frac_begin = i, frac_end = i;
  if (i < token.size() && token[i] == '.') {
    frac_begin = ++i;
    while (i < token.size() && std::isdigit(static_cast<unsigned char>(token[i]))) ++i;
    frac_end = i;
  }
  const bool plain = i == token.size() && (int_end > int_begin || frac_end > frac_begin);
  if (!plain || int_end - int_begin > 10) {
    double seconds = 0;
    if (!ParseDouble(token, &seconds) || std::abs(seconds) > 9.2e9) return false;
    *t_ns = std::llround(seconds * kNsPerS);
    return true;
  }
  uint64_t whole = 0;
  for (size_t k = int_begin; k < int_end; ++k)
    whole = whole * 10 + static_cast<uint64_t>(token[k] - '0');
  if (whole > 9'200'000'000ull) return false;
  uint64_t frac = 0;
  for (size_t k = 0; k < 9; ++k) {
    const size_t pos = frac_begin + k;
    frac = frac * 10 + (pos < frac_end ? static_cast<uint64_t>(token[pos] - '0') : 0u);
  }
  if (frac_begin + 9 < frac_end && token[frac_begin + 9] >= '5') ++frac;  // round the 10th digit
  const int64_t mag = static_cast<int64_t>(whole * 1'000'000'000ull + frac);
  *t_ns = negative ? -mag : mag;
  return true;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// SO(3)

Eigen::Matrix3d ExpSO3(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  if (theta < 1e-12) return Eigen::Matrix3d::Identity() + Hat(phi);
  return Eigen::AngleAxisd(theta, phi / theta).toRotationMatrix();
}

Eigen::Vector3d LogSO3(const Eigen::Matrix3d& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
}

Eigen::Matrix3d RightJacobianSO3(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  const Eigen::Matrix3d K = Hat(phi);
  if (theta < 1e-6) return Eigen::Matrix3d::Identity() - 0.5 * K + K * K / 6.0;
  const double t2 = theta * theta;
  return Eigen::Matrix3d::Identity() - (1.0 - std::cos(theta)) / t2 * K +
         (theta - std::sin(theta)) / (t2 * theta) * K * K;
}

Eigen::Matrix3d RightJacobianInvSO3(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  const Eigen::Matrix3d K = Hat(phi);
  if (theta < 1e-6) return Eigen::Matrix3d::Identity() + 0.5 * K + K * K / 12.0;
  const double coeff =
      1.0 / (theta * theta) - (1.0 + std::cos(theta)) / (2.0 * theta * std::sin(theta));
  return Eigen::Matrix3d::Identity() + 0.5 * K + coeff * K * K;
}

// ---------------------------------------------------------------------------------------------
// Trajectory

Trajectory::Trajectory(std::vector<TimedPose> keys) : keys_(std::move(keys)) {
  D3D_CHECK_MSG(keys_.size() >= 2, "a trajectory needs at least 2 key poses, got " << keys_.size());
  for (size_t i = 0; i < keys_.size(); ++i) {
    const Rigid3d& T = keys_[i].world_from_probe;
    D3D_CHECK_MSG(T.translation().allFinite(), "key " << i << ": non-finite translation");
    D3D_CHECK_MSG(IsProperRotation(T.linear()), "key " << i << ": not a proper rotation");
    if (i > 0) {
      D3D_CHECK_MSG(keys_[i].t_ns > keys_[i - 1].t_ns, "key times must be strictly increasing: key "
                                                           << i << " at " << keys_[i].t_ns
                                                           << " ns after " << keys_[i - 1].t_ns
                                                           << " ns");
    }
  }
  const size_t n = keys_.size();
  std::vector<double> h(n - 1);
  std::vector<Eigen::Vector3d> slope(n - 1), rot_slope(n - 1);
  segment_log_.resize(n - 1);
  for (size_t i = 0; i + 1 < n; ++i) {
    h[i] = SecondsBetween(keys_[i].t_ns, keys_[i + 1].t_ns);
    slope[i] =
        (keys_[i + 1].world_from_probe.translation() - keys_[i].world_from_probe.translation()) /
        h[i];
    segment_log_[i] = LogSO3(keys_[i].world_from_probe.linear().transpose() *
                             keys_[i + 1].world_from_probe.linear());
    // Log(R_iᵀ R_{i+1}) is the same vector whether read in frame i or i+1 (a rotation fixes its
    // axis).
    rot_slope[i] = segment_log_[i] / h[i];
  }
  linear_velocity_.resize(n);
  angular_velocity_.resize(n);
  linear_velocity_.front() = slope.front();
  angular_velocity_.front() = rot_slope.front();
  linear_velocity_.back() = slope.back();
  angular_velocity_.back() = rot_slope.back();
  for (size_t i = 1; i + 1 < n; ++i) {
    linear_velocity_[i] = ThreePointDerivative(slope[i - 1], h[i - 1], slope[i], h[i]);
    angular_velocity_[i] = ThreePointDerivative(rot_slope[i - 1], h[i - 1], rot_slope[i], h[i]);
  }
}

int64_t Trajectory::StartNs() const {
  D3D_CHECK_MSG(!keys_.empty(), "empty trajectory");
  return keys_.front().t_ns;
}

int64_t Trajectory::EndNs() const {
  D3D_CHECK_MSG(!keys_.empty(), "empty trajectory");
  return keys_.back().t_ns;
}

size_t Trajectory::SegmentIndex(int64_t t_ns) const {
  const auto it = std::upper_bound(keys_.begin(), keys_.end(), t_ns,
                                   [](int64_t t, const TimedPose& k) { return t < k.t_ns; });
  return static_cast<size_t>(it - keys_.begin()) - 1;
}

Rigid3d Trajectory::WorldFromProbe(int64_t t_ns) const {
  D3D_CHECK_MSG(!keys_.empty(), "WorldFromProbe on an empty trajectory");
  if (t_ns <= keys_.front().t_ns) return keys_.front().world_from_probe;
  if (t_ns >= keys_.back().t_ns) return keys_.back().world_from_probe;
  const size_t i = SegmentIndex(t_ns);
  const TimedPose& a = keys_[i];
  const TimedPose& b = keys_[i + 1];
  const double h = SecondsBetween(a.t_ns, b.t_ns);
  const double s = static_cast<double>(t_ns - a.t_ns) / static_cast<double>(b.t_ns - a.t_ns);
  const HermiteBasis H(s);

  const Eigen::Vector3d p =
      H.h00 * a.world_from_probe.translation() + H.h10 * h * linear_velocity_[i] +
      H.h01 * b.world_from_probe.translation() + H.h11 * h * linear_velocity_[i + 1];
  const Eigen::Vector3d& phi1 = segment_log_[i];
  const Eigen::Vector3d phi = H.h10 * h * angular_velocity_[i] + H.h01 * phi1 +
                              H.h11 * h * (RightJacobianInvSO3(phi1) * angular_velocity_[i + 1]);
  Rigid3d T = Rigid3d::Identity();
  T.linear() = a.world_from_probe.linear() * ExpSO3(phi);
  T.translation() = p;
  return T;
}

// ---------------------------------------------------------------------------------------------
// TUM I/O

Status Trajectory::SaveTum(const std::string& path) const {
  if (keys_.empty()) return InvalidArgument("SaveTum: empty trajectory");
  std::ofstream os(path);
  if (!os) return IoError("cannot open '" + path + "' for writing");
  os << "# d3dscan probe trajectory: world_from_probe, probe = camera frame (OpenCV)\n"
     << "# timestamp[s] tx ty tz[mm] qx qy qz qw\n";
  char buf[256];
  for (const TimedPose& k : keys_) {
    const Eigen::Quaterniond q(k.world_from_probe.linear());
    const Eigen::Vector3d& t = k.world_from_probe.translation();
    std::snprintf(buf, sizeof(buf), " %.9f %.9f %.9f %.12f %.12f %.12f %.12f\n", t.x(), t.y(),
                  t.z(), q.x(), q.y(), q.z(), q.w());
    os << FormatSeconds(k.t_ns) << buf;
  }
  os.flush();
  if (!os) return IoError("write failed: '" + path + "'");
  return Status::Ok();
}

Status Trajectory::LoadTum(const std::string& path, Trajectory* out) {
  if (out == nullptr) return InvalidArgument("LoadTum: null output");
  std::ifstream is(path);
  if (!is) return NotFound("cannot open TUM trajectory '" + path + "'");
  std::vector<TimedPose> keys;
  std::string line;
  int line_no = 0;
  while (std::getline(is, line)) {
    ++line_no;
    const std::string where = path + ":" + std::to_string(line_no) + ": ";
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const size_t first = line.find_first_not_of(" \t");
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream ls(line);
    std::vector<std::string> tokens;
    for (std::string tok; ls >> tok;) tokens.push_back(tok);
    if (tokens.size() != 8) {
      return ParseError(where + "expected 8 fields 'timestamp tx ty tz qx qy qz qw', got " +
                        std::to_string(tokens.size()));
    }
    TimedPose key;
    if (!ParseSecondsToNs(tokens[0], &key.t_ns))
      return ParseError(where + "bad timestamp '" + tokens[0] + "'");
    double v[7];
    for (int k = 0; k < 7; ++k) {
      if (!ParseDouble(tokens[static_cast<size_t>(k) + 1], &v[k])) {
        return ParseError(where + "bad number '" + tokens[static_cast<size_t>(k) + 1] +
                          "' in field " + std::to_string(k + 2));
      }
    }
    Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);  // (w, x, y, z)
    if (std::abs(q.norm() - 1.0) > 1e-3) {
      return ParseError(where + "quaternion is not unit (|q| = " + std::to_string(q.norm()) + ")");
    }
    key.world_from_probe = RigidFromQuaternion(q, Eigen::Vector3d(v[0], v[1], v[2]));
    if (!keys.empty() && key.t_ns <= keys.back().t_ns) {
      return ParseError(where + "timestamp " + tokens[0] + " s is not after the previous pose's");
    }
    keys.push_back(key);
  }
  if (is.bad()) return IoError("read failed: '" + path + "'");
  if (keys.size() < 2) {
    return ParseError(path + ": a trajectory needs at least 2 poses, found " +
                      std::to_string(keys.size()));
  }
  *out = Trajectory(std::move(keys));
  return Status::Ok();
}

// ---------------------------------------------------------------------------------------------
// Speeds

namespace {
// The central-difference window [t0, t1] around t, clamped into the trajectory's span.
std::pair<int64_t, int64_t> DifferenceWindow(const Trajectory& trajectory, int64_t t_ns,
                                             int64_t step_ns) {
  D3D_CHECK_MSG(step_ns > 0, "finite-difference step must be positive, got " << step_ns);
  const int64_t t0 = std::max(trajectory.StartNs(), t_ns - step_ns);
  const int64_t t1 = std::min(trajectory.EndNs(), t_ns + step_ns);
  return {t0, t1};
}
}  // namespace

double LinearSpeedMmPerS(const Trajectory& trajectory, int64_t t_ns, int64_t step_ns) {
  const auto [t0, t1] = DifferenceWindow(trajectory, t_ns, step_ns);
  if (t1 <= t0) return 0.0;
  return TranslationDistanceMm(trajectory.WorldFromProbe(t1), trajectory.WorldFromProbe(t0)) /
         SecondsBetween(t0, t1);
}

double AngularSpeedRadPerS(const Trajectory& trajectory, int64_t t_ns, int64_t step_ns) {
  const auto [t0, t1] = DifferenceWindow(trajectory, t_ns, step_ns);
  if (t1 <= t0) return 0.0;
  return RotationAngleRad(trajectory.WorldFromProbe(t1), trajectory.WorldFromProbe(t0)) /
         SecondsBetween(t0, t1);
}

}  // namespace d3d
