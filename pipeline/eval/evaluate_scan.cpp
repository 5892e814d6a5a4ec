#include "pipeline/eval/evaluate_scan.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <map>
#include <opencv2/imgproc.hpp>
#include <optional>
#include <random>
#include <unordered_map>

#include "common/core/status.h"
#include "common/mesh/closest_point.h"
#include "pipeline/register/fpfh.h"
#include "pipeline/register/kdtree.h"
#include "pipeline/register/rigid_fit.h"
#include "pipeline/register/segment_join.h"  // DentalFpfh

namespace d3d {

namespace {

uint64_t EdgeKey(int a, int b) {
  if (a > b) std::swap(a, b);
  return (static_cast<uint64_t>(static_cast<uint32_t>(a)) << 32) | static_cast<uint32_t>(b);
}

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  const size_t k = static_cast<size_t>(std::clamp(q, 0.0, 1.0) * static_cast<double>(v.size() - 1));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

}  // namespace

struct MeshClosestPoint::Impl {
  std::vector<Eigen::Vector3f> centroids;
  std::unique_ptr<PointKdTree> tree;
  std::vector<Eigen::Vector3d> normals;
  std::vector<uint8_t> boundary_edge;  // per face: bit 0 ab, bit 1 bc, bit 2 ca
  std::vector<uint8_t> boundary_vertex;
};

MeshClosestPoint::MeshClosestPoint(const TriangleMesh& mesh, int candidates)
    : mesh_(mesh), candidates_(candidates), impl_(std::make_unique<Impl>()) {
  mesh_.Check();
  D3D_CHECK_MSG(!mesh_.faces.empty(), "MeshClosestPoint: mesh has no faces");
  D3D_CHECK_MSG(candidates >= 1, "MeshClosestPoint: candidates >= 1");
  std::unordered_map<uint64_t, int> edge_count;
  for (const auto& f : mesh_.faces)
    for (int k = 0; k < 3; ++k) ++edge_count[EdgeKey(f[k], f[(k + 1) % 3])];
  impl_->boundary_vertex.assign(mesh_.vertices.size(), 0);
  for (int i = 0; i < static_cast<int>(mesh_.faces.size()); ++i) {
    const auto& f = mesh_.faces[static_cast<size_t>(i)];
    impl_->centroids.push_back(
        ((mesh_.vertices[static_cast<size_t>(f[0])] + mesh_.vertices[static_cast<size_t>(f[1])] +
          mesh_.vertices[static_cast<size_t>(f[2])]) /
         3)
            .cast<float>());
    impl_->normals.push_back(mesh_.FaceNormal(i));
    uint8_t b = 0;
    for (int k = 0; k < 3; ++k)
      if (edge_count[EdgeKey(f[k], f[(k + 1) % 3])] == 1) {
        b |= static_cast<uint8_t>(1 << k);
        impl_->boundary_vertex[static_cast<size_t>(f[k])] = 1;
        impl_->boundary_vertex[static_cast<size_t>(f[(k + 1) % 3])] = 1;
      }
    impl_->boundary_edge.push_back(b);
  }
  impl_->tree = std::make_unique<PointKdTree>(&impl_->centroids);
}

MeshClosestPoint::~MeshClosestPoint() = default;

MeshClosestPoint::Hit MeshClosestPoint::Closest(const Eigen::Vector3d& p) const {
  std::vector<int> idx(static_cast<size_t>(candidates_));
  std::vector<float> d2(static_cast<size_t>(candidates_));
  const int n = impl_->tree->Knn(p.cast<float>(), candidates_, idx.data(), d2.data());
  Hit best;
  best.distance_mm = 1e300;
  for (int k = 0; k < n; ++k) {
    const int fi = idx[static_cast<size_t>(k)];
    const auto& f = mesh_.faces[static_cast<size_t>(fi)];
    int region = 0;
    const Eigen::Vector3d q = ClosestOnTriangle(p, mesh_.vertices[static_cast<size_t>(f[0])],
                                                mesh_.vertices[static_cast<size_t>(f[1])],
                                                mesh_.vertices[static_cast<size_t>(f[2])], &region);
    const double d = (p - q).norm();
    if (d < best.distance_mm) {
      best.distance_mm = d;
      best.point = q;
      best.face = fi;
      const uint8_t be = impl_->boundary_edge[static_cast<size_t>(fi)];
      switch (region) {
        case kTriangleInterior:
          best.on_boundary = false;
          break;
        case kTriangleVertexA:
        case kTriangleVertexB:
        case kTriangleVertexC:
          best.on_boundary =
              impl_->boundary_vertex[static_cast<size_t>(f[region - kTriangleVertexA])];
          break;
        default:
          best.on_boundary = (be >> (region - kTriangleEdgeAB)) & 1;
          break;  // bit 0 ab, 1 bc, 2 ca
      }
    }
  }
  if (best.face >= 0) {
    const Eigen::Vector3d offset = p - best.point;
    const double s = impl_->normals[static_cast<size_t>(best.face)].dot(offset);
    best.signed_mm = s >= 0 ? best.distance_mm : -best.distance_mm;
    best.past_border =
        best.on_boundary &&
        (offset - s * impl_->normals[static_cast<size_t>(best.face)]).norm() > kPastBorderMm;
  }
  return best;
}

bool MeshClosestPoint::Find(const Eigen::Vector3f& q, float max_d, Eigen::Vector3f* p,
                            Eigen::Vector3f* n) const {
  const Hit h = Closest(q.cast<double>());
  if (h.face < 0 || h.distance_mm > max_d || h.on_boundary) return false;
  *p = h.point.cast<float>();
  *n = impl_->normals[static_cast<size_t>(h.face)].cast<float>();
  return true;
}

void EvaluateOptions::Check() const {
  D3D_CHECK_MSG(max_distance_mm > 0 && coverage_distance_mm > 0 && coverage_sample_mm2 > 0 &&
                    max_scan_points > 0,
                "EvaluateOptions: invalid value");
  D3D_CHECK_MSG(gap_mm >= 0 && gap_mm <= 10,
                "EvaluateOptions: gap_mm must be in [0, 10], got " << gap_mm);
  D3D_CHECK_MSG(footprint_depth_mm > 0,
                "EvaluateOptions: footprint_depth_mm must be positive, got " << footprint_depth_mm);
}

namespace {

SurfacePoints ScanSamples(const TriangleMesh& scan, int max_points) {
  TriangleMesh m = scan;
  if (m.vertex_normals.size() != m.vertices.size()) m.ComputeVertexNormals();
  SurfacePoints s;
  const size_t step = std::max<size_t>(1, m.vertices.size() / static_cast<size_t>(max_points));
  for (size_t i = 0; i < m.vertices.size(); i += step) {
    s.points.push_back(m.vertices[i].cast<float>());
    s.normals.push_back(m.vertex_normals[i].cast<float>());
  }
  return s;
}

// True when some face of `m` is labelled tooth: coverage figures then count the tooth faces only.
bool HasToothFaces(const TriangleMesh& m) {
  for (int f = 0; f < static_cast<int>(m.faces.size()); ++f)
    if (m.Label(f) == SurfaceLabel::kTooth) return true;
  return false;
}

// Per face of `m` (only those `counted`), whether it lies in a narrow gap: some face centroid q
// inside the ball of diameter gap_mm tangent to the face's centroid c on its front side (centre
// c + (gap_mm/2 + ε)·n), with a normal facing back (n_q · n < −0.5). That ball holds the surfaces
// within gap_mm in front of c and none of the face's own smooth neighbourhood.
std::vector<uint8_t> FacesInGaps(const TriangleMesh& m, const std::vector<uint8_t>& counted,
                                 double gap_mm) {
  const size_t nf = m.faces.size();
  std::vector<Eigen::Vector3f> centroids(nf), normals(nf);
  for (size_t f = 0; f < nf; ++f) {
    const auto& F = m.faces[f];
    const Eigen::Vector3d& a = m.vertices[static_cast<size_t>(F[0])];
    const Eigen::Vector3d& b = m.vertices[static_cast<size_t>(F[1])];
    const Eigen::Vector3d& c = m.vertices[static_cast<size_t>(F[2])];
    centroids[f] = ((a + b + c) / 3.0).cast<float>();
    normals[f] = m.FaceNormal(static_cast<int>(f)).cast<float>();  // zero for a degenerate face
  }
  const PointKdTree tree(&centroids);
  const float radius = static_cast<float>(gap_mm / 2);
  std::vector<uint8_t> in_gap(nf, 0);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, nf), [&](const tbb::blocked_range<size_t>& rng) {
    std::vector<int> near;
    for (size_t f = rng.begin(); f < rng.end(); ++f) {
      if (!counted[f] || normals[f].isZero()) continue;
      tree.Radius(centroids[f] + (radius + 1e-3f) * normals[f], radius, &near);
      for (int q : near)
        if (normals[static_cast<size_t>(q)].dot(normals[f]) < -0.5f) {
          in_gap[f] = 1;
          break;
        }
    }
  });
  return in_gap;
}

IcpOptions BestFitIcp() {
  IcpOptions o;
  o.levels = {{16, 30, 2.0, 0.8}, {4, 30, 0.5, 1.0}, {1, 30, 0.2, 1.0}};
  o.min_overlap = 0.05;
  o.max_rmse_mm = 1.0;
  o.min_eigen_ratio = 0;
  o.max_normal_angle_deg = 60;
  o.threads = 2;
  return o;
}

}  // namespace

TruenessReport EvaluateTrueness(const TriangleMesh& scan, const MeshClosestPoint& ref,
                                const Rigid3d& initial, const EvaluateOptions& o) {
  o.Check();
  TruenessReport r;
  r.reference_from_scan = initial;
  if (scan.vertices.empty()) return r;
  if (o.align) {
    const SurfacePoints s = ScanSamples(scan, 100000);
    const IcpResult icp = RegisterIcp(s, ref, initial, BestFitIcp());
    r.reference_from_scan = icp.target_from_source;
    r.alignment_rmse_mm = icp.rmse_mm;
  }
  // Signed distances of every scan vertex (subsampled evenly beyond max_scan_points).
  const size_t nv = scan.vertices.size();
  const size_t step = std::max<size_t>(1, nv / static_cast<size_t>(o.max_scan_points));
  r.signed_um.assign(nv, std::nanf(""));
  std::vector<uint8_t> state(
      nv, 0);  // 0 not evaluated, 1 in figures, 2 outlier, 3 in figures and on a tooth
  tbb::parallel_for(
      tbb::blocked_range<size_t>(0, nv), [&](const tbb::blocked_range<size_t>& range) {
        for (size_t i = range.begin(); i < range.end(); ++i) {
          if (i % step) continue;
          const MeshClosestPoint::Hit h = ref.Closest(r.reference_from_scan * scan.vertices[i]);
          if (h.face < 0 || h.distance_mm > o.max_distance_mm || h.past_border) {
            state[i] = 2;
            continue;
          }
          state[i] = ref.mesh().Label(h.face) == SurfaceLabel::kTooth ? 3 : 1;
          r.signed_um[i] = static_cast<float>(h.signed_mm * 1000.0);
        }
      });
  std::vector<double> absd, teeth_absd;
  double s = 0, s2 = 0, sa = 0, ts = 0, ts2 = 0;
  int64_t outliers = 0, evaluated = 0;
  for (size_t i = 0; i < nv; ++i) {
    if (!state[i]) continue;
    ++evaluated;
    if (state[i] == 2) {
      ++outliers;
      continue;
    }
    const double d = r.signed_um[i];
    s += d;
    s2 += d * d;
    sa += std::abs(d);
    absd.push_back(std::abs(d));
    if (state[i] == 3) {
      ts += d;
      ts2 += d * d;
      teeth_absd.push_back(std::abs(d));
    }
  }
  r.teeth_points = static_cast<int64_t>(teeth_absd.size());
  if (r.teeth_points) {
    const double n = static_cast<double>(r.teeth_points);
    r.teeth_mean_um = ts / n;
    r.teeth_rms_um = std::sqrt(ts2 / n);
    r.teeth_p95_um = Percentile(teeth_absd, 0.95);
  }
  r.points = static_cast<int64_t>(absd.size());
  if (r.points) {
    const double n = static_cast<double>(r.points);
    r.mean_um = s / n;
    r.rms_um = std::sqrt(s2 / n);
    r.mean_abs_um = sa / n;
    r.p95_um = Percentile(absd, 0.95);
    r.max_um = *std::max_element(absd.begin(), absd.end());
  }
  r.outlier_pct =
      evaluated ? 100.0 * static_cast<double>(outliers) / static_cast<double>(evaluated) : 0;
  // Coverage: area samples of the reference (tooth faces when labelled) near the scan.
  const TriangleMesh& R = ref.mesh();
  const bool has_teeth = o.teeth_only_coverage && HasToothFaces(R);
  // Covered: within coverage_distance_mm of a scan vertex, or, for a coarse mesh (edges longer on
  // average than half that distance, whose vertices lie further apart than it), of its surface.
  // A fused scan's vertices are dense enough (0.05 mm voxels) and its millions of faces would
  // make the surface search the evaluation's largest cost.
  std::vector<Eigen::Vector3f> scan_pts(nv);
  for (size_t i = 0; i < nv; ++i)
    scan_pts[i] = (r.reference_from_scan * scan.vertices[i]).cast<float>();
  PointKdTree tree(&scan_pts);
  std::unique_ptr<MeshClosestPoint> scan_surface;
  {
    double edge_sum = 0;
    const size_t faces = std::min<size_t>(scan.faces.size(), 100000);
    for (size_t f = 0; f < faces; ++f)
      edge_sum += (scan.vertices[scan.faces[f][1]] - scan.vertices[scan.faces[f][0]]).norm();
    if (faces > 0 && edge_sum / static_cast<double>(faces) > 0.5 * o.coverage_distance_mm) {
      TriangleMesh scan_in_ref;
      scan_in_ref.vertices.resize(nv);
      for (size_t i = 0; i < nv; ++i)
        scan_in_ref.vertices[i] = r.reference_from_scan * scan.vertices[i];
      scan_in_ref.faces = scan.faces;
      scan_surface = std::make_unique<MeshClosestPoint>(scan_in_ref);
    }
  }
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> U(0, 1);
  std::vector<uint8_t> counted(R.faces.size(), 0);
  for (int f = 0; f < static_cast<int>(R.faces.size()); ++f)
    counted[static_cast<size_t>(f)] = !has_teeth || R.Label(f) == SurfaceLabel::kTooth;
  const std::vector<uint8_t> in_gap =
      o.gap_mm > 0 ? FacesInGaps(R, counted, o.gap_mm) : std::vector<uint8_t>();
  int64_t covered = 0, samples = 0;
  int64_t gap_covered = 0, gap_samples = 0;  // of those, on faces in gaps
  const float cov2 = static_cast<float>(o.coverage_distance_mm * o.coverage_distance_mm);
  for (int f = 0; f < static_cast<int>(R.faces.size()); ++f) {
    if (!counted[static_cast<size_t>(f)]) continue;
    const bool gap = !in_gap.empty() && in_gap[static_cast<size_t>(f)];
    const double area = R.FaceArea(f);
    double expected = area / o.coverage_sample_mm2;
    int k = static_cast<int>(expected);
    if (U(rng) < expected - k) ++k;
    const auto& F = R.faces[static_cast<size_t>(f)];
    for (int j = 0; j < k; ++j) {
      double a = U(rng), b = U(rng);
      if (a + b > 1) {
        a = 1 - a;
        b = 1 - b;
      }
      const Eigen::Vector3d p =
          R.vertices[static_cast<size_t>(F[0])] +
          a * (R.vertices[static_cast<size_t>(F[1])] - R.vertices[static_cast<size_t>(F[0])]) +
          b * (R.vertices[static_cast<size_t>(F[2])] - R.vertices[static_cast<size_t>(F[0])]);
      float d2 = 0;
      ++samples;
      gap_samples += gap;
      const bool near =
          tree.Nearest(p.cast<float>(), &d2, cov2) >= 0 ||
          (scan_surface && scan_surface->Closest(p).distance_mm <= o.coverage_distance_mm);
      if (near) {
        ++covered;
        gap_covered += gap;
      }
    }
  }
  const auto pct = [](int64_t part, int64_t whole) {
    if (whole <= 0) return std::nan("");
    return 100.0 * static_cast<double>(part) / static_cast<double>(whole);
  };
  r.coverage_pct = samples ? pct(covered, samples) : 0;
  if (!in_gap.empty() && samples > 0) {
    r.gap_area_pct = pct(gap_samples, samples);
    r.coverage_gap_pct = pct(gap_covered, gap_samples);
    r.coverage_open_pct = pct(covered - gap_covered, samples - gap_samples);
  }
  return r;
}

// GlobalAlign's principal-axes starts are kept when their best ICP associates at least this
// fraction of the scan's samples at a residual at most this (a whole arch against a whole arch,
// a right fit: the residual is the scan's noise); otherwise FPFH is tried too.
constexpr double kGlobalAlignFpfhBelowOverlap = 0.8, kGlobalAlignFpfhAboveRmseMm = 0.05;

Rigid3d GlobalAlign(const TriangleMesh& scan, const MeshClosestPoint& ref) {
  auto frame = [](const std::vector<Eigen::Vector3d>& v, Eigen::Vector3d* mean) {
    Eigen::Vector3d m = Eigen::Vector3d::Zero();
    for (const auto& p : v) m += p;
    m /= static_cast<double>(v.size());
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    for (const auto& p : v) C += (p - m) * (p - m).transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
    *mean = m;
    return Eigen::Matrix3d(es.eigenvectors());
  };
  Eigen::Vector3d ms, mr;
  const Eigen::Matrix3d Es = frame(scan.vertices, &ms), Er = frame(ref.mesh().vertices, &mr);
  const SurfacePoints s = ScanSamples(scan, 20000);
  IcpOptions o = BestFitIcp();
  o.levels = {{4, 30, 5.0, 0.5}, {1, 30, 1.0, 0.9}, {1, 20, 0.3, 1.0}};
  Rigid3d best = Rigid3d::Identity();
  double best_score = -1, best_overlap = 0, best_rmse_mm = 0;
  for (int signs = 0; signs < 4; ++signs) {
    Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
    D(0, 0) = signs & 1 ? -1 : 1;
    D(1, 1) = signs & 2 ? -1 : 1;
    D(2, 2) = D(0, 0) * D(1, 1) * Es.determinant() * Er.determinant();
    Rigid3d T = Rigid3d::Identity();
    T.linear() = Er * D * Es.transpose();
    T.translation() = mr - T.linear() * ms;
    const IcpResult r = RegisterIcp(s, ref, T, o);
    const double score = r.overlap - r.rmse_mm;  // overlap first (fractions), residual breaks ties
    if (score > best_score) {
      best_score = score;
      best = r.target_from_source;
      best_overlap = r.overlap;
      best_rmse_mm = r.rmse_mm;
    }
  }
  // A partial scan (a quadrant, a tooth, a cut-out) has principal axes of its own, not the
  // reference's: when those starts leave much of the scan unmatched or fit it badly, FPFH +
  // RANSAC on both surfaces (fpfh.h, at the scale of teeth) proposes another start.
  if (best_overlap < kGlobalAlignFpfhBelowOverlap || best_rmse_mm > kGlobalAlignFpfhAboveRmseMm) {
    const FpfhOptions fo = DentalFpfh();
    const FpfhAlignResult a =
        AlignByFpfh(ComputeFpfh(s, fo), ComputeFpfh(ScanSamples(ref.mesh(), 400000), fo), fo);
    if (a.ok) {
      const IcpResult r = RegisterIcp(s, ref, a.target_from_source, o);
      if (r.overlap - r.rmse_mm > best_score) best = r.target_from_source;
    }
  }
  return best;
}

PrecisionReport EvaluatePrecision(const TriangleMesh& a, const TriangleMesh& b,
                                  const Rigid3d& a_from_b, double max_d,
                                  double reciprocal_below_um) {
  D3D_CHECK_MSG(reciprocal_below_um >= 0, "EvaluatePrecision: reciprocal_below_um must be >= 0");
  const MeshClosestPoint ref(a);
  EvaluateOptions o;
  o.max_distance_mm = max_d;
  o.teeth_only_coverage = false;
  o.gap_mm = 0;  // no coverage figures here: the split's search over a's faces would be wasted
  const TruenessReport t = EvaluateTrueness(b, ref, a_from_b, o);
  PrecisionReport p;
  p.one_sided_rms_um = t.rms_um;
  p.one_sided_p95_um = t.p95_um;
  // The overlap test: p of b (in a's frame) and its closest point q on a measure the same surface
  // when b's own closest point to q is about as far: |q − b| ≥ ½ |p − q|. Where a lacks the
  // surface b has at p (a tooth wall one scan reached and the other did not, above a gingiva both
  // have), q falls on that other surface, which b also measured, so |q − b| ≈ 0.
  TriangleMesh b_in_a = b;
  for (auto& v : b_in_a.vertices) v = t.reference_from_scan * v;
  const MeshClosestPoint bcp(b_in_a);
  const size_t nv = b_in_a.vertices.size();
  std::vector<uint8_t> kept(nv, 0);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, nv),
                    [&](const tbb::blocked_range<size_t>& range) {
                      for (size_t i = range.begin(); i < range.end(); ++i) {
                        const float d_um = t.signed_um[i];
                        if (!std::isfinite(d_um)) continue;
                        if (std::abs(d_um) <= reciprocal_below_um) {
                          kept[i] = 1;
                          continue;
                        }
                        const MeshClosestPoint::Hit q = ref.Closest(b_in_a.vertices[i]);
                        const MeshClosestPoint::Hit back = bcp.Closest(q.point);
                        kept[i] = back.distance_mm >= 0.5 * q.distance_mm ? 1 : 2;
                      }
                    });
  std::vector<double> absd;
  double s2 = 0;
  int64_t counted = 0;
  for (size_t i = 0; i < nv; ++i) {
    if (!kept[i]) continue;
    ++counted;
    if (kept[i] != 1) continue;
    const double d = t.signed_um[i];
    s2 += d * d;
    absd.push_back(std::abs(d));
  }
  p.points = static_cast<int64_t>(absd.size());
  p.not_reciprocal_pct =
      counted ? 100.0 * static_cast<double>(counted - p.points) / static_cast<double>(counted) : 0;
  if (p.points) {
    p.rms_um = std::sqrt(s2 / static_cast<double>(p.points));
    p.p95_um = Percentile(absd, 0.95);
  }
  return p;
}

SeenSurface::SeenSurface(const TriangleMesh& reference, double depth_min_mm, double depth_max_mm,
                         double max_incidence_deg)
    : depth_min_mm_(depth_min_mm),
      depth_max_mm_(depth_max_mm),
      cos_max_incidence_(std::cos(max_incidence_deg * M_PI / 180.0)) {
  D3D_CHECK_MSG(!reference.faces.empty(), "SeenSurface: empty reference");
  D3D_CHECK_MSG(depth_min_mm >= 0 && depth_min_mm < depth_max_mm,
                "SeenSurface: depth limits out of order");
  D3D_CHECK_MSG(max_incidence_deg > 0 && max_incidence_deg <= 90,
                "SeenSurface: max_incidence_deg must be in (0, 90]");
  const bool has_teeth = HasToothFaces(reference);
  const size_t n = reference.faces.size();
  normals_.resize(n);
  counted_area_.assign(n, 0.0);
  for (size_t f = 0; f < n; ++f) {
    const int i = static_cast<int>(f);
    normals_[f] = reference.FaceNormal(i);
    if (!has_teeth || reference.Label(i) == SurfaceLabel::kTooth)
      counted_area_[f] = reference.FaceArea(i);
  }
  seen_.assign(n, 0);
}

void SeenSurface::Add(const FrameTruth& truth) {
  if (!truth.has_maps() || truth.face_index.empty()) return;
  ++views_;
  const Rigid3d& world_from_cam = truth.world_from_probe;
  const Eigen::Vector3d centre = world_from_cam.translation();
  const int n_faces = static_cast<int>(normals_.size());
  for (int y = 0; y < truth.face_index.rows; ++y) {
    const int32_t* face = truth.face_index.ptr<int32_t>(y);
    const uint8_t* vis = truth.visibility.ptr<uint8_t>(y);
    const cv::Vec3f* p = truth.points_in_cam.ptr<cv::Vec3f>(y);
    for (int x = 0; x < truth.face_index.cols; ++x) {
      const int f = face[x];
      if (f < 0 || f >= n_faces || vis[x] != 2 || seen_[static_cast<size_t>(f)]) continue;
      if (!(p[x][2] >= depth_min_mm_ && p[x][2] <= depth_max_mm_)) continue;
      const Eigen::Vector3d q = world_from_cam * Eigen::Vector3d(p[x][0], p[x][1], p[x][2]);
      const double c = std::abs(normals_[static_cast<size_t>(f)].dot((centre - q).normalized()));
      if (c >= cos_max_incidence_) seen_[static_cast<size_t>(f)] = 1;
    }
  }
}

double SeenSurface::SeenToothAreaPct() const {
  double total = 0, seen = 0;
  for (size_t f = 0; f < counted_area_.size(); ++f) {
    total += counted_area_[f];
    if (seen_[f]) seen += counted_area_[f];
  }
  return total > 0 ? 100.0 * seen / total : 0;
}

AteReport AbsoluteTrajectoryError(const std::vector<Rigid3d>& est,
                                  const std::vector<Rigid3d>& truth, Rigid3d* out) {
  D3D_CHECK_MSG(est.size() == truth.size(), "AbsoluteTrajectoryError: sizes differ");
  AteReport r;
  r.poses = static_cast<int>(est.size());
  if (est.size() < 3) return r;
  std::vector<Correspondence3d> c;
  for (size_t i = 0; i < est.size(); ++i)
    c.push_back({est[i].translation(), truth[i].translation(), 1.0});
  Rigid3d T = FitRigid(c, 0).value_or(truth[0] * est[0].inverse());
  double s2 = 0, sr = 0;
  for (size_t i = 0; i < est.size(); ++i) {
    const Rigid3d e = T * est[i];
    const double d = TranslationDistanceMm(e, truth[i]);
    s2 += d * d;
    r.max_mm = std::max(r.max_mm, d);
    sr += RotationAngleRad(e, truth[i]) * 180.0 / M_PI;
  }
  r.rmse_mm = std::sqrt(s2 / static_cast<double>(est.size()));
  r.mean_deg = sr / static_cast<double>(est.size());
  if (out) *out = T;
  return r;
}

std::vector<Eigen::Vector3d> ViewFootprint(const PinholeBrownConrady& camera, double depth_mm) {
  D3D_CHECK_MSG(depth_mm > 0, "the footprint's depth must be positive, not " << depth_mm << " mm");
  const double w = camera.width - 1, h = camera.height - 1;
  std::vector<Eigen::Vector3d> footprint;
  for (const Eigen::Vector2d& px :
       {Eigen::Vector2d(w / 2, h / 2), Eigen::Vector2d(0, 0), Eigen::Vector2d(w, 0),
        Eigen::Vector2d(0, h), Eigen::Vector2d(w, h)}) {
    const std::optional<Eigen::Vector3d> ray = camera.PixelRay(px);  // (x, y, 1): z = depth
    if (ray) footprint.push_back(*ray * depth_mm);
  }
  return footprint;
}

double FootprintDistanceMm(const Rigid3d& estimate, const Rigid3d& truth,
                           const std::vector<Eigen::Vector3d>& footprint_in_cam) {
  if (footprint_in_cam.empty()) return TranslationDistanceMm(estimate, truth);
  double d = 0;
  for (const Eigen::Vector3d& p : footprint_in_cam)
    d = std::max(d, (estimate * p - truth * p).norm());
  return d;
}

RpeReport RelativePoseError(const std::vector<Rigid3d>& est, const std::vector<Rigid3d>& truth) {
  D3D_CHECK_MSG(est.size() == truth.size(), "RelativePoseError: sizes differ");
  RpeReport r;
  double s2 = 0, sr = 0;
  for (size_t k = 1; k < est.size(); ++k) {
    const Rigid3d e =
        (truth[k - 1].inverse() * truth[k]).inverse() * (est[k - 1].inverse() * est[k]);
    const double d = e.translation().norm();
    s2 += d * d;
    sr += RotationAngleRad(e, Rigid3d::Identity()) * 180.0 / M_PI;
    if (d > r.max_mm) {
      r.max_mm = d;
      r.max_pose = static_cast<int>(k);
    }
    ++r.steps;
  }
  if (r.steps > 0) {
    r.rmse_mm = std::sqrt(s2 / r.steps);
    r.mean_deg = sr / r.steps;
  }
  return r;
}

cv::Mat DeviationHeatMap(const TriangleMesh& scan, const std::vector<float>& signed_um,
                         double range_um, int width_px) {
  D3D_CHECK_MSG(signed_um.size() == scan.vertices.size(), "DeviationHeatMap: one value per vertex");
  cv::Mat img(10, 10, CV_8UC3, cv::Scalar(255, 255, 255));
  if (scan.vertices.empty()) return img;
  Eigen::Vector3d m = Eigen::Vector3d::Zero();
  for (const auto& p : scan.vertices) m += p;
  m /= static_cast<double>(scan.vertices.size());
  Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
  for (const auto& p : scan.vertices) C += (p - m) * (p - m).transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
  const Eigen::Vector3d ax = es.eigenvectors().col(2), ay = es.eigenvectors().col(1),
                        az = es.eigenvectors().col(0);
  // View from the side most normals face.
  TriangleMesh tmp = scan;
  tmp.ComputeVertexNormals();
  double facing = 0;
  for (const auto& n : tmp.vertex_normals) facing += n.dot(az);
  const double sz = facing >= 0 ? 1 : -1;
  double x0 = 1e30, x1 = -1e30, y0 = 1e30, y1 = -1e30;
  for (const auto& p : scan.vertices) {
    const double x = (p - m).dot(ax), y = (p - m).dot(ay);
    x0 = std::min(x0, x), x1 = std::max(x1, x), y0 = std::min(y0, y), y1 = std::max(y1, y);
  }
  const double scale = (width_px - 20) / std::max(x1 - x0, 1e-6);
  const int h = static_cast<int>((y1 - y0) * scale) + 20, bar = 70;
  img = cv::Mat(h + bar, width_px, CV_8UC3, cv::Scalar(255, 255, 255));
  cv::Mat zbuf(h, width_px, CV_64F, cv::Scalar(-1e30));
  auto colour = [&](double d) {
    const double t = std::clamp((d / range_um + 1) / 2, 0.0, 1.0);  // 0 blue, 0.5 green, 1 red
    const double r = std::clamp(2 * t - 1, 0.0, 1.0), b = std::clamp(1 - 2 * t, 0.0, 1.0),
                 g = 1 - r - b;
    return cv::Vec3b(static_cast<uint8_t>(255 * b), static_cast<uint8_t>(255 * g),
                     static_cast<uint8_t>(255 * r));
  };
  const int splat = std::max(1, static_cast<int>(std::ceil(0.05 * scale / 2)));
  for (size_t i = 0; i < scan.vertices.size(); ++i) {
    const Eigen::Vector3d d = scan.vertices[i] - m;
    const int u = static_cast<int>((d.dot(ax) - x0) * scale) + 10,
              v = static_cast<int>((y1 - d.dot(ay)) * scale) + 10;
    const double z = sz * d.dot(az);
    if (!std::isfinite(signed_um[i])) continue;  // not evaluated (subsampled) or excluded
    const cv::Vec3b c = colour(signed_um[i]);
    for (int y = std::max(0, v - splat); y <= std::min(h - 1, v + splat); ++y)
      for (int x = std::max(0, u - splat); x <= std::min(width_px - 1, u + splat); ++x)
        if (z > zbuf.at<double>(y, x)) {
          zbuf.at<double>(y, x) = z;
          img.at<cv::Vec3b>(y, x) = c;
        }
  }
  // Colour bar with labels (µm).
  const int bx0 = width_px / 6, bx1 = 5 * width_px / 6;
  for (int x = bx0; x < bx1; ++x) {
    const double d = (2.0 * (x - bx0) / (bx1 - bx0) - 1) * range_um;
    cv::line(img, {x, h + 10}, {x, h + 35}, cv::Scalar(colour(d)[0], colour(d)[1], colour(d)[2]));
  }
  for (int k = 0; k <= 4; ++k) {
    const int x = bx0 + k * (bx1 - bx0) / 4;
    const std::string label =
        std::to_string(static_cast<int>(std::lround((k / 2.0 - 1) * range_um))) + " um";
    cv::putText(img, label, {x - 25, h + 58}, cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 0, 0), 1,
                cv::LINE_AA);
  }
  return img;
}

}  // namespace d3d
