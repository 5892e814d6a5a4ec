#include "pipeline/register/surface_points.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>

#include "common/core/status.h"
#include "pipeline/register/kdtree.h"

namespace d3d {

SurfacePoints SurfacePoints::Subsample(int stride, int phase) const {
  D3D_CHECK_MSG(stride >= 1, "stride must be >= 1, got " << stride);
  SurfacePoints out;
  const bool has_n = normals.size() == points.size();
  const bool has_w = weights.size() == points.size();
  for (size_t i = static_cast<size_t>(std::max(phase, 0)); i < points.size();
       i += static_cast<size_t>(stride)) {
    out.points.push_back(points[i]);
    if (has_n) out.normals.push_back(normals[i]);
    if (has_w) out.weights.push_back(weights[i]);
  }
  return out;
}

SurfacePoints SurfacePoints::Transformed(const Rigid3d& T) const {
  SurfacePoints out = *this;
  const Eigen::Matrix3f R = T.linear().cast<float>();
  const Eigen::Vector3f t = T.translation().cast<float>();
  for (auto& p : out.points) p = R * p + t;
  for (auto& n : out.normals) n = R * n;
  return out;
}

Eigen::Vector3d SurfacePoints::Centroid() const {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (const auto& p : points) c += p.cast<double>();
  return points.empty() ? c : Eigen::Vector3d(c / static_cast<double>(points.size()));
}

double SurfacePoints::RadiusMm() const {
  if (points.empty()) return 0;
  const Eigen::Vector3d c = Centroid();
  double s = 0;
  for (const auto& p : points) s += (p.cast<double>() - c).squaredNorm();
  return std::sqrt(s / static_cast<double>(points.size()));
}

SurfacePoints SampleOrganised(const cv::Mat& points, const cv::Mat& normals, const cv::Mat& quality,
                              int stride) {
  SurfacePoints out;
  SampleOrganised(points, normals, quality, stride, &out);
  return out;
}

void SampleOrganised(const cv::Mat& points, const cv::Mat& normals, const cv::Mat& quality,
                     int stride, SurfacePoints* out) {
  D3D_CHECK_MSG(points.type() == CV_32FC3, "points must be CV_32FC3");
  D3D_CHECK_MSG(normals.type() == CV_32FC3 && normals.size() == points.size(),
                "normals must be CV_32FC3 like points");
  D3D_CHECK_MSG(quality.empty() || (quality.type() == CV_32F && quality.size() == points.size()),
                "quality must be CV_32F like points");
  D3D_CHECK_MSG(stride >= 1, "stride must be >= 1");
  out->clear();
  // Row order: every 2·stride-th row first (0, 2·stride, …), then those between (stride, 3·stride,
  // …), so that Subsample(2) keeps every other row.
  for (int first = 0; first <= stride; first += stride)
    for (int r = first; r < points.rows; r += 2 * stride) {
      const cv::Vec3f* P = points.ptr<cv::Vec3f>(r);
      const cv::Vec3f* N = normals.ptr<cv::Vec3f>(r);
      const float* Q = quality.empty() ? nullptr : quality.ptr<float>(r);
      for (int c = (r / stride) % 2 ? stride / 2 : 0; c < points.cols; c += stride) {
        const cv::Vec3f& p = P[c];
        const cv::Vec3f& n = N[c];
        if (!std::isfinite(p[0]) || !std::isfinite(p[2]) || !std::isfinite(n[0]) ||
            !std::isfinite(n[2]))
          continue;
        out->points.emplace_back(p[0], p[1], p[2]);
        out->normals.emplace_back(n[0], n[1], n[2]);
        if (Q) out->weights.push_back(std::clamp(std::isfinite(Q[c]) ? Q[c] : 0.0f, 0.0f, 1.0f));
      }
    }
}

cv::Mat GridNormals(const cv::Mat& P, double max_gap_mm) {
  D3D_CHECK_MSG(P.type() == CV_32FC3, "GridNormals: CV_32FC3 expected");
  cv::Mat N(P.size(), CV_32FC3, cv::Scalar::all(std::numeric_limits<float>::quiet_NaN()));
  const float gap = static_cast<float>(max_gap_mm);
  auto get = [&](int r, int c, Eigen::Vector3f* v) {
    if (r < 0 || c < 0 || r >= P.rows || c >= P.cols) return false;
    const cv::Vec3f& p = P.at<cv::Vec3f>(r, c);
    if (!std::isfinite(p[0])) return false;
    *v = Eigen::Vector3f(p[0], p[1], p[2]);
    return true;
  };
  for (int r = 0; r < P.rows; ++r)
    for (int c = 0; c < P.cols; ++c) {
      Eigen::Vector3f p, l, rr, u, d;
      if (!get(r, c, &p)) continue;
      const bool hl = get(r, c - 1, &l) && (l - p).norm() < gap,
                 hr = get(r, c + 1, &rr) && (rr - p).norm() < gap;
      const bool hu = get(r - 1, c, &u) && (u - p).norm() < gap,
                 hd = get(r + 1, c, &d) && (d - p).norm() < gap;
      if (!(hl || hr) || !(hu || hd)) continue;
      const Eigen::Vector3f dc = (hr ? rr : p) - (hl ? l : p), dr = (hd ? d : p) - (hu ? u : p);
      const Eigen::Vector3f n = dc.cross(dr);
      if (n.norm() < 1e-9f) continue;
      const Eigen::Vector3f m = n.normalized();
      N.at<cv::Vec3f>(r, c) = cv::Vec3f(m.x(), m.y(), m.z());
    }
  return N;
}

std::vector<Eigen::Vector3f> EstimateNormals(const std::vector<Eigen::Vector3f>& points, int k,
                                             const Eigen::Vector3f& viewpoint) {
  D3D_CHECK_MSG(k >= 3, "k must be >= 3");
  PointKdTree tree(&points);
  std::vector<Eigen::Vector3f> normals(points.size(), Eigen::Vector3f::Constant(std::nanf("")));
  std::vector<int> idx(static_cast<size_t>(k));
  std::vector<float> d2(static_cast<size_t>(k));
  for (size_t i = 0; i < points.size(); ++i) {
    const int n = tree.Knn(points[i], k, idx.data(), d2.data());
    Eigen::Vector3f nrm;
    if (!PcaPlaneNormal(points, idx.data(), static_cast<size_t>(std::max(n, 0)), &nrm)) continue;
    if (nrm.dot(viewpoint - points[i]) < 0) nrm = -nrm;
    normals[i] = nrm;
  }
  return normals;
}

bool PcaPlaneNormal(const std::vector<Eigen::Vector3f>& points, const int* indices, size_t count,
                    Eigen::Vector3f* normal) {
  if (count < 3) return false;
  Eigen::Vector3d m = Eigen::Vector3d::Zero();
  for (size_t j = 0; j < count; ++j) m += points[static_cast<size_t>(indices[j])].cast<double>();
  m /= static_cast<double>(count);
  Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
  for (size_t j = 0; j < count; ++j) {
    const Eigen::Vector3d d = points[static_cast<size_t>(indices[j])].cast<double>() - m;
    C += d * d.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
  if (!(es.eigenvalues()(1) > 1e-12)) return false;
  *normal = es.eigenvectors().col(0).cast<float>();
  return true;
}

namespace {
constexpr int kKeyAxisBits = 21;  // per axis in a VoxelKey
constexpr uint64_t kKeyAxisMask = (uint64_t{1} << kKeyAxisBits) - 1;
constexpr int64_t kKeyAxisBias = int64_t{1} << (kKeyAxisBits - 1);  // cell −2²⁰ is stored as 0
}  // namespace

uint64_t VoxelKey(int64_t x, int64_t y, int64_t z) {
  return (static_cast<uint64_t>(x + kKeyAxisBias) & kKeyAxisMask) |
         ((static_cast<uint64_t>(y + kKeyAxisBias) & kKeyAxisMask) << kKeyAxisBits) |
         ((static_cast<uint64_t>(z + kKeyAxisBias) & kKeyAxisMask) << (2 * kKeyAxisBits));
}

void VoxelOfKey(uint64_t key, int64_t* x, int64_t* y, int64_t* z) {
  *x = static_cast<int64_t>(key & kKeyAxisMask) - kKeyAxisBias;
  *y = static_cast<int64_t>((key >> kKeyAxisBits) & kKeyAxisMask) - kKeyAxisBias;
  *z = static_cast<int64_t>((key >> (2 * kKeyAxisBits)) & kKeyAxisMask) - kKeyAxisBias;
}

}  // namespace d3d
