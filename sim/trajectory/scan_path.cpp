#include "sim/trajectory/scan_path.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <numbers>
#include <numeric>
#include <queue>
#include <random>
#include <stdexcept>

namespace d3d {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kDegToRad = kPi / 180.0;
constexpr double kInf = std::numeric_limits<double>::infinity();

// ---------------------------------------------------------------------------------------------
// Arch analysis: constants

constexpr size_t kMinToothFaces = 50;     // fewer labelled tooth faces: not a dental arch
constexpr double kSampleSpacingMm = 1.5;  // faces are resampled so samples are ≤ ~1.5 mm apart
constexpr double kCellMm = 1.0;           // occupancy grid cell
constexpr double kSliceMm = 1.0;          // slices along the band
constexpr double kEndCapMm = 4.0;         // cells this close to the farthest ones form an end cap
constexpr double kEndChordMm = 4.0;       // the ends are extended along the chord over this length
constexpr double kEndTrimMm = 5.0;        // ... after dropping this much of each end
constexpr double kMinEndSliceWeight = 0.6;  // lighter end slices (× median) are merged
constexpr double kSmoothSigmaMm = 3.0;      // Gaussian smoothing of the slice centroids
constexpr double kCurveStepMm = 0.5;        // resampling of the arch curve
constexpr double kTangentSigmaMm = 8.0;     // Gaussian smoothing of the curve's tangents
constexpr double kHeightPercentile = 0.90;
constexpr double kWidthPercentile = 0.95;
constexpr double kMinElongation = 3.0;         // length / mean width
constexpr double kMaxCurveOverGeodesic = 1.3;  // refined curve length / geodesic diameter
constexpr double kMinArchLengthMm = 20.0;
constexpr double kWallWeight = 0.05;  // relative weight of a wall (face ∥ occlusal direction)

struct SurfaceSample {
  Eigen::Vector3d p;
  double w;           // area, mm²
  Eigen::Vector3d n;  // unit normal of the face
};

// Area-weighted points covering a face: centroids of its k² sub-triangles (k edge subdivisions),
// so large faces are not under-represented.
void SampleFace(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                std::vector<SurfaceSample>* out) {
  const Eigen::Vector3d cross = (b - a).cross(c - a);
  const double area = 0.5 * cross.norm();
  if (!(area > 0.0)) return;
  const Eigen::Vector3d n = cross.normalized();
  const double longest = std::max({(b - a).norm(), (c - b).norm(), (a - c).norm()});
  const int k = std::clamp(static_cast<int>(std::ceil(longest / kSampleSpacingMm)), 1, 32);
  const double w = area / (k * k);
  const Eigen::Vector3d e1 = (b - a) / k, e2 = (c - a) / k;
  for (int i = 0; i < k; ++i) {
    for (int j = 0; i + j < k; ++j) {
      out->push_back({a + (i + 1.0 / 3) * e1 + (j + 1.0 / 3) * e2, w, n});
      if (i + j + 2 <= k) out->push_back({a + (i + 2.0 / 3) * e1 + (j + 2.0 / 3) * e2, w, n});
    }
  }
}

double WeightedPercentile(std::vector<std::pair<double, double>> values, double q) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  double total = 0;
  for (const auto& v : values) total += v.second;
  double acc = 0;
  for (const auto& v : values) {
    acc += v.second;
    if (acc >= q * total) return v.first;
  }
  return values.back().first;
}

// Gaussian smoothing of a sequence with odd reflection at both ends (keeps the end values and
// linear trends: x[-k] = 2 x[0] - x[k]).
template <typename T>
std::vector<T> SmoothOddReflect(const std::vector<T>& x, double sigma_samples) {
  const int n = static_cast<int>(x.size());
  if (n < 3 || sigma_samples <= 0.0) return x;
  const int radius = std::min(static_cast<int>(std::ceil(3.0 * sigma_samples)), n - 1);
  std::vector<double> kernel(static_cast<size_t>(radius) + 1);
  for (int k = 0; k <= radius; ++k)
    kernel[static_cast<size_t>(k)] = std::exp(-0.5 * k * k / (sigma_samples * sigma_samples));
  auto at = [&](int i) -> T {
    if (i < 0) return 2.0 * x.front() - x[static_cast<size_t>(-i)];
    if (i >= n) return 2.0 * x.back() - x[static_cast<size_t>(2 * (n - 1) - i)];
    return x[static_cast<size_t>(i)];
  };
  std::vector<T> y(x.size());
  for (int i = 0; i < n; ++i) {
    T acc = kernel[0] * x[static_cast<size_t>(i)];
    double wsum = kernel[0];
    for (int k = 1; k <= radius; ++k) {
      acc = acc + kernel[static_cast<size_t>(k)] * (at(i - k) + at(i + k));
      wsum += 2.0 * kernel[static_cast<size_t>(k)];
    }
    y[static_cast<size_t>(i)] = acc / wsum;
  }
  return y;
}

// ---------------------------------------------------------------------------------------------
// Occupancy grid of the points projected on the occlusal plane

class BandGrid {
 public:
  BandGrid(const std::vector<Eigen::Vector2d>& pts, double margin_mm) {
    Eigen::Vector2d lo = pts.front(), hi = pts.front();
    for (const auto& p : pts) {
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
    }
    origin_ = lo - Eigen::Vector2d::Constant(margin_mm);
    nx_ = static_cast<int>(std::ceil((hi.x() - origin_.x() + margin_mm) / kCellMm)) + 1;
    ny_ = static_cast<int>(std::ceil((hi.y() - origin_.y() + margin_mm) / kCellMm)) + 1;
    raw_.assign(size(), 0);
    for (const auto& p : pts) raw_[static_cast<size_t>(CellOf(p))] = 1;
  }

  size_t size() const { return static_cast<size_t>(nx_) * static_cast<size_t>(ny_); }
  int CellOf(const Eigen::Vector2d& p) const {
    const int ix = std::clamp(static_cast<int>((p.x() - origin_.x()) / kCellMm), 0, nx_ - 1);
    const int iy = std::clamp(static_cast<int>((p.y() - origin_.y()) / kCellMm), 0, ny_ - 1);
    return iy * nx_ + ix;
  }
  const std::vector<uint8_t>& raw() const { return raw_; }

  // Morphological closing (dilate then erode) of the raw occupancy by a disk of `r` cells.
  std::vector<uint8_t> Closed(int r) const { return Morph(Morph(raw_, r, true), r, false); }

  // 8-connected components of `mask`; labels (−1 outside), returns the count.
  int Components(const std::vector<uint8_t>& mask, std::vector<int>* label) const {
    label->assign(size(), -1);
    int count = 0;
    std::vector<int> stack;
    for (int start = 0; start < static_cast<int>(size()); ++start) {
      if (!mask[static_cast<size_t>(start)] || (*label)[static_cast<size_t>(start)] >= 0) continue;
      stack.push_back(start);
      (*label)[static_cast<size_t>(start)] = count;
      while (!stack.empty()) {
        const int c = stack.back();
        stack.pop_back();
        ForNeighbours(c, [&](int nb, double) {
          if (mask[static_cast<size_t>(nb)] && (*label)[static_cast<size_t>(nb)] < 0) {
            (*label)[static_cast<size_t>(nb)] = count;
            stack.push_back(nb);
          }
        });
      }
      ++count;
    }
    return count;
  }

  // Dijkstra distances (mm) inside `mask` from every source cell (8-neighbours, 1 or √2 cells).
  std::vector<double> Geodesic(const std::vector<uint8_t>& mask,
                               const std::vector<int>& sources) const {
    std::vector<double> dist(size(), kInf);
    using Item = std::pair<double, int>;
    std::priority_queue<Item, std::vector<Item>, std::greater<>> queue;
    for (int s : sources) {
      dist[static_cast<size_t>(s)] = 0;
      queue.push({0.0, s});
    }
    while (!queue.empty()) {
      const auto [d, c] = queue.top();
      queue.pop();
      if (d > dist[static_cast<size_t>(c)]) continue;
      ForNeighbours(c, [&](int nb, double step) {
        const double nd = d + step * kCellMm;
        if (mask[static_cast<size_t>(nb)] && nd < dist[static_cast<size_t>(nb)]) {
          dist[static_cast<size_t>(nb)] = nd;
          queue.push({nd, nb});
        }
      });
    }
    return dist;
  }

 private:
  template <typename F>
  void ForNeighbours(int c, F&& f) const {
    const int ix = c % nx_, iy = c / nx_;
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dx = -1; dx <= 1; ++dx) {
        if (dx == 0 && dy == 0) continue;
        const int x = ix + dx, y = iy + dy;
        if (x < 0 || y < 0 || x >= nx_ || y >= ny_) continue;
        f(y * nx_ + x, (dx != 0 && dy != 0) ? std::numbers::sqrt2 : 1.0);
      }
    }
  }

  std::vector<uint8_t> Morph(const std::vector<uint8_t>& in, int r, bool dilate) const {
    std::vector<uint8_t> out(size(), dilate ? 0 : 1);
    for (int iy = 0; iy < ny_; ++iy) {
      for (int ix = 0; ix < nx_; ++ix) {
        bool any = false, all = true;
        for (int dy = -r; dy <= r; ++dy) {
          for (int dx = -r; dx <= r; ++dx) {
            if (dx * dx + dy * dy > r * r) continue;
            const int x = ix + dx, y = iy + dy;
            const bool v =
                x >= 0 && y >= 0 && x < nx_ && y < ny_ && in[static_cast<size_t>(y * nx_ + x)];
            any = any || v;
            all = all && v;
          }
        }
        out[static_cast<size_t>(iy * nx_ + ix)] = dilate ? any : all;
      }
    }
    return out;
  }

  Eigen::Vector2d origin_;
  int nx_ = 0, ny_ = 0;
  std::vector<uint8_t> raw_;
};

// Cells whose distance is within `band` of the largest finite one.
std::vector<int> FarthestCells(const std::vector<double>& dist, double band) {
  double best = 0;
  for (double d : dist)
    if (std::isfinite(d)) best = std::max(best, d);
  std::vector<int> out;
  for (size_t i = 0; i < dist.size(); ++i)
    if (std::isfinite(dist[i]) && dist[i] >= best - band) out.push_back(static_cast<int>(i));
  return out;
}

// ---------------------------------------------------------------------------------------------
// Arch analysis steps

struct SelectedSurface {
  std::vector<SurfaceSample> arch;     // the samples analysed (teeth, or everything)
  std::vector<SurfaceSample> gingiva;  // gingiva samples (when labelled)
  Eigen::Vector3d normal_sum = Eigen::Vector3d::Zero();  // Σ area · unit normal over the arch faces
  size_t faces = 0;
  bool used_labels = false;
};

Status SelectSurface(const TriangleMesh& mesh, SelectedSurface* sel) {
  size_t n_tooth = 0, n_gingiva = 0;
  for (SurfaceLabel l : mesh.face_labels) {
    n_tooth += l == SurfaceLabel::kTooth;
    n_gingiva += l == SurfaceLabel::kGingiva;
  }
  sel->used_labels = n_tooth + n_gingiva > 0;
  if (sel->used_labels && n_tooth < kMinToothFaces) {
    return InvalidArgument("not a dental arch: too few tooth faces (" + std::to_string(n_tooth) +
                           " of " + std::to_string(mesh.faces.size()) + ", need " +
                           std::to_string(kMinToothFaces) + ")");
  }
  for (int f = 0; f < static_cast<int>(mesh.faces.size()); ++f) {
    const Eigen::Vector3i& F = mesh.faces[static_cast<size_t>(f)];
    const Eigen::Vector3d& a = mesh.vertices[static_cast<size_t>(F[0])];
    const Eigen::Vector3d& b = mesh.vertices[static_cast<size_t>(F[1])];
    const Eigen::Vector3d& c = mesh.vertices[static_cast<size_t>(F[2])];
    const SurfaceLabel label = mesh.Label(f);
    if (!sel->used_labels || label == SurfaceLabel::kTooth) {
      SampleFace(a, b, c, &sel->arch);
      sel->normal_sum += 0.5 * (b - a).cross(c - a);
      ++sel->faces;
    } else if (label == SurfaceLabel::kGingiva) {
      SampleFace(a, b, c, &sel->gingiva);
    }
  }
  if (sel->arch.empty()) return InvalidArgument("not a dental arch: all faces are degenerate");
  return Status::Ok();
}

Eigen::Vector3d WeightedMean(const std::vector<SurfaceSample>& s) {
  Eigen::Vector3d acc = Eigen::Vector3d::Zero();
  double w = 0;
  for (const auto& x : s) {
    acc += x.w * x.p;
    w += x.w;
  }
  return acc / w;
}

// Principal axes (columns, ascending variance) and variances of the samples.
struct Pca {
  Eigen::Vector3d mean;
  Eigen::Matrix3d axes;
  Eigen::Vector3d variances;
};

Pca ComputePca(const std::vector<SurfaceSample>& s) {
  Pca pca;
  pca.mean = WeightedMean(s);
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  double w = 0;
  for (const auto& x : s) {
    const Eigen::Vector3d d = x.p - pca.mean;
    cov += x.w * d * d.transpose();
    w += x.w;
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov / w);
  pca.axes = eig.eigenvectors();
  pca.variances = eig.eigenvalues().cwiseMax(0.0);
  return pca;
}

// Sense of the occlusal axis: teeth above gingiva, else the mean normal. 0 when undecidable.
double OcclusalSense(const SelectedSurface& sel, const Eigen::Vector3d& axis) {
  if (!sel.gingiva.empty()) {
    const double sep = (WeightedMean(sel.arch) - WeightedMean(sel.gingiva)).dot(axis);
    if (std::abs(sep) > 0.5) return sep > 0 ? 1.0 : -1.0;
  }
  double area = 0;
  for (const auto& x : sel.arch) area += x.w;
  const double mean_normal = sel.normal_sum.dot(axis) / area;
  if (std::abs(mean_normal) > 0.05) return mean_normal > 0 ? 1.0 : -1.0;
  return 0.0;
}

// The analysed surface in occlusal-plane coordinates.
struct PlanePoints {
  std::vector<Eigen::Vector2d> uv;  // mm, in the occlusal plane
  std::vector<double> height;       // mm, along the occlusal direction
  std::vector<double> weight;       // mm²
};

// Resamples a polyline every `step` mm (after extending both ends straight by `extend` mm).
template <typename V>
std::vector<V> Resample(std::vector<V> pts, double step, double extend) {
  const V d0 = (pts[0] - pts[1]).normalized();
  const V d1 = (pts[pts.size() - 1] - pts[pts.size() - 2]).normalized();
  pts.insert(pts.begin(), V(pts.front() + extend * d0));
  pts.push_back(V(pts.back() + extend * d1));
  std::vector<double> arc(pts.size(), 0.0);
  for (size_t i = 1; i < pts.size(); ++i) arc[i] = arc[i - 1] + (pts[i] - pts[i - 1]).norm();
  std::vector<V> out;
  size_t seg = 0;
  const int n = std::max(2, static_cast<int>(std::round(arc.back() / step)) + 1);
  for (int k = 0; k < n; ++k) {
    const double s = arc.back() * k / (n - 1);
    while (seg + 2 < pts.size() && arc[seg + 1] < s) ++seg;
    const double len = arc[seg + 1] - arc[seg];
    const double u = len > 0 ? std::clamp((s - arc[seg]) / len, 0.0, 1.0) : 0.0;
    out.push_back((1 - u) * pts[seg] + u * pts[seg + 1]);
  }
  return out;
}

// First guess of the centreline: the band is rasterised, its geodesic diameter gives the two
// ends, and slices by geodesic distance from one end give ordered centroids (smoothed, 1 mm apart).
Status GeodesicCentreline(const PlanePoints& pts, std::vector<Eigen::Vector2d>* line,
                          double* area_mm2, double* length_mm) {
  const BandGrid grid(pts.uv, 10.0);
  // Close the interdental gaps with the smallest radius that gathers ≥ 90 % of the surface.
  const double total = std::accumulate(pts.weight.begin(), pts.weight.end(), 0.0);
  std::vector<uint8_t> mask;
  std::vector<int> label;
  int best = -1;
  for (int r = 2; r <= 8; ++r) {
    mask = grid.Closed(r);
    const int n = grid.Components(mask, &label);
    std::vector<double> comp_weight(static_cast<size_t>(n), 0.0);
    for (size_t i = 0; i < pts.uv.size(); ++i) {
      const int l = label[static_cast<size_t>(grid.CellOf(pts.uv[i]))];
      if (l >= 0) comp_weight[static_cast<size_t>(l)] += pts.weight[i];
    }
    const auto it = std::max_element(comp_weight.begin(), comp_weight.end());
    best = static_cast<int>(it - comp_weight.begin());
    if (*it >= 0.9 * total) break;
  }
  for (size_t c = 0; c < mask.size(); ++c) mask[c] = label[c] == best;
  *area_mm2 = static_cast<double>(std::count(mask.begin(), mask.end(), 1)) * kCellMm * kCellMm;

  const int any = static_cast<int>(std::find(mask.begin(), mask.end(), 1) - mask.begin());
  const auto d0 = grid.Geodesic(mask, {any});
  const auto d_a0 = grid.Geodesic(mask, FarthestCells(d0, 0.0));
  const auto d_b = grid.Geodesic(mask, FarthestCells(d_a0, kEndCapMm));
  const auto d_a = grid.Geodesic(mask, FarthestCells(d_b, kEndCapMm));
  *length_mm = 0;
  for (double d : d_a)
    if (std::isfinite(d)) *length_mm = std::max(*length_mm, d);

  std::vector<Eigen::Vector2d> sum;
  std::vector<double> weight;
  for (size_t i = 0; i < pts.uv.size(); ++i) {
    const double d = d_a[static_cast<size_t>(grid.CellOf(pts.uv[i]))];
    if (!std::isfinite(d)) continue;
    const size_t k = static_cast<size_t>(d / kSliceMm);
    if (k >= sum.size()) {
      sum.resize(k + 1, Eigen::Vector2d::Zero());
      weight.resize(k + 1, 0.0);
    }
    sum[k] += pts.weight[i] * pts.uv[i];
    weight[k] += pts.weight[i];
  }
  line->clear();
  for (size_t k = 0; k < sum.size(); ++k)
    if (weight[k] > 0) line->push_back(sum[k] / weight[k]);
  if (line->size() < 3) return InvalidArgument("not a dental arch: the tooth band is too small");
  *line = Resample(SmoothOddReflect(*line, kSmoothSigmaMm / kSliceMm), kSliceMm, 0.0);
  return Status::Ok();
}

// The polyline with both ends extended straight by `extend` mm along the chord over their last
// kEndChordMm (more robust than the last segment's direction).
std::vector<Eigen::Vector2d> ExtendEnds(const std::vector<Eigen::Vector2d>& line, double extend) {
  auto end_dir = [&](auto begin, auto end) {
    double acc = 0;
    auto it = begin;
    for (auto next = begin + 1; next != end && acc < kEndChordMm; ++next) {
      acc += (*next - *it).norm();
      it = next;
    }
    return Eigen::Vector2d((*begin - *it).normalized());
  };
  std::vector<Eigen::Vector2d> out;
  out.push_back(line.front() + extend * end_dir(line.begin(), line.end()));
  out.insert(out.end(), line.begin(), line.end());
  out.push_back(line.back() + extend * end_dir(line.rbegin(), line.rend()));
  return out;
}

// Where a point lies relative to a polyline: arc position of its foot (mm along the polyline)
// and signed lateral offset (mm, > 0 to the left of the direction of travel).
struct LineCoords {
  double arc = 0;
  double lateral = 0;
};

double Cross2(const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return a.x() * b.y() - a.y() * b.x();
}

// Nearest-point queries on a polyline, accelerated by a grid of its segments: a cell lists every
// segment within kSearchRadiusMm of it, so a hit closer than that radius is the global nearest;
// farther points fall back to a scan of all segments.
class PolylineProjector {
 public:
  explicit PolylineProjector(const std::vector<Eigen::Vector2d>& line)
      : line_(line), arc_(line.size(), 0.0) {
    for (size_t i = 1; i < line_.size(); ++i)
      arc_[i] = arc_[i - 1] + (line_[i] - line_[i - 1]).norm();
    lo_ = hi_ = line_.front();
    for (const auto& p : line_) {
      lo_ = lo_.cwiseMin(p);
      hi_ = hi_.cwiseMax(p);
    }
    lo_ -= Eigen::Vector2d::Constant(kSearchRadiusMm);
    hi_ += Eigen::Vector2d::Constant(kSearchRadiusMm);
    nx_ = static_cast<int>((hi_.x() - lo_.x()) / kGridCellMm) + 1;
    ny_ = static_cast<int>((hi_.y() - lo_.y()) / kGridCellMm) + 1;
    cells_.resize(static_cast<size_t>(nx_) * static_cast<size_t>(ny_));
    for (size_t i = 0; i + 1 < line_.size(); ++i) {
      const Eigen::Vector2d a =
          line_[i].cwiseMin(line_[i + 1]) - Eigen::Vector2d::Constant(kSearchRadiusMm);
      const Eigen::Vector2d b =
          line_[i].cwiseMax(line_[i + 1]) + Eigen::Vector2d::Constant(kSearchRadiusMm);
      for (int y = CellY(a.y()); y <= CellY(b.y()); ++y)
        for (int x = CellX(a.x()); x <= CellX(b.x()); ++x)
          cells_[static_cast<size_t>(y * nx_ + x)].push_back(i);
    }
  }

  LineCoords Project(const Eigen::Vector2d& p) const {
    double best = kInf;
    LineCoords out;
    if ((p.array() >= lo_.array()).all() && (p.array() <= hi_.array()).all()) {
      for (size_t i : cells_[static_cast<size_t>(CellY(p.y()) * nx_ + CellX(p.x()))])
        Consider(i, p, &best, &out);
      if (best <= kSearchRadiusMm * kSearchRadiusMm) return out;
    }
    for (size_t i = 0; i + 1 < line_.size(); ++i) Consider(i, p, &best, &out);
    return out;
  }

 private:
  static constexpr double kGridCellMm = 4.0;
  static constexpr double kSearchRadiusMm = 8.0;

  int CellX(double x) const {
    return std::clamp(static_cast<int>((x - lo_.x()) / kGridCellMm), 0, nx_ - 1);
  }
  int CellY(double y) const {
    return std::clamp(static_cast<int>((y - lo_.y()) / kGridCellMm), 0, ny_ - 1);
  }

  void Consider(size_t i, const Eigen::Vector2d& p, double* best, LineCoords* out) const {
    const Eigen::Vector2d d = line_[i + 1] - line_[i];
    const double len2 = d.squaredNorm();
    if (len2 <= 0) return;
    const double t = std::clamp((p - line_[i]).dot(d) / len2, 0.0, 1.0);
    const Eigen::Vector2d foot = line_[i] + t * d;
    const double dist2 = (p - foot).squaredNorm();
    if (dist2 < *best) {
      *best = dist2;
      const double len = std::sqrt(len2);
      out->arc = arc_[i] + t * len;
      out->lateral = Cross2(d / len, p - foot);
    }
  }

  std::vector<Eigen::Vector2d> line_;
  std::vector<double> arc_;
  Eigen::Vector2d lo_, hi_;
  int nx_ = 0, ny_ = 0;
  std::vector<std::vector<size_t>> cells_;
};

// The point at arc position `arc` of a polyline and its left normal there.
std::pair<Eigen::Vector2d, Eigen::Vector2d> PointAtArc(const std::vector<Eigen::Vector2d>& line,
                                                       double arc) {
  double acc = 0;
  for (size_t i = 0; i + 1 < line.size(); ++i) {
    const Eigen::Vector2d d = line[i + 1] - line[i];
    const double len = d.norm();
    if (len <= 0) continue;
    if (acc + len >= arc || i + 2 == line.size()) {
      const Eigen::Vector2d u = d / len;
      return {line[i] + (arc - acc) * u, Eigen::Vector2d(-u.y(), u.x())};
    }
    acc += len;
  }
  return {line.back(), Eigen::Vector2d::UnitY()};
}

// Slices of the band along a centreline: centre (plane coords) and heights.
struct Slice {
  Eigen::Vector2d centre = Eigen::Vector2d::Zero();
  double weight = 0;
  double arc_sum = 0;                              // Σ weight · arc
  std::vector<std::pair<double, double>> lateral;  // (lateral offset, weight)
  std::vector<std::pair<double, double>> heights;  // (height, weight)
};

// The last slice at an end holds whatever is left of the band there; cut slightly obliquely it
// may hold only one side of the band and would drag the curve's end sideways. End slices lighter
// than kMinEndSliceWeight × the median are merged into their neighbour.
void MergeLightEnds(std::vector<Slice>* slices) {
  if (slices->size() < 4) return;
  std::vector<double> w;
  for (const auto& sl : *slices) w.push_back(sl.weight);
  std::nth_element(w.begin(), w.begin() + static_cast<long>(w.size() / 2), w.end());
  const double min_w = kMinEndSliceWeight * w[w.size() / 2];
  auto merge = [](const Slice& from, Slice* into) {
    into->weight += from.weight;
    into->arc_sum += from.arc_sum;
    into->lateral.insert(into->lateral.end(), from.lateral.begin(), from.lateral.end());
    into->heights.insert(into->heights.end(), from.heights.begin(), from.heights.end());
  };
  while (slices->size() > 3 && slices->back().weight < min_w) {
    merge(slices->back(), &(*slices)[slices->size() - 2]);
    slices->pop_back();
  }
  while (slices->size() > 3 && slices->front().weight < min_w) {
    merge(slices->front(), &(*slices)[1]);
    slices->erase(slices->begin());
  }
}

// Slices the points square to the centreline (extended straight beyond its ends) every
// kSliceMm. A slice's centre sits at its mean arc position, midway between the 5th and 95th
// percentiles of the lateral offsets: the middle of the band, even where a slice cuts the end of
// the band obliquely (a centroid would be pulled toward the corner that sticks out).
std::vector<Slice> SliceAlong(const PlanePoints& pts,
                              const std::vector<Eigen::Vector2d>& centreline) {
  const std::vector<Eigen::Vector2d> line = ExtendEnds(centreline, 100.0);
  const PolylineProjector projector(line);
  std::vector<LineCoords> lc(pts.uv.size());
  double lo = kInf;
  for (size_t i = 0; i < pts.uv.size(); ++i) {
    lc[i] = projector.Project(pts.uv[i]);
    lo = std::min(lo, lc[i].arc);
  }
  std::vector<Slice> slices;
  for (size_t i = 0; i < pts.uv.size(); ++i) {
    const size_t k = static_cast<size_t>((lc[i].arc - lo) / kSliceMm);
    if (k >= slices.size()) slices.resize(k + 1);
    Slice& sl = slices[k];
    sl.weight += pts.weight[i];
    sl.arc_sum += pts.weight[i] * lc[i].arc;
    sl.lateral.push_back({lc[i].lateral, pts.weight[i]});
    sl.heights.push_back({pts.height[i], pts.weight[i]});
  }
  std::erase_if(slices, [](const Slice& s) { return s.weight <= 0; });
  MergeLightEnds(&slices);
  for (auto& sl : slices) {
    const auto [foot, normal] = PointAtArc(line, sl.arc_sum / sl.weight);
    const double mid =
        0.5 * (WeightedPercentile(sl.lateral, 0.05) + WeightedPercentile(sl.lateral, 0.95));
    sl.centre = foot + mid * normal;
  }
  return slices;
}

// Drops the first and last `trim` mm of a polyline sampled every kSliceMm (when long enough).
std::vector<Eigen::Vector2d> TrimEnds(const std::vector<Eigen::Vector2d>& line, double trim) {
  const size_t k = static_cast<size_t>(std::round(trim / kSliceMm));
  if (line.size() < 4 * k + 3) return line;
  return {line.begin() + static_cast<long>(k), line.end() - static_cast<long>(k)};
}

// Principal-curve refinement (in the spirit of Hastie & Stuetzle 1989): slice the points square
// to the current centreline, take the slices' centres, smooth, repeat. The last kEndTrimMm at
// each end are dropped before slicing again, so the end slices are square to the straight
// extension of the curve rather than to its possibly bent end.
std::vector<Slice> RefinedSlices(const PlanePoints& pts, std::vector<Eigen::Vector2d> line) {
  constexpr int kIterations = 5;
  line = TrimEnds(line, kEndTrimMm);
  for (int it = 0;; ++it) {
    std::vector<Slice> slices = SliceAlong(pts, line);
    if (it == kIterations || slices.size() < 3) return slices;
    line.clear();
    for (const auto& s : slices) line.push_back(s.centre);
    line = TrimEnds(Resample(SmoothOddReflect(line, kSmoothSigmaMm / kSliceMm), kSliceMm, 0.0),
                    kEndTrimMm);
  }
}

// Builds the curve (positions, tangents, buccal directions, arc lengths) from the slices.
void BuildCurve(const std::vector<Slice>& slices, const Eigen::Vector3d& centre,
                const Eigen::Vector3d& e_u, const Eigen::Vector3d& e_v,
                const Eigen::Vector3d& occlusal, ArchFrame* arch) {
  std::vector<Eigen::Vector3d> raw;
  for (const Slice& s : slices) {
    const double h = WeightedPercentile(s.heights, kHeightPercentile);
    raw.push_back(centre + s.centre.x() * e_u + s.centre.y() * e_v + h * occlusal);
  }
  const auto smooth = SmoothOddReflect(raw, kSmoothSigmaMm / kSliceMm);
  const auto pts = Resample(smooth, kCurveStepMm, 0.5 * kSliceMm);
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : pts) mean += p / static_cast<double>(pts.size());

  // Tangents: finite differences smoothed over kTangentSigmaMm, so the frame follows the arch
  // rather than the tooth-by-tooth wobble of its centreline.
  std::vector<Eigen::Vector3d> diff(pts.size());
  for (size_t i = 0; i < pts.size(); ++i) {
    const size_t a = i == 0 ? 0 : i - 1, b = std::min(i + 1, pts.size() - 1);
    diff[i] = (pts[b] - pts[a]).normalized();
  }
  const auto tangents = SmoothOddReflect(diff, kTangentSigmaMm / kCurveStepMm);

  arch->curve.assign(pts.size(), ArchPoint{});
  int votes = 0;
  double arc = 0;
  for (size_t i = 0; i < pts.size(); ++i) {
    ArchPoint& q = arch->curve[i];
    q.position = pts[i];
    q.tangent = tangents[i].normalized();
    q.buccal = q.tangent.cross(occlusal).normalized();
    if (i > 0) arc += (pts[i] - pts[i - 1]).norm();
    q.arc_mm = arc;
    votes += q.buccal.dot(pts[i] - mean) > 0 ? 1 : -1;
  }
  if (votes < 0)
    for (auto& q : arch->curve) q.buccal = -q.buccal;
  arch->length_mm = arc;
}

// Per-point half width: 95th percentile of |lateral offset| of the nearby samples.
void EstimateHalfWidths(const PlanePoints& plane, const Eigen::Vector3d& centre,
                        const Eigen::Vector3d& e_u, const Eigen::Vector3d& e_v, ArchFrame* arch) {
  const size_t n = arch->curve.size();
  std::vector<Eigen::Vector2d> line;
  for (const auto& q : arch->curve)
    line.emplace_back((q.position - centre).dot(e_u), (q.position - centre).dot(e_v));
  std::vector<double> arc(n, 0.0);
  for (size_t k = 1; k < n; ++k) arc[k] = arc[k - 1] + (line[k] - line[k - 1]).norm();
  const PolylineProjector projector(line);
  std::vector<std::vector<std::pair<double, double>>> lateral(n);
  for (size_t i = 0; i < plane.uv.size(); ++i) {
    const LineCoords lc = projector.Project(plane.uv[i]);
    const size_t k = std::min<size_t>(
        static_cast<size_t>(std::lower_bound(arc.begin(), arc.end(), lc.arc) - arc.begin()), n - 1);
    lateral[k].push_back({std::abs(lc.lateral), plane.weight[i]});
  }
  const int window = static_cast<int>(std::round(2.0 / kCurveStepMm));
  for (size_t k = 0; k < n; ++k) {
    std::vector<std::pair<double, double>> near;
    for (int j = -window; j <= window; ++j) {
      const long idx = static_cast<long>(k) + j;
      if (idx < 0 || idx >= static_cast<long>(n)) continue;
      const auto& l = lateral[static_cast<size_t>(idx)];
      near.insert(near.end(), l.begin(), l.end());
    }
    arch->curve[k].half_width_mm = WeightedPercentile(near, kWidthPercentile);
  }
}

double MidlineArc(const ArchFrame& arch) {
  const Eigen::Vector3d a = arch.curve.front().position, b = arch.curve.back().position;
  Eigen::Vector3d chord = b - a;
  chord -= chord.dot(arch.occlusal) * arch.occlusal;
  const Eigen::Vector3d dir = chord.normalized();
  double best = -1, arc = 0.5 * arch.length_mm;
  for (const auto& q : arch.curve) {
    Eigen::Vector3d d = q.position - a;
    d -= d.dot(arch.occlusal) * arch.occlusal;
    const double dist = (d - d.dot(dir) * dir).norm();
    if (dist > best) {
      best = dist;
      arc = q.arc_mm;
    }
  }
  return arc;
}

std::vector<std::pair<double, double>> Zip(const std::vector<double>& a,
                                           const std::vector<double>& b) {
  std::vector<std::pair<double, double>> out(a.size());
  for (size_t i = 0; i < a.size(); ++i) out[i] = {a[i], b[i]};
  return out;
}

// Fits the arch curve to the plane points (see AnalyzeArch): fills curve, length, widths and
// midline of *arch, or says why the points are not an arch.
Status FitArchCurve(const PlanePoints& plane, const Eigen::Vector3d& centre,
                    const Eigen::Vector3d& e_u, const Eigen::Vector3d& e_v, ArchFrame* arch) {
  char buf[200];
  std::vector<Eigen::Vector2d> line;
  double area_mm2 = 0, geodesic_mm = 0;
  D3D_RETURN_IF_ERROR(GeodesicCentreline(plane, &line, &area_mm2, &geodesic_mm));
  // A band: its geodesic diameter is long compared with its width (area / diameter).
  if (geodesic_mm < kMinElongation * area_mm2 / std::max(geodesic_mm, 1e-9)) {
    std::snprintf(buf, sizeof(buf),
                  "not a dental arch: not an elongated band (geodesic length %.1f mm vs mean width "
                  "%.1f mm; a "
                  "plate or a blob?)",
                  geodesic_mm, area_mm2 / std::max(geodesic_mm, 1e-9));
    return InvalidArgument(buf);
  }
  const std::vector<Slice> slices = RefinedSlices(plane, line);
  if (slices.size() < 3) {
    return InvalidArgument("not a dental arch: the tooth band is too small");
  }
  BuildCurve(slices, centre, e_u, e_v, arch->occlusal, arch);
  arch->mean_width_mm = area_mm2 / std::max(arch->length_mm, 1e-9);
  if (arch->length_mm < kMinArchLengthMm) {
    std::snprintf(buf, sizeof(buf), "not a dental arch: too short (%.1f mm)", arch->length_mm);
    return InvalidArgument(buf);
  }
  // The refined curve must follow the band, not wander across a wide one.
  if (arch->length_mm > kMaxCurveOverGeodesic * geodesic_mm + 10.0) {
    std::snprintf(
        buf, sizeof(buf),
        "not a dental arch: no clear centreline (curve %.1f mm vs geodesic length %.1f mm)",
        arch->length_mm, geodesic_mm);
    return InvalidArgument(buf);
  }
  EstimateHalfWidths(plane, centre, e_u, e_v, arch);
  arch->midline_arc_mm = MidlineArc(*arch);
  return Status::Ok();
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// ArchFrame

ArchPoint ArchFrame::At(double arc_mm) const {
  D3D_CHECK_MSG(!curve.empty(), "ArchFrame::At on an arch without a curve");
  if (arc_mm <= curve.front().arc_mm || curve.size() == 1) {
    ArchPoint p = curve.front();
    p.position += (arc_mm - p.arc_mm) * p.tangent;
    p.arc_mm = arc_mm;
    return p;
  }
  if (arc_mm >= curve.back().arc_mm) {
    ArchPoint p = curve.back();
    p.position += (arc_mm - p.arc_mm) * p.tangent;
    p.arc_mm = arc_mm;
    return p;
  }
  const auto it = std::upper_bound(curve.begin(), curve.end(), arc_mm,
                                   [](double s, const ArchPoint& q) { return s < q.arc_mm; });
  const ArchPoint& b = *it;
  const ArchPoint& a = *(it - 1);
  const double u = (arc_mm - a.arc_mm) / std::max(b.arc_mm - a.arc_mm, 1e-12);
  ArchPoint p;
  p.position = (1 - u) * a.position + u * b.position;
  p.tangent = ((1 - u) * a.tangent + u * b.tangent).normalized();
  p.buccal = ((1 - u) * a.buccal + u * b.buccal).normalized();
  p.half_width_mm = (1 - u) * a.half_width_mm + u * b.half_width_mm;
  p.arc_mm = arc_mm;
  return p;
}

ArchFrame AnalyzeArch(const TriangleMesh& mesh) {
  ArchFrame arch;
  if (mesh.empty()) {
    arch.status = InvalidArgument("not a dental arch: empty mesh (no faces)");
    return arch;
  }
  try {
    mesh.Check();
  } catch (const std::invalid_argument& e) {
    arch.status = InvalidArgument(std::string("invalid mesh: ") + e.what());
    return arch;
  }
  SelectedSurface sel;
  arch.status = SelectSurface(mesh, &sel);
  if (!arch.ok()) return arch;
  arch.used_labels = sel.used_labels;
  arch.faces_used = sel.faces;

  const Pca pca = ComputePca(sel.arch);
  const Eigen::Vector3d var = pca.variances;
  char buf[200];
  if (var(1) < 1.0 || var(1) < 1e-3 * var(2)) {
    std::snprintf(buf, sizeof(buf),
                  "not a dental arch: the surface is degenerate (spreads %.2f, %.2f, %.2f mm)",
                  std::sqrt(var(0)), std::sqrt(var(1)), std::sqrt(var(2)));
    arch.status = InvalidArgument(buf);
    return arch;
  }
  if (var(0) > 0.5 * var(1)) {
    std::snprintf(buf, sizeof(buf),
                  "not a dental arch: no dominant occlusal plane (spreads %.1f, %.1f, %.1f mm)",
                  std::sqrt(var(0)), std::sqrt(var(1)), std::sqrt(var(2)));
    arch.status = InvalidArgument(buf);
    return arch;
  }
  const double sense = OcclusalSense(sel, pca.axes.col(0));
  if (sense == 0.0) {
    arch.status = InvalidArgument(
        "cannot tell the occlusal side: no tooth/gingiva labels and no net face normal (closed "
        "mesh?)");
    return arch;
  }
  arch.occlusal = sense * pca.axes.col(0);
  arch.centroid = pca.mean;
  const Eigen::Vector3d e_u = pca.axes.col(2), e_v = arch.occlusal.cross(e_u);

  PlanePoints plane;
  for (const auto& s : sel.arch) {
    const Eigen::Vector3d d = s.p - pca.mean;
    plane.uv.emplace_back(d.dot(e_u), d.dot(e_v));
    plane.height.push_back(d.dot(arch.occlusal));
    // Footprint weight: what the surface covers in the occlusal plane (walls parallel to the
    // occlusal direction, e.g. the distal faces of the last molars, barely pull the curve).
    plane.weight.push_back(s.w *
                           (kWallWeight + (1.0 - kWallWeight) * std::abs(s.n.dot(arch.occlusal))));
  }
  arch.status = FitArchCurve(plane, pca.mean, e_u, e_v, &arch);
  if (!arch.ok() && !sel.used_labels) {
    // Unlabelled scans often hold the palate or the floor of the mouth as well: retry with the
    // most occlusal part of the surface, where the crowns are.
    for (const double q : {0.5, 0.7}) {
      const double floor = WeightedPercentile(Zip(plane.height, plane.weight), q);
      PlanePoints top;
      for (size_t i = 0; i < plane.uv.size(); ++i) {
        if (plane.height[i] < floor) continue;
        top.uv.push_back(plane.uv[i]);
        top.height.push_back(plane.height[i]);
        top.weight.push_back(plane.weight[i]);
      }
      ArchFrame retry = arch;
      retry.status = FitArchCurve(top, pca.mean, e_u, e_v, &retry);
      if (retry.ok()) {
        arch = std::move(retry);
        break;
      }
    }
  }
  if (!arch.ok()) {
    arch.curve.clear();
    arch.length_mm = arch.midline_arc_mm = arch.mean_width_mm = 0;
  }
  return arch;
}

int ArchPointNearestAxis(const ArchFrame& arch, const Rigid3d& world_from_probe) {
  const Rigid3d probe_from_world = world_from_probe.inverse();
  double best_r2 = kInf;
  int best = -1;
  for (size_t i = 0; i < arch.curve.size(); ++i) {
    const Eigen::Vector3d p = probe_from_world * arch.curve[i].position;
    if (p.z() <= 0) continue;
    const double r2 = p.x() * p.x() + p.y() * p.y();
    if (r2 < best_r2) {
      best_r2 = r2;
      best = static_cast<int>(i);
    }
  }
  return best;
}

double AxisDepthToArchMm(const ArchFrame& arch, const Rigid3d& world_from_probe) {
  const int i = ArchPointNearestAxis(arch, world_from_probe);
  if (i < 0) return std::numeric_limits<double>::quiet_NaN();
  return (world_from_probe.inverse() * arch.curve[static_cast<size_t>(i)].position).z();
}

// ---------------------------------------------------------------------------------------------
// Scan paths

const char* ScanPhaseName(ScanPhase phase) {
  switch (phase) {
    case ScanPhase::kOcclusal:
      return "occlusal";
    case ScanPhase::kBuccal:
      return "buccal";
    case ScanPhase::kLingual:
      return "lingual";
    case ScanPhase::kTransition:
      return "transition";
    case ScanPhase::kDwell:
      return "dwell";
    case ScanPhase::kLift:
      return "lift";
  }
  return "unknown";
}

void ScanPathOptions::Check() const {
  auto in = [](double v, double lo, double hi) { return std::isfinite(v) && v >= lo && v <= hi; };
  D3D_CHECK_MSG(in(working_distance_mm, 1, 500),
                "working_distance_mm out of (1, 500]: " << working_distance_mm);
  D3D_CHECK_MSG(!passes.empty(), "passes is empty");
  for (ScanPhase p : passes) {
    D3D_CHECK_MSG(p == ScanPhase::kOcclusal || p == ScanPhase::kBuccal || p == ScanPhase::kLingual,
                  "passes may only hold occlusal, buccal or lingual, got " << ScanPhaseName(p));
  }
  D3D_CHECK_MSG(in(buccal_tilt_deg, 0, 80), "buccal_tilt_deg out of [0, 80]: " << buccal_tilt_deg);
  D3D_CHECK_MSG(in(lingual_tilt_deg, 0, 80),
                "lingual_tilt_deg out of [0, 80]: " << lingual_tilt_deg);
  D3D_CHECK_MSG(in(buccal_aim_offset_mm, 0, 20),
                "buccal_aim_offset_mm out of [0, 20]: " << buccal_aim_offset_mm);
  D3D_CHECK_MSG(in(lingual_aim_offset_mm, 0, 20),
                "lingual_aim_offset_mm out of [0, 20]: " << lingual_aim_offset_mm);
  D3D_CHECK_MSG(in(side_aim_drop_mm, -10, 10),
                "side_aim_drop_mm out of [-10, 10]: " << side_aim_drop_mm);
  D3D_CHECK_MSG(in(end_overshoot_mm, 0, 20),
                "end_overshoot_mm out of [0, 20]: " << end_overshoot_mm);
  D3D_CHECK_MSG(in(distal_tilt_deg, 0, 80), "distal_tilt_deg out of [0, 80]: " << distal_tilt_deg);
  D3D_CHECK_MSG(in(transition_lift_mm, 0, 20),
                "transition_lift_mm out of [0, 20]: " << transition_lift_mm);
  D3D_CHECK_MSG(in(corner_smoothing_mm, 0, 50),
                "corner_smoothing_mm out of [0, 50]: " << corner_smoothing_mm);
  D3D_CHECK_MSG(in(speed_mm_s, 5, 30), "speed_mm_s out of [5, 30]: " << speed_mm_s);
  D3D_CHECK_MSG(in(speed_variation, 0, 0.5),
                "speed_variation out of [0, 0.5]: " << speed_variation);
  D3D_CHECK_MSG(
      in(min_camera_speed_mm_s, 0.1, 100) && in(max_camera_speed_mm_s, min_camera_speed_mm_s, 100),
      "need 0.1 <= min_camera_speed_mm_s <= max_camera_speed_mm_s <= 100, got "
          << min_camera_speed_mm_s << ", " << max_camera_speed_mm_s);
  D3D_CHECK_MSG(in(transition_speed_mm_s, 1, 100),
                "transition_speed_mm_s out of [1, 100]: " << transition_speed_mm_s);
  D3D_CHECK_MSG(in(max_path_angular_speed_rad_s, 0.05, 20),
                "max_path_angular_speed_rad_s out of [0.05, 20]: " << max_path_angular_speed_rad_s);
  D3D_CHECK_MSG(in(roll_amplitude_deg, 0, 45),
                "roll_amplitude_deg out of [0, 45]: " << roll_amplitude_deg);
  D3D_CHECK_MSG(in(rock_amplitude_deg, 0, 45),
                "rock_amplitude_deg out of [0, 45]: " << rock_amplitude_deg);
  D3D_CHECK_MSG(in(roll_frequency_hz, 0, 5),
                "roll_frequency_hz out of [0, 5]: " << roll_frequency_hz);
  D3D_CHECK_MSG(in(rock_frequency_hz, 0, 5),
                "rock_frequency_hz out of [0, 5]: " << rock_frequency_hz);
  D3D_CHECK_MSG(in(roll_pivot_depth_mm, 0, 2 * working_distance_mm),
                "roll_pivot_depth_mm out of [0, 2 × working distance]: " << roll_pivot_depth_mm);
  D3D_CHECK_MSG(in(rock_pivot_depth_mm, 0, 2 * working_distance_mm),
                "rock_pivot_depth_mm out of [0, 2 × working distance]: " << rock_pivot_depth_mm);
  D3D_CHECK_MSG(in(tremor_position_mm, 0, 5),
                "tremor_position_mm out of [0, 5]: " << tremor_position_mm);
  D3D_CHECK_MSG(in(tremor_rotation_deg, 0, 5),
                "tremor_rotation_deg out of [0, 5]: " << tremor_rotation_deg);
  D3D_CHECK_MSG(in(tremor_min_hz, 0.1, 100) && in(tremor_max_hz, tremor_min_hz, 100),
                "need 0.1 <= tremor_min_hz <= tremor_max_hz <= 100, got " << tremor_min_hz << ", "
                                                                          << tremor_max_hz);
  D3D_CHECK_MSG(in(drift_position_mm, 0, 20),
                "drift_position_mm out of [0, 20]: " << drift_position_mm);
  D3D_CHECK_MSG(in(drift_rotation_deg, 0, 20),
                "drift_rotation_deg out of [0, 20]: " << drift_rotation_deg);
  D3D_CHECK_MSG(in(drift_frequency_hz, 0.01, 10),
                "drift_frequency_hz out of [0.01, 10]: " << drift_frequency_hz);
  D3D_CHECK_MSG(side == 0 || side == 1, "side must be 0 or 1, got " << side);
  D3D_CHECK_MSG(in(tooth_arc_mm, 0, 200), "tooth_arc_mm out of [0, 200]: " << tooth_arc_mm);
  D3D_CHECK_MSG(in(dwell_rock_deg, 0, 60), "dwell_rock_deg out of [0, 60]: " << dwell_rock_deg);
  D3D_CHECK_MSG(key_interval_ns >= 100'000 && key_interval_ns <= 100'000'000,
                "key_interval_ns out of [0.1 ms, 100 ms]: " << key_interval_ns);
}

namespace {

// Sum of seeded sinusoids Σ a_k sin(2π f_k t + φ_k), Σ a_k = peak: smooth (C∞) and bounded by peak.
class Oscillator {
 public:
  Oscillator() = default;
  Oscillator(std::mt19937* rng, int components, double f_lo_hz, double f_hi_hz, double peak) {
    std::uniform_real_distribution<double> freq(f_lo_hz, f_hi_hz), phase(0, 2 * kPi), amp(0.5, 1.0);
    double total = 0;
    for (int k = 0; k < components; ++k) {
      omega_.push_back(2 * kPi * freq(*rng));
      phase_.push_back(phase(*rng));
      amp_.push_back(amp(*rng));
      total += amp_.back();
    }
    for (double& a : amp_) a *= peak / total;
  }
  double operator()(double t_s) const {
    double v = 0;
    for (size_t k = 0; k < amp_.size(); ++k) v += amp_[k] * std::sin(omega_[k] * t_s + phase_[k]);
    return v;
  }

 private:
  std::vector<double> amp_, omega_, phase_;
};

struct Oscillator3 {
  Oscillator x, y, z;
  Oscillator3() = default;
  Oscillator3(std::mt19937* rng, int components, double f_lo, double f_hi, double peak)
      : x(rng, components, f_lo, f_hi, peak),
        y(rng, components, f_lo, f_hi, peak),
        z(rng, components, f_lo, f_hi, peak) {}
  Eigen::Vector3d operator()(double t_s) const { return {x(t_s), y(t_s), z(t_s)}; }
};

// All the seeded randomness of one scan.
struct HandModel {
  Oscillator speed;       // relative speed variation, peak 1
  Oscillator roll, rock;  // peak 1
  Oscillator3 tremor_pos, tremor_rot, drift_pos, drift_rot;

  explicit HandModel(const ScanPathOptions& o) {
    std::mt19937 rng(o.seed);
    speed = Oscillator(&rng, 3, 0.05, 0.25, 1.0);
    roll = Oscillator(&rng, 2, 0.85 * o.roll_frequency_hz, 1.15 * o.roll_frequency_hz, 1.0);
    rock = Oscillator(&rng, 2, 0.85 * o.rock_frequency_hz, 1.15 * o.rock_frequency_hz, 1.0);
    tremor_pos = Oscillator3(&rng, 3, o.tremor_min_hz, o.tremor_max_hz, o.tremor_position_mm);
    tremor_rot =
        Oscillator3(&rng, 3, o.tremor_min_hz, o.tremor_max_hz, o.tremor_rotation_deg * kDegToRad);
    drift_pos = Oscillator3(&rng, 2, 0.6 * o.drift_frequency_hz, 1.4 * o.drift_frequency_hz,
                            o.drift_position_mm);
    drift_rot = Oscillator3(&rng, 2, 0.6 * o.drift_frequency_hz, 1.4 * o.drift_frequency_hz,
                            o.drift_rotation_deg * kDegToRad);
  }
};

// The planned (intentional) state of the probe relative to the arch.
struct PlanState {
  double arc = 0;   // arc position of the aimed point, mm
  double tilt = 0;  // rad about the tangent: 0 occlusal, > 0 camera on the buccal side, < 0 lingual
  double pitch = 0;  // rad: optical axis tilted toward +tangent
  double lift = 0;   // mm added to the working distance
  ScanPhase phase = ScanPhase::kOcclusal;
};

// A stretch of the plan: state(s) for s ∈ [0, 1].
struct Leg {
  ScanPhase phase;
  std::function<PlanState(double)> at;
};

double PassTilt(ScanPhase pass, const ScanPathOptions& o) {
  if (pass == ScanPhase::kBuccal) return o.buccal_tilt_deg * kDegToRad;
  if (pass == ScanPhase::kLingual) return -o.lingual_tilt_deg * kDegToRad;
  return 0.0;
}

Leg PassLeg(ScanPhase pass, double arc0, double arc1, const ScanPathOptions& o) {
  const double tilt = PassTilt(pass, o);
  return {pass, [=](double s) {
            return PlanState{arc0 + s * (arc1 - arc0), tilt, 0.0, 0.0, pass};
          }};
}

// Lift and roll from tilt0 to tilt1 at `arc`; distal_sign = ±1 at a distal end (the side beyond
// the end along the tangent), 0 elsewhere (the midline of a quadrant).
Leg TransitionLeg(double arc, double tilt0, double tilt1, double distal_sign,
                  const ScanPathOptions& o) {
  const double pitch = -distal_sign * o.distal_tilt_deg * kDegToRad;
  const double lift = o.transition_lift_mm;
  return {ScanPhase::kTransition, [=](double s) {
            const double bump = std::sin(kPi * s);
            return PlanState{arc, tilt0 + s * (tilt1 - tilt0), pitch * bump, lift * bump,
                             ScanPhase::kTransition};
          }};
}

// Serpentine passes between arc positions a (start) and b, with transitions at the turning ends.
std::vector<Leg> PassPlan(double a, double b, double distal_sign_a, double distal_sign_b,
                          const ScanPathOptions& o) {
  std::vector<Leg> legs;
  double from = a, to = b;
  for (size_t i = 0; i < o.passes.size(); ++i) {
    legs.push_back(PassLeg(o.passes[i], from, to, o));
    if (i + 1 < o.passes.size()) {
      const double sign = to == b ? distal_sign_b : distal_sign_a;
      legs.push_back(
          TransitionLeg(to, PassTilt(o.passes[i], o), PassTilt(o.passes[i + 1], o), sign, o));
    }
    std::swap(from, to);
  }
  return legs;
}

// Circling one tooth: occlusal → buccal, a loop buccal → mesially tilted → lingual → distally
// tilted → buccal, back to occlusal.
std::vector<Leg> DwellPlan(double arc, const ScanPathOptions& o) {
  const double buccal = o.buccal_tilt_deg * kDegToRad, lingual = o.lingual_tilt_deg * kDegToRad;
  const double rock = o.dwell_rock_deg * kDegToRad;
  auto loop = [=](double s) {
    const double psi = 2 * kPi * s, c = std::cos(psi);
    return PlanState{arc, c >= 0 ? buccal * c : lingual * c, rock * std::sin(psi), 0.0,
                     ScanPhase::kDwell};
  };
  return {{ScanPhase::kDwell,
           [=](double s) {
             return PlanState{arc, buccal * s, 0.0, 0.0, ScanPhase::kDwell};
           }},
          {ScanPhase::kDwell, loop},
          {ScanPhase::kDwell, [=](double s) {
             return PlanState{arc, buccal * (1 - s), 0.0, 0.0, ScanPhase::kDwell};
           }}};
}

double PlanDistance(const PlanState& a, const PlanState& b, double wd) {
  return std::sqrt(std::pow(b.arc - a.arc, 2) + std::pow(wd * (b.tilt - a.tilt), 2) +
                   std::pow(wd * (b.pitch - a.pitch), 2) + std::pow(b.lift - a.lift, 2));
}

constexpr double kPlanStepMm = 0.25;

// Samples the legs about every kPlanStepMm of (arc, WD·angle, lift) travel.
std::vector<PlanState> SamplePlan(const std::vector<Leg>& legs, const ScanPathOptions& o) {
  std::vector<PlanState> out;
  for (const Leg& leg : legs) {
    double length = 0;
    constexpr int kProbe = 256;
    for (int k = 1; k <= kProbe; ++k)
      length +=
          PlanDistance(leg.at((k - 1.0) / kProbe), leg.at(1.0 * k / kProbe), o.working_distance_mm);
    const int n = std::max(2, static_cast<int>(std::ceil(length / kPlanStepMm)));
    for (int k = out.empty() ? 0 : 1; k <= n; ++k) out.push_back(leg.at(1.0 * k / n));
  }
  return out;
}

// Rounds the corners between legs: Gaussian smoothing of the numeric channels (labels kept).
std::vector<PlanState> SmoothPlan(const std::vector<PlanState>& plan, double sigma_mm) {
  std::vector<Eigen::Vector4d> v;
  for (const auto& s : plan) v.emplace_back(s.arc, s.tilt, s.pitch, s.lift);
  const auto sm = SmoothOddReflect(v, sigma_mm / kPlanStepMm);
  std::vector<PlanState> out = plan;
  for (size_t i = 0; i < out.size(); ++i) {
    out[i].arc = sm[i](0);
    out[i].tilt = sm[i](1);
    out[i].pitch = sm[i](2);
    out[i].lift = sm[i](3);
  }
  return out;
}

struct BasePose {
  Rigid3d world_from_probe;
  Eigen::Vector3d aim;
};

// The intended pose for a plan state: aim at the arch point (moved to the scanned side), optical
// axis tilted about the tangent by `tilt` and toward the tangent by `pitch`, image x across the
// arch, camera at working distance + lift from the aim.
BasePose PoseFor(const ArchFrame& arch, const PlanState& st, const ScanPathOptions& o) {
  const ArchPoint q = arch.At(st.arc);
  const Eigen::Vector3d& O = arch.occlusal;
  const Eigen::Vector3d T = (q.tangent - q.tangent.dot(O) * O).normalized();
  const Eigen::Vector3d B =
      T.cross(O).dot(q.buccal) >= 0 ? T.cross(O).normalized() : O.cross(T).normalized();
  // How far to the side the aim moves: 1 at the pass's nominal tilt.
  const double ref = st.tilt >= 0 ? o.buccal_tilt_deg : o.lingual_tilt_deg;
  const double side =
      ref > 0 ? std::clamp(std::sin(std::abs(st.tilt)) / std::sin(ref * kDegToRad), 0.0, 1.5) : 0.0;
  const double lateral =
      st.tilt >= 0 ? o.buccal_aim_offset_mm * side : -o.lingual_aim_offset_mm * side;
  const Eigen::Vector3d aim = q.position + lateral * B - o.side_aim_drop_mm * side * O;

  const double ct = std::cos(st.tilt), stl = std::sin(st.tilt);
  const Eigen::Vector3d d = -O * ct - B * stl;  // optical axis
  const Eigen::Vector3d x = B * ct - O * stl;   // image right, ⟂ d and T
  const Eigen::Vector3d z = d * std::cos(st.pitch) + T * std::sin(st.pitch);
  Rigid3d pose = Rigid3d::Identity();
  pose.linear() = LookRotation(z, x);
  pose.translation() = aim - (o.working_distance_mm + st.lift) * z;
  return {pose, aim};
}

bool IsPass(ScanPhase p) {
  return p == ScanPhase::kOcclusal || p == ScanPhase::kBuccal || p == ScanPhase::kLingual;
}

// Times the plan: during passes the aim moves at the (varying) nominal speed with the camera
// speed kept within its bounds; elsewhere the camera moves at the transition speed; the path's
// angular speed is capped. Returns seconds from the start, one per state.
std::vector<double> TimePlan(const std::vector<PlanState>& plan, const std::vector<BasePose>& poses,
                             const HandModel& hand, const ScanPathOptions& o) {
  std::vector<double> t(plan.size(), 0.0);
  for (size_t i = 1; i < plan.size(); ++i) {
    const double dc =
        (poses[i].world_from_probe.translation() - poses[i - 1].world_from_probe.translation())
            .norm();
    const double da = (poses[i].aim - poses[i - 1].aim).norm();
    const double dang = RotationAngleRad(poses[i].world_from_probe, poses[i - 1].world_from_probe);
    const double vary = 1.0 + o.speed_variation * hand.speed(t[i - 1]);
    double v_cam;
    if (IsPass(plan[i].phase)) {
      const double v_aim = o.speed_mm_s * vary;
      v_cam = da > 1e-9
                  ? std::clamp(v_aim * dc / da, o.min_camera_speed_mm_s, o.max_camera_speed_mm_s)
                  : o.min_camera_speed_mm_s;
    } else {
      v_cam = o.transition_speed_mm_s * vary;
    }
    const double dt = std::max({dc / v_cam, dang / o.max_path_angular_speed_rad_s, 1e-4});
    t[i] = t[i - 1] + dt;
  }
  return t;
}

// world_from_probe · (rotation by `angle` about the probe-frame `axis` through (0, 0, depth)).
Rigid3d PivotAboutAxisPoint(const Rigid3d& world_from_probe, const Eigen::Vector3d& axis,
                            double angle, double depth) {
  Rigid3d local = Rigid3d::Identity();
  local.linear() = Eigen::AngleAxisd(angle, axis).toRotationMatrix();
  const Eigen::Vector3d pivot(0, 0, depth);
  local.translation() = pivot - local.linear() * pivot;
  return world_from_probe * local;
}

constexpr double kWiggleRampS = 1.5;

// Weight of the deliberate wiggles at t: 0 at the start and end of the scan and during
// transitions (the plan already turns the probe there, and each pass must reach the arch's ends
// unwiggled), back to 1 within kWiggleRampS along a smoothstep (C1).
double WiggleEnvelope(int64_t t_ns, const std::vector<ScanSegment>& segments) {
  double gap_ns = std::min(std::abs(static_cast<double>(t_ns - segments.front().start_ns)),
                           std::abs(static_cast<double>(segments.back().end_ns - t_ns)));
  for (const auto& s : segments) {
    if (s.phase != ScanPhase::kTransition) continue;
    if (t_ns >= s.start_ns && t_ns <= s.end_ns) return 0.0;
    gap_ns = std::min({gap_ns, std::abs(static_cast<double>(t_ns - s.start_ns)),
                       std::abs(static_cast<double>(t_ns - s.end_ns))});
  }
  const double x = std::clamp(gap_ns * 1e-9 / kWiggleRampS, 0.0, 1.0);
  return x * x * (3.0 - 2.0 * x);
}

// Composes the deliberate wiggles (scaled by `envelope`) and the involuntary motion on the planned
// pose at t (s).
Rigid3d HandPose(const Rigid3d& planned, double t, double envelope, const HandModel& hand,
                 const ScanPathOptions& o) {
  Rigid3d T = PivotAboutAxisPoint(planned, Eigen::Vector3d::UnitX(),
                                  envelope * o.rock_amplitude_deg * kDegToRad * hand.rock(t),
                                  o.rock_pivot_depth_mm);
  T = PivotAboutAxisPoint(T, Eigen::Vector3d::UnitY(),
                          envelope * o.roll_amplitude_deg * kDegToRad * hand.roll(t),
                          o.roll_pivot_depth_mm);
  // Drift and tremor: world-axis rotation about the optical centre, world-axis translation.
  const Eigen::Vector3d rot = hand.drift_rot(t) + hand.tremor_rot(t);
  T.linear() = (ExpSO3(rot) * T.linear()).eval();
  T.translation() += hand.drift_pos(t) + hand.tremor_pos(t);
  return T;
}

std::vector<ScanSegment> Segments(const std::vector<PlanState>& plan,
                                  const std::vector<int64_t>& t_ns) {
  std::vector<ScanSegment> out;
  for (size_t i = 0; i < plan.size(); ++i) {
    if (out.empty() || out.back().phase != plan[i].phase) {
      if (!out.empty()) out.back().end_ns = t_ns[i];
      out.push_back({plan[i].phase, t_ns[i], t_ns[i]});
    }
    out.back().end_ns = t_ns[i];
  }
  return out;
}

Status BuildLegs(const ArchFrame& arch, ScanKind kind, const ScanPathOptions& o,
                 std::vector<Leg>* legs) {
  const double lo = -o.end_overshoot_mm, hi = arch.length_mm + o.end_overshoot_mm;
  const double mid = arch.midline_arc_mm;
  switch (kind) {
    case ScanKind::kFullArch:
      *legs = o.side == 0 ? PassPlan(lo, hi, -1, +1, o) : PassPlan(hi, lo, +1, -1, o);
      return Status::Ok();
    case ScanKind::kQuadrant:
      *legs = o.side == 0 ? PassPlan(lo, mid + o.end_overshoot_mm, -1, 0, o)
                          : PassPlan(hi, mid - o.end_overshoot_mm, +1, 0, o);
      return Status::Ok();
    case ScanKind::kTooth: {
      const double half = o.side == 0 ? mid : arch.length_mm - mid;
      if (o.tooth_arc_mm > half) {
        return InvalidArgument("tooth_arc_mm " + std::to_string(o.tooth_arc_mm) +
                               " mm is beyond the midline (half arch " + std::to_string(half) +
                               " mm)");
      }
      *legs = DwellPlan(o.side == 0 ? o.tooth_arc_mm : arch.length_mm - o.tooth_arc_mm, o);
      return Status::Ok();
    }
  }
  return InvalidArgument("unknown scan kind");
}

}  // namespace

ScanPathResult MakeScanTrajectory(const TriangleMesh& mesh, ScanKind kind,
                                  const ScanPathOptions& options) {
  options.Check();
  const ArchFrame arch = AnalyzeArch(mesh);
  if (!arch.ok()) {
    ScanPathResult result;
    result.status = arch.status;
    result.arch = arch;
    return result;
  }
  return MakeScanTrajectory(arch, kind, options);
}

ScanPathResult MakeScanTrajectory(const ArchFrame& arch, ScanKind kind,
                                  const ScanPathOptions& options) {
  options.Check();
  ScanPathResult result;
  result.arch = arch;
  if (!arch.ok() || arch.curve.size() < 2) {
    result.status = arch.ok() ? InvalidArgument("arch has no curve") : arch.status;
    return result;
  }
  std::vector<Leg> legs;
  result.status = BuildLegs(arch, kind, options, &legs);
  if (!result.ok()) return result;

  const HandModel hand(options);
  const std::vector<PlanState> plan =
      SmoothPlan(SamplePlan(legs, options), options.corner_smoothing_mm);
  std::vector<BasePose> poses;
  for (const auto& st : plan) poses.push_back(PoseFor(arch, st, options));
  const std::vector<double> t_s = TimePlan(plan, poses, hand, options);

  // The planned (smooth) motion as a C1 trajectory, then the hand on top, sampled every key
  // interval.
  std::vector<TimedPose> planned_keys;
  std::vector<int64_t> t_ns(plan.size());
  for (size_t i = 0; i < plan.size(); ++i) {
    t_ns[i] = options.start_ns + static_cast<int64_t>(std::llround(t_s[i] * 1e9));
    if (planned_keys.empty() || t_ns[i] > planned_keys.back().t_ns) {
      planned_keys.push_back({t_ns[i], poses[i].world_from_probe});
    }
  }
  const Trajectory planned(std::move(planned_keys));
  result.segments = Segments(plan, t_ns);
  std::vector<TimedPose> keys;
  for (int64_t t = planned.StartNs();; t += options.key_interval_ns) {
    const int64_t tc = std::min(t, planned.EndNs());
    const double ts = static_cast<double>(tc - options.start_ns) * 1e-9;
    keys.push_back({tc, HandPose(planned.WorldFromProbe(tc), ts,
                                 WiggleEnvelope(tc, result.segments), hand, options)});
    if (tc == planned.EndNs()) break;
  }
  result.trajectory = Trajectory(std::move(keys));
  return result;
}

// ---------------------------------------------------------------------------------------------
// Stats

std::string ScanPathStats::ToString() const {
  char buf[512];
  std::snprintf(
      buf, sizeof(buf),
      "duration %.1f s, path %.0f mm, speed min/mean/max %.1f/%.1f/%.1f mm/s (%.1f %% in 5-20), "
      "angular mean/max %.2f/%.2f rad/s, axis depth in DOF %.1f %% (mean %.1f mm), %zu samples",
      duration_s, path_length_mm, min_speed_mm_s, mean_speed_mm_s, max_speed_mm_s,
      100 * speed_in_5_20_share, mean_angular_speed_rad_s, max_angular_speed_rad_s,
      100 * depth_in_dof_share, mean_axis_depth_mm, samples);
  return buf;
}

ScanPathStats ComputeScanPathStats(const Trajectory& trajectory, const ArchFrame& arch) {
  constexpr int64_t kSampleNs = 1'000'000'000 / 30;
  constexpr int64_t kPathStepNs = 2'000'000;
  constexpr double kDofNear = 42.0, kDofFar = 58.0;
  ScanPathStats st;
  if (trajectory.empty()) return st;
  st.duration_s = static_cast<double>(trajectory.DurationNs()) * 1e-9;
  Eigen::Vector3d prev = trajectory.WorldFromProbe(trajectory.StartNs()).translation();
  for (int64_t t = trajectory.StartNs() + kPathStepNs; t <= trajectory.EndNs(); t += kPathStepNs) {
    const Eigen::Vector3d p = trajectory.WorldFromProbe(t).translation();
    st.path_length_mm += (p - prev).norm();
    prev = p;
  }
  st.min_speed_mm_s = kInf;
  size_t in_speed = 0, in_dof = 0, depth_count = 0;
  double depth_sum = 0;
  for (int64_t t = trajectory.StartNs(); t <= trajectory.EndNs(); t += kSampleNs) {
    const double v = LinearSpeedMmPerS(trajectory, t);
    const double w = AngularSpeedRadPerS(trajectory, t);
    st.min_speed_mm_s = std::min(st.min_speed_mm_s, v);
    st.max_speed_mm_s = std::max(st.max_speed_mm_s, v);
    st.mean_speed_mm_s += v;
    st.max_angular_speed_rad_s = std::max(st.max_angular_speed_rad_s, w);
    st.mean_angular_speed_rad_s += w;
    in_speed += v >= 5.0 && v <= 20.0;
    if (arch.ok() && !arch.curve.empty()) {
      const double depth = AxisDepthToArchMm(arch, trajectory.WorldFromProbe(t));
      if (std::isfinite(depth)) {
        depth_sum += depth;
        ++depth_count;
        in_dof += depth >= kDofNear && depth <= kDofFar;
      }
    }
    ++st.samples;
  }
  const double n = static_cast<double>(st.samples);
  st.mean_speed_mm_s /= n;
  st.mean_angular_speed_rad_s /= n;
  st.speed_in_5_20_share = static_cast<double>(in_speed) / n;
  st.depth_in_dof_share = static_cast<double>(in_dof) / n;
  st.mean_axis_depth_mm = depth_count > 0 ? depth_sum / static_cast<double>(depth_count) : 0.0;
  return st;
}

}  // namespace d3d
