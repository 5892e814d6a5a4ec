#include "pipeline/register/fpfh.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <unordered_map>

#include "common/core/status.h"
#include "pipeline/register/icp.h"
#include "pipeline/register/kdtree.h"

namespace d3d {

RansacOptions FpfhOptions::DefaultRansac() {
  return RansacOptions{.inlier_threshold_mm = 3.75,
                       .max_iterations = 50000,
                       .confidence = 0.999,
                       .min_inliers = 12,
                       .min_inlier_ratio = 0.02,
                       .min_sample_spread_mm = 10,
                       .min_inlier_spread_mm = 2.5,
                       .max_edge_ratio_error = 0.1,
                       .seed = 1};
}

void FpfhOptions::Check() const {
  D3D_CHECK_MSG(voxel_mm > 0, "FpfhOptions: voxel_mm must be > 0, got " << voxel_mm);
  D3D_CHECK_MSG(normal_radius_mm >= 0, "FpfhOptions: normal_radius_mm must be >= 0");
  D3D_CHECK_MSG(feature_radius_mm > 0, "FpfhOptions: feature_radius_mm must be > 0");
  D3D_CHECK_MSG(max_neighbours >= min_neighbours && min_neighbours >= 1,
                "FpfhOptions: need 1 <= min_neighbours <= max_neighbours");
  D3D_CHECK_MSG(ratio > 0 && ratio <= 1, "FpfhOptions: ratio must be in (0, 1]");
  D3D_CHECK_MSG(verify_iterations >= 1, "FpfhOptions: verify_iterations must be >= 1");
  D3D_CHECK_MSG(min_overlap >= 0 && min_overlap <= 1 && min_eigen_ratio >= 0,
                "FpfhOptions: acceptance thresholds invalid");
  D3D_CHECK_MSG(
      ambiguity_ratio >= 0 && ambiguity_ratio <= 1 && ambiguity_deg > 0 && ambiguity_mm > 0,
      "FpfhOptions: ambiguity thresholds invalid");
  ransac.Check();
}

SurfacePoints VoxelDownsample(const SurfacePoints& in, double voxel_mm) {
  D3D_CHECK_MSG(voxel_mm > 0, "VoxelDownsample: voxel_mm must be > 0");
  const bool has_n = in.normals.size() == in.points.size();
  const double inv = 1.0 / voxel_mm;
  std::unordered_map<uint64_t, int> cell_of;
  cell_of.reserve(in.size() / 4 + 16);
  std::vector<Eigen::Vector3d> psum, nsum;
  std::vector<int> count;
  for (size_t i = 0; i < in.size(); ++i) {
    const Eigen::Vector3f& p = in.points[i];
    if (!p.allFinite()) continue;
    auto [it, fresh] = cell_of.emplace(VoxelKeyOf(p, inv), static_cast<int>(count.size()));
    if (fresh) {
      psum.emplace_back(Eigen::Vector3d::Zero());
      nsum.emplace_back(Eigen::Vector3d::Zero());
      count.push_back(0);
    }
    const auto c = static_cast<size_t>(it->second);
    psum[c] += p.cast<double>();
    if (has_n && in.normals[i].allFinite()) nsum[c] += in.normals[i].cast<double>();
    ++count[c];
  }
  SurfacePoints out;
  out.points.reserve(count.size());
  for (size_t c = 0; c < count.size(); ++c) {
    out.points.push_back((psum[c] / count[c]).cast<float>());
    if (!has_n) continue;
    const double n = nsum[c].norm();
    out.normals.push_back(n > 1e-9 ? Eigen::Vector3f((nsum[c] / n).cast<float>())
                                   : Eigen::Vector3f::Constant(std::nanf("")));
  }
  return out;
}

Eigen::Vector3f DarbouxPairFeature(const Eigen::Vector3f& p1, const Eigen::Vector3f& n1,
                                   const Eigen::Vector3f& p2, const Eigen::Vector3f& n2) {
  Eigen::Vector3f d = p2 - p1;
  const float dist = d.norm();
  if (!(dist > 0)) return Eigen::Vector3f::Zero();
  d /= dist;
  // The source is the point whose normal makes the smaller angle with the joining line:
  // acos|n1·d| > acos|n2·d| ⇔ |n1·d| < |n2·d|.
  const bool swap = std::abs(n1.dot(d)) < std::abs(n2.dot(d));
  const Eigen::Vector3f& ns = swap ? n2 : n1;
  const Eigen::Vector3f& nt = swap ? n1 : n2;
  if (swap) d = -d;
  const Eigen::Vector3f u = ns;
  Eigen::Vector3f v = u.cross(d);
  const float vn = v.norm();
  if (!(vn > 1e-7f)) return Eigen::Vector3f::Zero();
  v /= vn;
  const Eigen::Vector3f w = u.cross(v);
  return {v.dot(nt), u.dot(d), std::atan2(w.dot(nt), u.dot(nt))};
}

namespace {

using Histogram = FpfhDescriptor;

int Bin(float value, float lo, float hi) {
  const int b = static_cast<int>(std::floor((value - lo) / (hi - lo) * kFpfhBins));
  return std::clamp(b, 0, kFpfhBins - 1);
}

// Each 11-bin block scaled to sum 100 (a block of zeros stays zero).
void NormaliseBlocks(Histogram* h) {
  for (int b = 0; b < 3; ++b) {
    auto seg = h->segment<kFpfhBins>(b * kFpfhBins);
    const float s = seg.sum();
    if (s > 0) seg *= 100.0f / s;
  }
}

// PCA normal of the keypoints within radius, oriented like `hint`; `hint` when under-determined.
Eigen::Vector3f PcaNormal(const std::vector<Eigen::Vector3f>& pts, const std::vector<int>& nb,
                          const Eigen::Vector3f& hint) {
  Eigen::Vector3f n;
  if (!PcaPlaneNormal(pts, nb.data(), nb.size(), &n)) return hint;
  return n.dot(hint) < 0 ? Eigen::Vector3f(-n) : n;
}

}  // namespace

FpfhFeatures ComputeFpfh(const SurfacePoints& surface, const FpfhOptions& o) {
  o.Check();
  D3D_CHECK_MSG(surface.normals.size() == surface.points.size(),
                "ComputeFpfh: normals required (one per point)");
  const SurfacePoints key = VoxelDownsample(surface, o.voxel_mm);
  std::vector<Eigen::Vector3f> pts, nrm;
  for (size_t i = 0; i < key.size(); ++i)
    if (key.normals[i].allFinite()) {
      pts.push_back(key.points[i]);
      nrm.push_back(key.normals[i]);
    }
  const size_t n = pts.size();
  FpfhFeatures f;
  if (n == 0) return f;
  const PointKdTree tree(&pts);
  std::vector<int> nb;
  if (o.normal_radius_mm > 0) {
    std::vector<Eigen::Vector3f> refined(n);
    for (size_t i = 0; i < n; ++i) {
      tree.Radius(pts[i], static_cast<float>(o.normal_radius_mm), &nb);
      refined[i] = PcaNormal(pts, nb, nrm[i]);
    }
    nrm = std::move(refined);
  }
  // Neighbourhoods (without the point itself), at most max_neighbours nearest; ω_k in mm.
  std::vector<std::vector<int>> nbs(n);
  std::vector<std::vector<float>> dists(n);
  std::vector<std::pair<float, int>> sorted;
  for (size_t i = 0; i < n; ++i) {
    tree.Radius(pts[i], static_cast<float>(o.feature_radius_mm), &nb);
    sorted.clear();
    for (int j : nb)
      if (static_cast<size_t>(j) != i)
        sorted.emplace_back((pts[static_cast<size_t>(j)] - pts[i]).norm(), j);
    const size_t keep = std::min(sorted.size(), static_cast<size_t>(o.max_neighbours));
    std::partial_sort(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(keep),
                      sorted.end());
    for (size_t k = 0; k < keep; ++k) {
      nbs[i].push_back(sorted[k].second);
      dists[i].push_back(sorted[k].first);
    }
  }
  // SPFH of every keypoint.
  std::vector<Histogram> spfh(n, Histogram::Zero());
  for (size_t i = 0; i < n; ++i) {
    Histogram& h = spfh[i];
    for (int j : nbs[i]) {
      const Eigen::Vector3f a = DarbouxPairFeature(pts[i], nrm[i], pts[static_cast<size_t>(j)],
                                                   nrm[static_cast<size_t>(j)]);
      h(Bin(a.x(), -1, 1)) += 1;
      h(kFpfhBins + Bin(a.y(), -1, 1)) += 1;
      h(2 * kFpfhBins + Bin(a.z(), static_cast<float>(-M_PI), static_cast<float>(M_PI))) += 1;
    }
    NormaliseBlocks(&h);
  }
  // FPFH (eq. 3) of the keypoints with enough neighbours.
  for (size_t i = 0; i < n; ++i) {
    const size_t k = nbs[i].size();
    if (static_cast<int>(k) < o.min_neighbours) continue;
    Histogram h = Histogram::Zero();
    for (size_t m = 0; m < k; ++m)
      h += spfh[static_cast<size_t>(nbs[i][m])] / std::max(dists[i][m], 1e-6f);
    h = spfh[i] + h / static_cast<float>(k);
    NormaliseBlocks(&h);
    f.points.push_back(pts[i]);
    f.normals.push_back(nrm[i]);
    f.descriptors.push_back(h);
  }
  return f;
}

namespace {

// Nearest (and second nearest) target descriptor of every source descriptor and the nearest
// source of every target, by blocks of squared L2 distances (‖a‖² + ‖b‖² − 2 a·b).
struct NearestDescriptors {
  std::vector<int> fwd;                // source → nearest target
  std::vector<float> fwd_d2, fwd_d2b;  // its squared distance, the second nearest's
  std::vector<int> bwd;                // target → nearest source
};

NearestDescriptors FindNearest(const std::vector<FpfhDescriptor>& s,
                               const std::vector<FpfhDescriptor>& t) {
  const auto ns = static_cast<Eigen::Index>(s.size()), nt = static_cast<Eigen::Index>(t.size());
  Eigen::MatrixXf Tt(nt, kFpfhSize);
  for (Eigen::Index j = 0; j < nt; ++j) Tt.row(j) = t[static_cast<size_t>(j)].transpose();
  const Eigen::VectorXf tn = Tt.rowwise().squaredNorm();
  NearestDescriptors r;
  r.fwd.assign(s.size(), -1);
  r.fwd_d2.assign(s.size(), std::numeric_limits<float>::infinity());
  r.fwd_d2b = r.fwd_d2;
  r.bwd.assign(t.size(), -1);
  std::vector<float> bwd_d2(t.size(), std::numeric_limits<float>::infinity());
  constexpr Eigen::Index kBlock = 256;
  Eigen::MatrixXf S(kFpfhSize, kBlock), D;  // D: nt × block, one source per (contiguous) column
  for (Eigen::Index b = 0; b < ns; b += kBlock) {
    const Eigen::Index m = std::min(kBlock, ns - b);
    for (Eigen::Index i = 0; i < m; ++i) S.col(i) = s[static_cast<size_t>(b + i)];
    D.noalias() = -2.0f * Tt * S.leftCols(m);
    D.colwise() += tn;
    D.rowwise() += S.leftCols(m).colwise().squaredNorm();
    for (Eigen::Index i = 0; i < m; ++i) {
      const float* col = D.col(i).data();
      float d1 = std::numeric_limits<float>::infinity(), d2 = d1;
      int j1 = -1;
      for (Eigen::Index j = 0; j < nt; ++j) {
        const float d = col[j];
        if (d < bwd_d2[static_cast<size_t>(j)]) {
          bwd_d2[static_cast<size_t>(j)] = d;
          r.bwd[static_cast<size_t>(j)] = static_cast<int>(b + i);
        }
        if (d < d2) {
          if (d < d1) {
            d2 = d1;
            d1 = d;
            j1 = static_cast<int>(j);
          } else {
            d2 = d;
          }
        }
      }
      const auto si = static_cast<size_t>(b + i);
      r.fwd[si] = j1;
      r.fwd_d2[si] = d1;
      r.fwd_d2b[si] = d2;
    }
  }
  return r;
}

}  // namespace

FpfhAlignResult AlignByFpfh(const FpfhFeatures& s, const FpfhFeatures& t, const FpfhOptions& o) {
  o.Check();
  FpfhAlignResult r;
  r.source_keypoints = static_cast<int>(s.size());
  r.target_keypoints = static_cast<int>(t.size());
  const auto fail = [&](const std::string& why) {
    r.ok = false;
    r.reason = "fpfh: " + why;
    return r;
  };
  if (s.size() < 3 || t.size() < 3)
    return fail("too few keypoints (" + std::to_string(s.size()) + " source, " +
                std::to_string(t.size()) + " target)");
  const NearestDescriptors nn = FindNearest(s.descriptors, t.descriptors);
  const float ratio2 = static_cast<float>(o.ratio * o.ratio);
  std::vector<Correspondence3d> c;
  for (size_t i = 0; i < s.size(); ++i) {
    const int j = nn.fwd[i];
    if (j < 0) continue;
    if (o.mutual && nn.bwd[static_cast<size_t>(j)] != static_cast<int>(i)) continue;
    if (o.ratio < 1 && !(std::max(nn.fwd_d2[i], 0.0f) <= ratio2 * std::max(nn.fwd_d2b[i], 0.0f)))
      continue;
    c.push_back({s.points[i].cast<double>(), t.points[static_cast<size_t>(j)].cast<double>(), 1.0});
  }
  r.matches = static_cast<int>(c.size());
  const RansacResult best = RansacRigid(c, o.ransac);
  r.inliers = static_cast<int>(best.inliers.size());
  if (!best.ok) return fail(best.reason);
  r.inlier_rmse_mm = best.inlier_rmse_mm;
  // Verification: point-to-plane ICP on the keypoints from the RANSAC pose.
  SurfacePoints src, tgt;
  src.points = s.points;
  src.normals = s.normals;
  tgt.points = t.points;
  tgt.normals = t.normals;
  const KdTreeTarget target(std::move(tgt));
  IcpOptions icp;
  icp.levels = {{1, o.verify_iterations, o.ransac.inlier_threshold_mm, 1.0}};
  icp.min_sigma_mm = o.voxel_mm / 10;
  icp.max_rmse_mm = o.ransac.inlier_threshold_mm;
  icp.min_overlap = o.min_overlap;
  icp.min_eigen_ratio = o.min_eigen_ratio;
  icp.conditioning_on_overlap = o.verify_conditioning_on_overlap;
  icp.min_correspondences = std::max(6, o.ransac.min_inliers);
  const IcpResult v = RegisterIcp(src, target, best.target_from_source, icp);
  r.overlap = v.overlap;
  r.eigen_ratio = v.eigen_ratio;
  r.target_from_source = v.target_from_source;
  if (!v.ok) return fail("verification: " + v.reason);
  // Ambiguity: the largest consensus among the correspondences the winner does not explain, if the
  // same verification holds it too, elsewhere (a consensus whose surfaces do not meet, e.g. turned
  // inside out, explains nothing and is no rival).
  if (o.ambiguity_ratio > 0) {
    std::vector<uint8_t> used(c.size(), 0);
    for (int i : best.inliers) used[static_cast<size_t>(i)] = 1;
    std::vector<Correspondence3d> rest;
    for (size_t i = 0; i < c.size(); ++i)
      if (!used[i]) rest.push_back(c[i]);
    RansacOptions ro = o.ransac;
    ro.min_inlier_ratio = 0;
    const RansacResult rival = RansacRigid(rest, ro);
    if (rival.ok) {
      const auto elsewhere = [&](const Rigid3d& a, const Rigid3d& b) {
        return RotationAngleRad(a, b) * 180 / M_PI > o.ambiguity_deg ||
               TranslationDistanceMm(a, b) > o.ambiguity_mm;
      };
      r.rival_inliers = static_cast<int>(rival.inliers.size());
      r.rival_deg =
          RotationAngleRad(rival.target_from_source, best.target_from_source) * 180 / M_PI;
      r.rival_mm = TranslationDistanceMm(rival.target_from_source, best.target_from_source);
      if (r.rival_inliers >= o.ambiguity_ratio * r.inliers &&
          elsewhere(rival.target_from_source, best.target_from_source)) {
        // Verified, and still elsewhere once refined (not the winner reached from a worse start).
        const IcpResult rv = RegisterIcp(src, target, rival.target_from_source, icp);
        r.rival_verified = rv.ok && elsewhere(rv.target_from_source, v.target_from_source);
        if (r.rival_verified) {
          r.rival_target_from_source = rv.target_from_source;
          return fail("ambiguous (a second consensus of " + std::to_string(r.rival_inliers) +
                      " vs " + std::to_string(r.inliers) + " inliers, " +
                      std::to_string(r.rival_deg) + " deg / " + std::to_string(r.rival_mm) +
                      " mm away)");
        }
      }
    }
  }
  r.ok = true;
  return r;
}

}  // namespace d3d
