#include "pipeline/register/icp.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "calib/model/camera_model.h"
#include "common/core/status.h"

namespace d3d {

KdTreeTarget::KdTreeTarget(SurfacePoints target) : target_(std::move(target)) {
  D3D_CHECK_MSG(target_.normals.size() == target_.points.size(),
                "KdTreeTarget needs a normal per point");
  tree_ = std::make_unique<PointKdTree>(&target_.points);
}

bool KdTreeTarget::Find(const Eigen::Vector3f& q, float max_d, Eigen::Vector3f* p,
                        Eigen::Vector3f* n) const {
  float d2 = 0;
  const int i = tree_->Nearest(q, &d2, max_d * max_d);
  if (i < 0) return false;
  *p = target_.points[static_cast<size_t>(i)];
  *n = target_.normals[static_cast<size_t>(i)];
  return std::isfinite((*n)[0]);
}

PinholeIntrinsics PinholeIntrinsics::Of(const PinholeBrownConrady& camera) {
  PinholeIntrinsics k;
  k.fx = camera.fx;
  k.fy = camera.fy;
  k.cx = camera.cx;
  k.cy = camera.cy;
  k.width = camera.width;
  k.height = camera.height;
  return k;
}

PinholeIntrinsics PinholeIntrinsics::Scaled(double s) const {
  PinholeIntrinsics o;
  o.fx = fx * s;
  o.fy = fy * s;
  o.cx = (cx + 0.5) * s - 0.5;
  o.cy = (cy + 0.5) * s - 0.5;
  o.width = static_cast<int>(std::lround(width * s));
  o.height = static_cast<int>(std::lround(height * s));
  return o;
}

ProjectiveTarget::ProjectiveTarget(cv::Mat points, cv::Mat normals, const PinholeIntrinsics& k,
                                   const Rigid3d& cam_from_target, int window)
    : points_(std::move(points)), normals_(std::move(normals)), k_(k), window_(window) {
  D3D_CHECK_MSG(points_.type() == CV_32FC3 && normals_.type() == CV_32FC3 &&
                    points_.size() == normals_.size(),
                "ProjectiveTarget: points and normals must be CV_32FC3 of one size");
  D3D_CHECK_MSG(points_.cols == k.width && points_.rows == k.height,
                "ProjectiveTarget: image size != intrinsics");
  D3D_CHECK_MSG(window >= 0, "window must be >= 0");
  R_ = cam_from_target.linear().cast<float>();
  t_ = cam_from_target.translation().cast<float>();
}

bool ProjectiveTarget::Find(const Eigen::Vector3f& q, float max_d, Eigen::Vector3f* p,
                            Eigen::Vector3f* n) const {
  const Eigen::Vector3f c = R_ * q + t_;
  if (c.z() <= 0) return false;
  const int u = static_cast<int>(std::lround(k_.fx * c.x() / c.z() + k_.cx));
  const int v = static_cast<int>(std::lround(k_.fy * c.y() / c.z() + k_.cy));
  float best = max_d * max_d;
  bool found = false;
  for (int y = std::max(0, v - window_); y <= std::min(k_.height - 1, v + window_); ++y) {
    const cv::Vec3f* P = points_.ptr<cv::Vec3f>(y);
    for (int x = std::max(0, u - window_); x <= std::min(k_.width - 1, u + window_); ++x) {
      const cv::Vec3f& s = P[x];
      if (!std::isfinite(s[0])) continue;
      const float d2 = (Eigen::Vector3f(s[0], s[1], s[2]) - q).squaredNorm();
      if (d2 <= best) {
        best = d2;
        *p = Eigen::Vector3f(s[0], s[1], s[2]);
        const cv::Vec3f& m = normals_.at<cv::Vec3f>(y, x);
        *n = Eigen::Vector3f(m[0], m[1], m[2]);
        found = true;
      }
    }
  }
  return found && std::isfinite((*n)[0]);
}

void IcpOptions::Check() const {
  D3D_CHECK_MSG(!levels.empty(), "IcpOptions: at least one level");
  D3D_CHECK_MSG(remap_min_eigen_ratio >= 0 && remap_min_eigen_ratio < 1,
                "IcpOptions: remap_min_eigen_ratio must be in [0, 1)");
  for (const auto& l : levels) {
    D3D_CHECK_MSG(
        l.stride >= 1 && l.max_iterations >= 1 && l.max_distance_mm > 0 && l.max_samples >= 0,
        "IcpOptions: level needs stride >= 1, max_iterations >= 1, max_distance_mm > 0, "
        "max_samples >= 0");
    D3D_CHECK_MSG(l.min_delta_rotation_rad >= 0 && l.min_delta_translation_mm >= 0,
                  "IcpOptions: a level's min_delta_rotation_rad and min_delta_translation_mm >= 0 "
                  "(0 = IcpOptions')");
    D3D_CHECK_MSG(l.point_to_plane_weight >= 0 && l.point_to_plane_weight <= 1,
                  "point_to_plane_weight must be in [0, 1]");
    D3D_CHECK_MSG(l.min_overlap >= 0 && l.min_overlap <= 1,
                  "IcpOptions: a level's min_overlap must be in [0, 1] (0 = none)");
  }
  D3D_CHECK_MSG(max_normal_angle_deg > 0 && max_normal_angle_deg <= 180,
                "max_normal_angle_deg must be in (0, 180]");
  D3D_CHECK_MSG(min_sigma_mm > 0, "min_sigma_mm must be > 0");
  D3D_CHECK_MSG(min_overlap >= 0 && min_overlap <= 1, "min_overlap must be in [0, 1]");
  D3D_CHECK_MSG(max_rmse_mm > 0 && min_correspondences >= 6 && min_eigen_ratio >= 0,
                "acceptance thresholds invalid");
  D3D_CHECK_MSG(threads >= 1, "threads must be >= 1");
  D3D_CHECK_MSG(association_reuse_margin >= 0 && std::isfinite(association_reuse_margin),
                "association_reuse_margin must be >= 0");
}

namespace {

// The information of a pose update x = [ω, t] (rotation about the target origin) in the variables
// degeneracy is judged in: y = [ω · radius, t_c] with t_c = t + ω × c, the motion of the source
// centroid c, so that all six are in mm; x = to_x · y. Its eigen decomposition, ascending.
struct NormalisedInformation {
  Eigen::Matrix<double, 6, 6> to_x;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eigen;
  NormalisedInformation(const Eigen::Matrix<double, 6, 6>& information, const Eigen::Vector3d& c,
                        double radius) {
    Eigen::Matrix<double, 6, 6> A = Eigen::Matrix<double, 6, 6>::Identity();
    A.block<3, 3>(3, 0) << 0, -c.z(), c.y(), c.z(), 0, -c.x(), -c.y(), c.x(),
        0;  // t = t_c + [c]× ω
    Eigen::Matrix<double, 6, 6> D = Eigen::Matrix<double, 6, 6>::Identity();
    D.topLeftCorner<3, 3>() *= 1.0 / radius;
    to_x = A * D;
    eigen.compute(to_x.transpose() * information * to_x);
  }
};

struct Match {
  Eigen::Vector3f p;  // moved source point (target frame)
  Eigen::Vector3f q;  // target point
  Eigen::Vector3f n;  // target normal
  float w0;           // source confidence
  float r;            // point-to-plane residual
};

// A sample's certified association (IcpTarget::FindCertified) and the query it was made for.
struct ReusableMatch {
  bool valid = false;
  Eigen::Vector3f query = Eigen::Vector3f::Zero();
  CertifiedNearest nearest;
};
// Slack (mm) in the reuse tests: float rounding of the distances (~1e-7 mm here) never turns a
// sample that is not provably the nearest into a reused answer.
constexpr float kReuseSlackMm = 1e-5f;

// Find(query, gate) through a reusable answer: reused when the moved query provably has the same
// answer (CertifiedNearest's tests), else searched and certified again. *searched: whether the
// target was searched.
bool FindReusing(const IcpTarget& target, const Eigen::Vector3f& query, float gate, float margin,
                 ReusableMatch* r, Eigen::Vector3f* point, Eigen::Vector3f* normal,
                 bool* searched) {
  bool holds = false;
  if (r->valid) {
    const CertifiedNearest& c = r->nearest;
    const float moved = (query - r->query).norm();
    holds = c.found ? (query - c.point).norm() + moved + kReuseSlackMm < c.clearance_mm
                    : gate + moved + kReuseSlackMm < c.clearance_mm;
  }
  *searched = !holds;
  if (!holds) {
    r->valid = target.FindCertified(query, gate, margin, &r->nearest);
    if (!r->valid) return target.Find(query, gate, point, normal);
    r->query = query;
  }
  const CertifiedNearest& c = r->nearest;
  if (!c.found || !(L2SimpleDistance2(query, c.point) < gate * gate)) return false;
  *point = c.point;
  *normal = c.normal;
  return std::isfinite((*normal)[0]);
}

double Median(std::vector<float>* v) {
  if (v->empty()) return 0;
  auto mid = v->begin() + static_cast<std::ptrdiff_t>(v->size() / 2);
  std::nth_element(v->begin(), mid, v->end());
  return *mid;
}

// Gauss–Newton sums of the combined metric over a set of matches (see RegisterIcp), as sums per
// term so that a match costs 21 + 10 products rather than three 6×6 outer products: the plane
// term's Σ w J Jᵀ (upper triangle), Σ w r J, Σ w r², and the point term's moments, from which its
// sums follow in closed form (Finish).
struct NormalEquations {
  Eigen::Matrix<double, 6, 6> P =
      Eigen::Matrix<double, 6, 6>::Zero();  // Σ w J Jᵀ, upper triangle until Finish
  Eigen::Matrix<double, 6, 1> gp = Eigen::Matrix<double, 6, 1>::Zero();  // Σ w r J
  double errp = 0;                                                       // Σ w r²
  // Point term (α < 1), with d = p − q: Σ w p, Σ w p pᵀ (upper triangle; its trace is Σ w |p|²),
  // Σ w p × d, Σ w d, Σ w |d|².
  Eigen::Vector3d sp = Eigen::Vector3d::Zero();
  Eigen::Matrix3d spp = Eigen::Matrix3d::Zero();
  Eigen::Vector3d spxd = Eigen::Vector3d::Zero(), sd = Eigen::Vector3d::Zero();
  double sdd = 0;
  double wsum = 0, r2sum = 0;  // Σ w, Σ r² (inliers)
  void Add(const NormalEquations& o) {
    P += o.P;
    gp += o.gp;
    errp += o.errp;
    sp += o.sp;
    spp += o.spp;
    spxd += o.spxd;
    sd += o.sd;
    sdd += o.sdd;
    wsum += o.wsum;
    r2sum += o.r2sum;
  }
  // The combined system α·plane + (1 − α)·point: H, g, err, and the plane term's H alone
  // (*H_plane). Point term, J = [−[p]×, I] (so Jᵀ J = [|p|² I − p pᵀ, [p]×; −[p]×, I] and Jᵀ d = [p
  // × d; d]): Σ w Jᵀ J = [Σw|p|² I − Σw p pᵀ, [Σw p]×; −[Σw p]×, Σw I], Σ w Jᵀ d = [Σ w p × d; Σ w
  // d].
  void Finish(double alpha, Eigen::Matrix<double, 6, 6>* H, Eigen::Matrix<double, 6, 1>* g,
              double* err, Eigen::Matrix<double, 6, 6>* H_plane) {
    P.triangularView<Eigen::StrictlyLower>() = P.transpose();
    *H_plane = P;
    *H = alpha * P;
    *g = alpha * gp;
    *err = alpha * errp;
    if (alpha < 1) {
      spp.triangularView<Eigen::StrictlyLower>() = spp.transpose();
      Eigen::Matrix3d skew;
      skew << 0, -sp.z(), sp.y(), sp.z(), 0, -sp.x(), -sp.y(), sp.x(), 0;  // [Σw p]×
      Eigen::Matrix<double, 6, 6> Q;
      Q.topLeftCorner<3, 3>() = spp.trace() * Eigen::Matrix3d::Identity() - spp;
      Q.topRightCorner<3, 3>() = skew;
      Q.bottomLeftCorner<3, 3>() = -skew;
      Q.bottomRightCorner<3, 3>() = wsum * Eigen::Matrix3d::Identity();
      *H += (1 - alpha) * Q;
      g->head<3>() += (1 - alpha) * spxd;
      g->tail<3>() += (1 - alpha) * sd;
      *err += (1 - alpha) * sdd;
    }
  }
};
constexpr size_t kAccumulateChunk = 4096;  // matches per chunk of the parallel sums

// Adds matches [b, e) with Tukey biweight w = w0 (1 − (r/c)²)² (|r| < c) to *ne: point-to-plane
// J = [p × n; n] (left perturbation [ω, t]) with weight α, point-to-point J = [−[p]×, I] with 1 − α
// (Low 2004 for the linearised plane term; the combined metric of the dissertation's ICP). With
// α = 1 the point term's moments are not summed.
void Accumulate(const std::vector<Match>& matches, size_t b, size_t e, double alpha, double c,
                NormalEquations* ne) {
  for (size_t k = b; k < e; ++k) {
    const Match& m = matches[k];
    const double r = m.r;
    if (std::abs(r) >= c) continue;
    const double u = r / c;
    const double w = m.w0 * (1 - u * u) * (1 - u * u);
    const Eigen::Vector3d p = m.p.cast<double>(), q = m.q.cast<double>(), n = m.n.cast<double>();
    Eigen::Matrix<double, 6, 1> J;
    J.head<3>() = p.cross(n);
    J.tail<3>() = n;
    for (int j = 0; j < 6; ++j) {
      const double wj = w * J(j);
      for (int i = 0; i <= j; ++i) ne->P(i, j) += wj * J(i);
    }
    ne->gp += (w * r) * J;
    ne->errp += w * r * r;
    if (alpha < 1) {
      const Eigen::Vector3d d = p - q;
      const Eigen::Vector3d wp = w * p;
      ne->sp += wp;
      for (int j = 0; j < 3; ++j)
        for (int i = 0; i <= j; ++i) ne->spp(i, j) += wp(j) * p(i);
      ne->spxd += wp.cross(d);
      ne->sd += w * d;
      ne->sdd += w * d.squaredNorm();
    }
    ne->wsum += w;
    ne->r2sum += r * r;
  }
}

Rigid3d ExpSe3(const Eigen::Matrix<double, 6, 1>& x) {
  Rigid3d d = Rigid3d::Identity();
  const Eigen::Vector3d w = x.head<3>();
  const double a = w.norm();
  d.linear() = a > 0 ? Eigen::AngleAxisd(a, w / a).toRotationMatrix() : Eigen::Matrix3d::Identity();
  d.translation() = x.tail<3>();
  return d;
}

}  // namespace

IcpResult RegisterIcp(const SurfacePoints& source, const IcpTarget& target, const Rigid3d& initial,
                      const IcpOptions& o) {
  o.Check();
  IcpResult res;
  res.target_from_source = initial;
  const bool has_n = source.normals.size() == source.points.size();
  const bool has_w = source.weights.size() == source.points.size();
  const float cos_max = static_cast<float>(std::cos(o.max_normal_angle_deg * M_PI / 180.0));
  const double radius = std::max(source.RadiusMm(), 1e-3);
  Rigid3d T = initial;
  std::vector<Match> matches;
  std::vector<uint8_t> found, searched;
  std::vector<ReusableMatch> reusable;
  std::vector<Match> scratch;
  std::vector<float> absr;
  Eigen::Matrix<double, 6, 6> H_plane_last = Eigen::Matrix<double, 6, 6>::Zero();
  double sigma_last = o.min_sigma_mm;
  int associated_last = 0, samples_last = 0;
  double rmse_last = 0;

  for (size_t li = 0; li < o.levels.size(); ++li) {
    const IcpLevel& L = o.levels[li];
    const float gate = static_cast<float>(L.max_distance_mm);
    const double alpha = L.point_to_plane_weight;
    const double min_delta_rotation_rad =
        L.min_delta_rotation_rad > 0 ? L.min_delta_rotation_rad : o.min_delta_rotation_rad;
    const double min_delta_translation_mm =
        L.min_delta_translation_mm > 0 ? L.min_delta_translation_mm : o.min_delta_translation_mm;
    size_t stride = static_cast<size_t>(L.stride);
    if (L.max_samples > 0)
      stride = std::max(
          stride, (source.points.size() + L.max_samples - 1) / static_cast<size_t>(L.max_samples));
    std::vector<size_t> idx;
    for (size_t i = 0; i < source.points.size(); i += stride) idx.push_back(i);
    scratch.resize(idx.size());
    found.assign(idx.size(), 0);
    // Per sample: its reusable association (a level's gate differs from the last one's: none yet)
    // and whether the iteration searched (summed after each association pass).
    const bool reuse = o.association_reuse_margin > 0;
    const float margin = static_cast<float>(o.association_reuse_margin * L.max_distance_mm);
    reusable.assign(reuse ? idx.size() : 0, ReusableMatch{});
    searched.assign(idx.size(), 1);
    double prev_err = -1;
    for (int it = 0; it < L.max_iterations; ++it) {
      ++res.iterations;
      const Eigen::Matrix3f R = T.linear().cast<float>();
      const Eigen::Vector3f t = T.translation().cast<float>();
      auto associate = [&](size_t b, size_t e) {
        for (size_t k = b; k < e; ++k) {
          const size_t i = idx[k];
          found[k] = 0;
          const Eigen::Vector3f p = R * source.points[i] + t;
          Match m;
          if (reuse) {
            bool did = true;
            const bool hit = FindReusing(target, p, gate, margin, &reusable[k], &m.q, &m.n, &did);
            searched[k] = did ? 1 : 0;
            if (!hit) continue;
          } else if (!target.Find(p, gate, &m.q, &m.n)) {
            continue;
          }
          if (has_n && (R * source.normals[i]).dot(m.n) < cos_max) continue;
          m.p = p;
          m.w0 = has_w ? source.weights[i] : 1.0f;
          m.r = m.n.dot(p - m.q);
          if (!(m.w0 > 0)) continue;
          scratch[k] = m;
          found[k] = 1;
        }
      };
      if (o.threads > 1) {
        tbb::parallel_for(
            tbb::blocked_range<size_t>(0, idx.size(), 512),
            [&](const tbb::blocked_range<size_t>& r) { associate(r.begin(), r.end()); });
      } else {
        associate(0, idx.size());
      }
      matches.clear();
      for (size_t k = 0; k < idx.size(); ++k) {
        if (found[k]) matches.push_back(scratch[k]);
        res.searches += searched[k];
        res.searches_reused += 1 - searched[k];
      }
      const int nm = static_cast<int>(matches.size());
      samples_last = static_cast<int>(idx.size());
      associated_last = nm;
      if (nm < o.min_correspondences) {
        res.reason = "too few correspondences (" + std::to_string(nm) + " at level " +
                     std::to_string(li) + ")";
        res.target_from_source = T;
        res.correspondences = nm;
        res.overlap = idx.empty() ? 0 : static_cast<double>(nm) / static_cast<double>(idx.size());
        return res;
      }
      absr.resize(static_cast<size_t>(nm));
      for (int k = 0; k < nm; ++k)
        absr[static_cast<size_t>(k)] = std::abs(matches[static_cast<size_t>(k)].r);
      const double sigma = std::max(o.min_sigma_mm, 1.4826 * Median(&absr));
      const double c = 4.685 * sigma;
      NormalEquations ne;
      if (o.threads > 1) {
        // Fixed chunks summed in a fixed tree: the same result for any thread count or schedule.
        ne = tbb::parallel_deterministic_reduce(
            tbb::blocked_range<size_t>(0, matches.size(), kAccumulateChunk), NormalEquations{},
            [&](const tbb::blocked_range<size_t>& r, NormalEquations acc) {
              Accumulate(matches, r.begin(), r.end(), alpha, c, &acc);
              return acc;
            },
            [](NormalEquations a, const NormalEquations& b) {
              a.Add(b);
              return a;
            },
            tbb::simple_partitioner());
      } else {
        Accumulate(matches, 0, matches.size(), alpha, c, &ne);
      }
      Eigen::Matrix<double, 6, 6> H, Hp;
      Eigen::Matrix<double, 6, 1> g;
      double err = 0;
      ne.Finish(alpha, &H, &g, &err, &Hp);
      const double wsum = ne.wsum, r2sum = ne.r2sum;
      if (!(wsum > 0)) {
        res.reason = "no inlier correspondences";
        return res;
      }
      H_plane_last = Hp / (sigma * sigma);
      sigma_last = sigma;
      int inl = 0;
      for (const Match& m : matches) inl += std::abs(m.r) < c;
      rmse_last = std::sqrt(r2sum / std::max(inl, 1));
      // Solve with the Hessian about the source centroid for conditioning (ω, t in the target
      // frame).
      H.diagonal().array() += 1e-9 * H.trace() + 1e-12;
      Eigen::Matrix<double, 6, 1> x = -H.ldlt().solve(g);
      if (o.remap_min_eigen_ratio > 0) {
        // Solution remapping: no step along the directions the surface leaves free.
        const NormalisedInformation n(Hp, T * source.Centroid(), radius);
        const double lmax = n.eigen.eigenvalues()(5);
        const Eigen::Matrix<double, 6, 1> y = n.to_x.inverse() * x;
        Eigen::Matrix<double, 6, 1> kept = Eigen::Matrix<double, 6, 1>::Zero();
        for (int i = 0; i < 6; ++i)
          if (n.eigen.eigenvalues()(i) >= o.remap_min_eigen_ratio * lmax)
            kept += n.eigen.eigenvectors().col(i) * n.eigen.eigenvectors().col(i).dot(y);
        x = n.to_x * kept;
      }
      if (!x.allFinite()) {
        res.reason = "singular normal equations";
        return res;
      }
      T = ExpSe3(x) * T;
      err /= wsum;
      const bool small = x.head<3>().norm() < min_delta_rotation_rad &&
                         x.tail<3>().norm() < min_delta_translation_mm;
      const bool flat =
          prev_err > 0 && std::abs(prev_err - err) <= o.min_relative_error_change * prev_err;
      prev_err = err;
      if (small || flat) break;
    }
    const double level_overlap =
        samples_last ? static_cast<double>(associated_last) / samples_last : 0;
    if (L.min_overlap > 0 && level_overlap < L.min_overlap) {
      char why[96];
      std::snprintf(why, sizeof why, "left the target at level %zu (overlap %.2f < %.2f)", li,
                    level_overlap, L.min_overlap);
      res.reason = why;
      res.target_from_source = T;
      res.correspondences = associated_last;
      res.overlap = level_overlap;
      return res;
    }
  }
  res.target_from_source = T;
  res.correspondences = associated_last;
  res.overlap = samples_last ? static_cast<double>(associated_last) / samples_last : 0;
  res.rmse_mm = rmse_last;
  // Information in [ω, t] with the rotation taken about the target origin; its conditioning is
  // judged after scaling rotations by the source radius and moving to the source centroid.
  res.information = H_plane_last;
  {
    Eigen::Vector3d c = T * source.Centroid();
    double r = radius;
    if (o.conditioning_on_overlap && !matches.empty()) {
      // The associated samples' centroid and RMS radius (moved by the pose before the last step:
      // a difference far below the radius).
      SurfacePoints matched;
      matched.points.reserve(matches.size());
      for (const Match& m : matches) matched.points.push_back(m.p);
      c = matched.Centroid();
      r = std::max(matched.RadiusMm(), 1e-3);
    }
    const NormalisedInformation n(H_plane_last, c, r);
    const double lmax = n.eigen.eigenvalues()(5);
    res.eigen_ratio = lmax > 0 ? n.eigen.eigenvalues()(0) / lmax : 0;
  }
  (void)sigma_last;
  if (res.overlap < o.min_overlap) {
    res.reason =
        "low overlap (" + std::to_string(res.overlap) + " < " + std::to_string(o.min_overlap) + ")";
    return res;
  }
  if (res.rmse_mm > o.max_rmse_mm) {
    res.reason = "high residual (rmse " + std::to_string(res.rmse_mm * 1000) + " um)";
    return res;
  }
  if (res.eigen_ratio < o.min_eigen_ratio) {
    res.reason = "degenerate geometry (eigenvalue ratio " + std::to_string(res.eigen_ratio) + ")";
    return res;
  }
  res.ok = true;
  return res;
}

}  // namespace d3d
