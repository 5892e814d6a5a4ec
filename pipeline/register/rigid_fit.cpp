#include "pipeline/register/rigid_fit.h"

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <random>

#include "common/core/status.h"

namespace d3d {

std::optional<Rigid3d> FitRigid(const std::vector<Correspondence3d>& c, double min_spread_mm) {
  double wsum = 0;
  int used = 0;
  Eigen::Vector3d ms = Eigen::Vector3d::Zero(), mt = Eigen::Vector3d::Zero();
  for (const auto& k : c) {
    if (!(k.weight > 0)) continue;
    wsum += k.weight;
    ms += k.weight * k.source;
    mt += k.weight * k.target;
    ++used;
  }
  if (used < 3 || !(wsum > 0)) return std::nullopt;
  ms /= wsum;
  mt /= wsum;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero(), scatter = Eigen::Matrix3d::Zero();
  for (const auto& k : c) {
    if (!(k.weight > 0)) continue;
    const Eigen::Vector3d ds = k.source - ms;
    cov += k.weight * (k.target - mt) * ds.transpose();
    scatter += k.weight * ds * ds.transpose();
  }
  Eigen::JacobiSVD<Eigen::Matrix3d> sc(scatter);
  if (sc.singularValues()(1) < min_spread_mm * min_spread_mm * wsum) return std::nullopt;
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(cov, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) d(2, 2) = -1;
  Rigid3d out = Rigid3d::Identity();
  out.linear() = svd.matrixU() * d * svd.matrixV().transpose();
  out.translation() = mt - out.linear() * ms;
  if (!out.matrix().allFinite()) return std::nullopt;
  return out;
}

void RansacOptions::Check() const {
  D3D_CHECK_MSG(inlier_threshold_mm > 0,
                "inlier_threshold_mm must be > 0, got " << inlier_threshold_mm);
  D3D_CHECK_MSG(max_iterations > 0, "max_iterations must be > 0");
  D3D_CHECK_MSG(confidence > 0 && confidence < 1, "confidence must be in (0, 1)");
  D3D_CHECK_MSG(min_inliers >= 3, "min_inliers must be >= 3");
  D3D_CHECK_MSG(min_inlier_ratio >= 0 && min_inlier_ratio <= 1,
                "min_inlier_ratio must be in [0, 1]");
  D3D_CHECK_MSG(min_sample_spread_mm >= 0 && min_inlier_spread_mm >= 0, "spreads must be >= 0");
  D3D_CHECK_MSG(max_edge_ratio_error > 0, "max_edge_ratio_error must be > 0");
}

namespace {

std::vector<int> CollectInliers(const std::vector<Correspondence3d>& c, const Rigid3d& T,
                                double thr2) {
  std::vector<int> in;
  for (size_t i = 0; i < c.size(); ++i)
    if ((T * c[i].source - c[i].target).squaredNorm() < thr2) in.push_back(static_cast<int>(i));
  return in;
}

// Second principal standard deviation (mm) of the source points of a subset.
double SecondSpreadMm(const std::vector<Correspondence3d>& c, const std::vector<int>& idx) {
  if (idx.size() < 3) return 0;
  Eigen::Vector3d m = Eigen::Vector3d::Zero();
  for (int i : idx) m += c[static_cast<size_t>(i)].source;
  m /= static_cast<double>(idx.size());
  Eigen::Matrix3d s = Eigen::Matrix3d::Zero();
  for (int i : idx) {
    const Eigen::Vector3d d = c[static_cast<size_t>(i)].source - m;
    s += d * d.transpose();
  }
  s /= static_cast<double>(idx.size());
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(s);
  return std::sqrt(std::max(0.0, svd.singularValues()(1)));
}

}  // namespace

RansacResult RansacRigid(const std::vector<Correspondence3d>& c, const RansacOptions& o) {
  o.Check();
  RansacResult r;
  const int n = static_cast<int>(c.size());
  if (n < std::max(3, o.min_inliers)) {
    r.reason = "too few correspondences (" + std::to_string(n) + ")";
    return r;
  }
  std::mt19937 rng(o.seed);
  std::uniform_int_distribution<int> pick(0, n - 1);
  const double thr2 = o.inlier_threshold_mm * o.inlier_threshold_mm;
  std::vector<int> best;
  Rigid3d best_T = Rigid3d::Identity();
  int needed = o.max_iterations;
  int it = 0;
  int draws = 0;
  const double spread2 = o.min_sample_spread_mm * o.min_sample_spread_mm;
  for (; it < needed && draws < 20 * o.max_iterations; ++draws) {
    const int a = pick(rng), b = pick(rng), d = pick(rng);
    if (a == b || b == d || a == d) continue;
    const Eigen::Vector3d& s0 = c[a].source;
    const Eigen::Vector3d& s1 = c[b].source;
    const Eigen::Vector3d& s2 = c[d].source;
    // A thin or small triangle determines the rotation badly.
    const double e01 = (s1 - s0).squaredNorm(), e02 = (s2 - s0).squaredNorm(),
                 e12 = (s2 - s1).squaredNorm();
    const double emax = std::max({e01, e02, e12});
    const double area2 = (s1 - s0).cross(s2 - s0).squaredNorm();  // (2·area)²
    if (std::min({e01, e02, e12}) < spread2 || area2 < spread2 * emax) continue;
    // Rigid motions keep edge lengths.
    const auto edge_ok = [&](int i, int j) {
      const double ls = (c[i].source - c[j].source).norm(), lt = (c[i].target - c[j].target).norm();
      return std::abs(ls - lt) <= o.max_edge_ratio_error * std::max(ls, lt);
    };
    ++it;
    if (!edge_ok(a, b) || !edge_ok(a, d) || !edge_ok(b, d)) continue;
    const std::vector<Correspondence3d> sample = {{c[a].source, c[a].target, 1},
                                                  {c[b].source, c[b].target, 1},
                                                  {c[d].source, c[d].target, 1}};
    const auto T = FitRigid(sample, 1e-6);
    if (!T) continue;
    std::vector<int> in = CollectInliers(c, *T, thr2);
    if (in.size() > best.size()) {
      best = std::move(in);
      best_T = *T;
      // Hypotheses needed for `confidence`: log(1 − confidence) / log(1 − w³). With a tiny inlier
      // fraction the quotient overflows an int (or is ±inf): cap it in double before the cast.
      const double w = static_cast<double>(best.size()) / n;
      const double log_fail = std::log1p(-w * w * w);
      const double k =
          log_fail < 0 ? std::ceil(std::log(1 - o.confidence) / log_fail) : o.max_iterations;
      needed = static_cast<int>(
          std::clamp(k, static_cast<double>(it), static_cast<double>(o.max_iterations)));
    }
  }
  r.iterations = it;
  if (static_cast<int>(best.size()) < o.min_inliers) {
    r.reason = "too few inliers (" + std::to_string(best.size()) + " of " + std::to_string(n) + ")";
    return r;
  }
  // Refit on the consensus, recollect, refit.
  for (int round = 0; round < 2; ++round) {
    std::vector<Correspondence3d> sub;
    for (int i : best) sub.push_back(c[static_cast<size_t>(i)]);
    const auto T = FitRigid(sub);
    if (!T) break;
    std::vector<int> in = CollectInliers(c, *T, thr2);
    if (in.size() < best.size() / 2) break;
    best_T = *T;
    best = std::move(in);
  }
  if (static_cast<double>(best.size()) < o.min_inlier_ratio * n) {
    r.reason =
        "inlier ratio too low (" + std::to_string(best.size()) + " of " + std::to_string(n) + ")";
    return r;
  }
  const double spread = SecondSpreadMm(c, best);
  if (spread < o.min_inlier_spread_mm) {
    r.reason = "degenerate inlier set (points on a line, spread " + std::to_string(spread) + " mm)";
    return r;
  }
  double e2 = 0;
  for (int i : best)
    e2 += (best_T * c[static_cast<size_t>(i)].source - c[static_cast<size_t>(i)].target)
              .squaredNorm();
  r.ok = true;
  r.target_from_source = best_T;
  r.inliers = std::move(best);
  r.inlier_rmse_mm = std::sqrt(e2 / static_cast<double>(r.inliers.size()));
  return r;
}

}  // namespace d3d
