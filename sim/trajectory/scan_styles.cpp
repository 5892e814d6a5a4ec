#include "sim/trajectory/scan_styles.h"

#include <algorithm>
#include <cmath>
#include <random>

namespace d3d {
namespace {

constexpr double kLiftMm =
    30.0;  // backed off this far along the axis: 80 mm from the teeth, beyond the 58 mm volume
constexpr int64_t kNsPerSecond = 1'000'000'000;

double SmoothStep(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return x * x * (3 - 2 * x);
}

// The segments of `r` within [from_ns, to_ns], shifted by shift_ns, appended to *out.
void AppendSegments(const std::vector<ScanSegment>& segments, int64_t from_ns, int64_t to_ns,
                    int64_t shift_ns, std::vector<ScanSegment>* out) {
  for (const ScanSegment& s : segments) {
    const int64_t a = std::max(s.start_ns, from_ns), b = std::min(s.end_ns, to_ns);
    if (b <= a) continue;
    out->push_back({s.phase, a + shift_ns, b + shift_ns});
  }
}

// `base` with lifts at seeded times (style "lifts").
ScanPathResult WithLifts(ScanPathResult base, uint32_t seed) {
  std::mt19937 rng(seed ^ 0x5eed11f7u);
  const int64_t t0 = base.trajectory.StartNs(), t1 = base.trajectory.EndNs();
  const double duration_s = static_cast<double>(t1 - t0) / kNsPerSecond;
  constexpr int kLifts = 3;
  // Cut k at a seeded time within the k-th of kLifts + 1 equal parts, past the first 8 s (the model
  // must hold more than the put-back point) and before the last 4 s.
  std::vector<int64_t> cuts;
  for (int k = 1; k <= kLifts; ++k) {
    const double part = duration_s / (kLifts + 1);
    const double lo = std::max(8.0, part * k - 0.3 * part),
                 hi = std::min(duration_s - 4, part * k + 0.3 * part);
    if (lo >= hi) continue;  // a path too short for this lift
    std::uniform_real_distribution<double> at(lo, hi);
    cuts.push_back(t0 + static_cast<int64_t>(at(rng) * kNsPerSecond));
  }
  std::uniform_real_distribution<double> lift_s(1.0, 3.0), back_s(2.0, 6.0);
  ScanPathResult out;
  out.status = base.status;
  out.arch = base.arch;
  // Pieces of the base path: [from, cut_k] then, after the lift, from cut_k − back on.
  Trajectory joined = base.trajectory;
  int64_t piece_start = t0;  // in base time
  int64_t shift = 0;         // output time − base time of the current piece
  for (int64_t cut : cuts) {
    if (cut <= piece_start + 2 * kNsPerSecond) continue;  // too close to the last put-back
    const int64_t lift = static_cast<int64_t>(lift_s(rng) * kNsPerSecond);
    const int64_t resume = std::max(t0, cut - static_cast<int64_t>(back_s(rng) * kNsPerSecond));
    AppendSegments(base.segments, piece_start, cut, shift, &out.segments);
    out.segments.push_back({ScanPhase::kLift, cut + shift, cut + shift + lift});
    joined = JoinWithLift(joined, cut + shift, base.trajectory, resume, lift, kLiftMm);
    shift += cut + lift - resume;
    piece_start = resume;
  }
  AppendSegments(base.segments, piece_start, t1, shift, &out.segments);
  out.trajectory = std::move(joined);
  return out;
}

// `r` played backwards over the same time span (its segments too): a path that ended at the
// midline starts there.
ScanPathResult Reversed(const ScanPathResult& r) {
  const int64_t t0 = r.trajectory.StartNs(), t1 = r.trajectory.EndNs();
  std::vector<TimedPose> keys(r.trajectory.keys().rbegin(), r.trajectory.keys().rend());
  for (TimedPose& k : keys) k.t_ns = t0 + t1 - k.t_ns;
  ScanPathResult out;
  out.status = r.status;
  out.arch = r.arch;
  out.trajectory = Trajectory(std::move(keys));
  for (auto s = r.segments.rbegin(); s != r.segments.rend(); ++s)
    out.segments.push_back({s->phase, t0 + t1 - s->end_ns, t0 + t1 - s->start_ns});
  return out;
}

// One quadrant, a lift of lift_ns, then the other quadrant (another hand motion). Each quadrant
// runs from its distal end to the midline (style "quadrants": the second starts on ground not yet
// scanned and joins the first over the incisors) or, `outward`, played backwards from the midline
// to its distal end (style "incisors-first": the second starts on the incisors the first began
// on, a re-entry onto the model's oldest part).
ScanPathResult TwoQuadrants(const ArchFrame& arch, const ScanPathOptions& base, bool outward,
                            int64_t lift_ns) {
  ScanPathOptions o = base;
  o.side = 0;
  ScanPathResult first = MakeScanTrajectory(arch, ScanKind::kQuadrant, o);
  if (!first.ok()) return first;
  o.side = 1;
  o.seed = base.seed + 7919;  // the other hand motion
  ScanPathResult second = MakeScanTrajectory(arch, ScanKind::kQuadrant, o);
  if (!second.ok()) return second;
  if (outward) {
    first = Reversed(first);
    second = Reversed(second);
  }
  const int64_t a_end = first.trajectory.EndNs(), b_start = second.trajectory.StartNs();
  ScanPathResult out;
  out.arch = arch;
  out.trajectory =
      JoinWithLift(first.trajectory, a_end, second.trajectory, b_start, lift_ns, kLiftMm);
  out.segments = first.segments;
  out.segments.push_back({ScanPhase::kLift, a_end, a_end + lift_ns});
  AppendSegments(second.segments, b_start, second.trajectory.EndNs(), a_end + lift_ns - b_start,
                 &out.segments);
  return out;
}

}  // namespace

const std::vector<std::string>& ScanStyleNames() {
  static const std::vector<std::string> names = {
      "full-arch", "buccal-first", "lingual-first",  "second-pass", "fast",
      "lifts",     "quadrants",    "incisors-first", "tooth",       "glare"};
  return names;
}

double ScanStyleWetness(const std::string& style) { return style == "glare" ? 3.0 : 1.0; }

std::string ScanStyleList(const std::string& separator) {
  std::string out;
  for (const std::string& n : ScanStyleNames()) out += (out.empty() ? "" : separator) + n;
  return out;
}

bool IsScanStyle(const std::string& name) {
  const auto& n = ScanStyleNames();
  return std::find(n.begin(), n.end(), name) != n.end();
}

Trajectory JoinWithLift(const Trajectory& a, int64_t a_end_ns, const Trajectory& b,
                        int64_t b_start_ns, int64_t lift_ns, double lift_mm,
                        int64_t key_interval_ns) {
  D3D_CHECK_MSG(!a.empty() && !b.empty(), "JoinWithLift: empty trajectory");
  D3D_CHECK_MSG(a_end_ns > a.StartNs() && a_end_ns <= a.EndNs(),
                "JoinWithLift: a_end_ns outside a");
  D3D_CHECK_MSG(b_start_ns >= b.StartNs() && b_start_ns < b.EndNs(),
                "JoinWithLift: b_start_ns outside b");
  D3D_CHECK_MSG(key_interval_ns > 0 && lift_ns > 2 * key_interval_ns,
                "JoinWithLift: lift_ns must exceed two key intervals");
  D3D_CHECK_MSG(std::isfinite(lift_mm) && lift_mm >= 0, "JoinWithLift: lift_mm must be >= 0");
  std::vector<TimedPose> keys;
  for (const TimedPose& k : a.keys())
    if (k.t_ns < a_end_ns) keys.push_back(k);
  const Rigid3d from = a.WorldFromProbe(a_end_ns), to = b.WorldFromProbe(b_start_ns);
  const Eigen::Vector3d turn = LogSO3(from.linear().transpose() * to.linear());
  // The lift: rise over its first quarter, hold, descend over its last quarter, while the pose
  // moves and turns from `from` to `to` (smooth step in time).
  const int steps = static_cast<int>(lift_ns / key_interval_ns);
  for (int i = 0; i <= steps; ++i) {
    const int64_t t = i == steps ? lift_ns : i * key_interval_ns;
    const double s = static_cast<double>(t) / static_cast<double>(lift_ns);
    const double w = SmoothStep(s);
    const double up = lift_mm * SmoothStep(s / 0.25) * SmoothStep((1 - s) / 0.25);
    Rigid3d p = Rigid3d::Identity();
    p.linear() = from.linear() * ExpSO3(w * turn);
    p.translation() = (1 - w) * from.translation() + w * to.translation() -
                      up * (p.linear() * Eigen::Vector3d::UnitZ());
    keys.push_back({a_end_ns + t, p});
  }
  const int64_t shift = a_end_ns + lift_ns - b_start_ns;
  for (const TimedPose& k : b.keys())
    if (k.t_ns > b_start_ns) keys.push_back({k.t_ns + shift, k.world_from_probe});
  return Trajectory(std::move(keys));
}

ScanPathResult MakeStyledScan(const TriangleMesh& mesh, const std::string& style,
                              const ScanPathOptions& base) {
  base.Check();
  ScanPathResult result;
  if (!IsScanStyle(style)) {
    result.status = InvalidArgument("unknown scan style '" + style + "'");
    return result;
  }
  const ArchFrame arch = AnalyzeArch(mesh);
  if (!arch.ok()) {
    result.status = arch.status;
    result.arch = arch;
    return result;
  }
  ScanPathOptions o = base;
  if (style == "tooth") return MakeScanTrajectory(arch, ScanKind::kTooth, o);
  if (style == "quadrants") return TwoQuadrants(arch, o, false, 2 * kNsPerSecond);
  if (style == "incisors-first") return TwoQuadrants(arch, o, true, 1'500'000'000);
  if (style == "buccal-first")
    o.passes = {ScanPhase::kBuccal, ScanPhase::kOcclusal, ScanPhase::kLingual};
  if (style == "lingual-first")
    o.passes = {ScanPhase::kLingual, ScanPhase::kOcclusal, ScanPhase::kBuccal};
  if (style == "second-pass") o.passes.push_back(ScanPhase::kOcclusal);
  if (style == "fast") {
    o.speed_mm_s = 27;
    o.max_camera_speed_mm_s = 35;
    o.transition_speed_mm_s = 25;
  }
  result = MakeScanTrajectory(arch, ScanKind::kFullArch, o);
  if (result.ok() && style == "lifts") result = WithLifts(std::move(result), o.seed);
  return result;
}

}  // namespace d3d
