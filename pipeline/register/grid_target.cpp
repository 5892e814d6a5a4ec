#include "pipeline/register/grid_target.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "common/core/status.h"

namespace d3d {
namespace {
constexpr uint32_t kNoSlot = std::numeric_limits<uint32_t>::max();
// Boxes are widened by this much (mm) in the skip tests, so that rounding in a box's corner (float
// coordinates of tens of mm: ulp ~4e-6 mm) never skips a sample the exact test would take.
constexpr float kBoxSlackMm = 1e-4f;

bool Finite(const Eigen::Vector3f& p) {
  return std::isfinite(p.x()) && std::isfinite(p.y()) && std::isfinite(p.z());
}

// Squared distance from v to the interval [a, a + c] (widened by kBoxSlackMm) along one axis.
inline float AxisGap2(float v, float a, float c) {
  const float lo = a - kBoxSlackMm, hi = a + c + kBoxSlackMm;
  const float d = v < lo ? lo - v : (v > hi ? v - hi : 0.0f);
  return d * d;
}

inline int Clamp(int v, int n) { return std::min(std::max(v, 0), n - 1); }
}  // namespace

void GridTarget::Build(const SurfacePoints& target, const std::vector<double>& gates_mm,
                       double decimate_min_gate_mm) {
  D3D_CHECK_MSG(target.normals.size() == target.points.size(),
                "GridTarget needs a normal per point");
  std::vector<double> gates = gates_mm;
  for (double g : gates) D3D_CHECK_MSG(g > 0 && std::isfinite(g), "GridTarget: gates must be > 0");
  std::sort(gates.begin(), gates.end());
  gates.erase(std::unique(gates.begin(), gates.end()), gates.end());
  // A gate within kShareGateRatio of the next one up is served by that one's grid, unless that grid
  // is decimated (GridFor takes the first grid whose gate is at least the query's).
  const auto decimated = [&](double g) {
    return decimate_min_gate_mm > 0 && g >= decimate_min_gate_mm;
  };
  size_t kept = 0;
  for (size_t i = 0; i < gates.size(); ++i)
    if (i + 1 == gates.size() || gates[i + 1] > kShareGateRatio * gates[i] ||
        decimated(gates[i + 1]))
      gates[kept++] = gates[i];
  gates.resize(kept);

  size_ = target.points.size();
  lo_ = Eigen::Vector3f::Constant(std::numeric_limits<float>::max());
  hi_ = Eigen::Vector3f::Constant(std::numeric_limits<float>::lowest());
  bool any = false;
  for (const Eigen::Vector3f& p : target.points)
    if (Finite(p)) {
      lo_ = lo_.cwiseMin(p);
      hi_ = hi_.cwiseMax(p);
      any = true;
    }
  used_grids_ = 0;
  if (!any) return;
  if (grids_.size() < gates.size()) grids_.resize(gates.size());
  for (size_t i = 0; i < gates.size(); ++i) {
    grids_[i].gate = static_cast<float>(gates[i]);
    BuildGrid(&grids_[i], target, decimated(gates[i]));
  }
  used_grids_ = gates.size();
}

void GridTarget::BuildGrid(Grid* g, const SurfacePoints& target, bool decimate) {
  // Cells of the gate's edge, each split into sub³ sub-cells of about kSubCellMm; fewer sub-cells,
  // then coarser cells, while the slots would exceed kMaxCells.
  float cell = g->gate;
  int sub = std::clamp(static_cast<int>(std::lround(g->gate / kSubCellMm)), 1, 8);
  const Eigen::Vector3f extent = hi_ - lo_;
  for (;;) {
    g->nx = static_cast<int>(std::floor(extent.x() / cell)) + 1;
    g->ny = static_cast<int>(std::floor(extent.y() / cell)) + 1;
    g->nz = static_cast<int>(std::floor(extent.z() / cell)) + 1;
    if (int64_t{g->nx} * g->ny * g->nz * sub * sub * sub <= kMaxCells) break;
    if (sub > 1)
      --sub;
    else
      cell *= 1.25f;
  }
  g->cell = cell;
  g->sub = sub;
  g->sub_cell = cell / static_cast<float>(sub);
  g->origin = lo_;
  const size_t slots = static_cast<size_t>(g->nx) * static_cast<size_t>(g->ny) *
                       static_cast<size_t>(g->nz) * static_cast<size_t>(sub * sub * sub);
  const size_t n = target.points.size();
  // Counting sort of the samples by slot: cell-major (x fastest), then sub-cell (x fastest).
  g->start.assign(slots + 1, 0);
  slot_of_.resize(n);
  const float inv = 1.0f / cell, inv_sub = 1.0f / g->sub_cell;
  constexpr int kV = kDecimateVoxels;
  static_assert(kV * kV * kV <= 64, "a cell's voxels fit one 64-bit mask");
  const float inv_voxel = static_cast<float>(kV) / cell;
  // One 64-bit mask per cell: 64 kB for the tracker's ~20 mm targets at 1 mm cells (a grid capped
  // at kMaxCells cells would take 64 MB).
  if (decimate) voxel_taken_.assign(static_cast<size_t>(g->nx) * g->ny * g->nz, 0);
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3f& p = target.points[i];
    if (!Finite(p)) {
      slot_of_[i] = kNoSlot;
      continue;
    }
    const Eigen::Vector3f rel = p - lo_;
    const int x = Clamp(static_cast<int>(rel.x() * inv), g->nx),
              y = Clamp(static_cast<int>(rel.y() * inv), g->ny),
              z = Clamp(static_cast<int>(rel.z() * inv), g->nz);
    const int a = Clamp(static_cast<int>((rel.x() - static_cast<float>(x) * cell) * inv_sub), sub),
              b = Clamp(static_cast<int>((rel.y() - static_cast<float>(y) * cell) * inv_sub), sub),
              d = Clamp(static_cast<int>((rel.z() - static_cast<float>(z) * cell) * inv_sub), sub);
    const size_t c = (static_cast<size_t>(z) * g->ny + y) * g->nx + x;
    if (decimate) {  // the first sample of each voxel only, one with a normal (Find refuses the
                     // others)
      if (!Finite(target.normals[i])) {
        slot_of_[i] = kNoSlot;
        continue;
      }
      const int vx = Clamp(static_cast<int>((rel.x() - static_cast<float>(x) * cell) * inv_voxel),
                           kV),
                vy = Clamp(static_cast<int>((rel.y() - static_cast<float>(y) * cell) * inv_voxel),
                           kV),
                vz = Clamp(static_cast<int>((rel.z() - static_cast<float>(z) * cell) * inv_voxel),
                           kV);
      const uint64_t bit = uint64_t{1} << ((vz * kV + vy) * kV + vx);
      if (voxel_taken_[c] & bit) {
        slot_of_[i] = kNoSlot;
        continue;
      }
      voxel_taken_[c] |= bit;
    }
    const uint32_t s = static_cast<uint32_t>(c * static_cast<size_t>(sub * sub * sub) +
                                             static_cast<size_t>((d * sub + b) * sub + a));
    slot_of_[i] = s;
    ++g->start[s + 1];
  }
  for (size_t s = 0; s < slots; ++s) g->start[s + 1] += g->start[s];
  const size_t kept = g->start[slots];
  g->points.resize(kept);
  g->normals.resize(kept);
  // Scatter with a running cursor per slot (start[s] advanced, then shifted back).
  for (size_t i = 0; i < n; ++i) {
    const uint32_t s = slot_of_[i];
    if (s == kNoSlot) continue;
    const uint32_t at = g->start[s]++;
    g->points[at] = target.points[i];
    g->normals[at] = target.normals[i];
  }
  for (size_t s = slots; s > 0; --s) g->start[s] = g->start[s - 1];
  g->start[0] = 0;
}

const GridTarget::Grid* GridTarget::GridFor(float r) const {
  if (used_grids_ == 0) return nullptr;
  for (size_t i = 0; i < used_grids_; ++i)
    if (grids_[i].gate >= r) return &grids_[i];
  return &grids_[used_grids_ - 1];
}

size_t GridTarget::samples(float max_distance_mm) const {
  const Grid* g = GridFor(max_distance_mm);
  return g == nullptr ? 0 : g->points.size();
}

bool GridTarget::Find(const Eigen::Vector3f& q, float max_d, Eigen::Vector3f* point,
                      Eigen::Vector3f* normal) const {
  Hit hit;  // a sample found lies within the gate: Find's search starts at best = gate²
  if (!Search<false>(q, max_d, 0.0f, &hit)) return false;
  const Grid& g = *GridFor(max_d);
  *point = g.points[static_cast<size_t>(hit.found)];
  *normal = g.normals[static_cast<size_t>(hit.found)];
  return std::isfinite((*normal)[0]);
}

bool GridTarget::FindCertified(const Eigen::Vector3f& q, float max_d, float margin_mm,
                               CertifiedNearest* out) const {
  *out = CertifiedNearest{};
  if (!Finite(q) || !(max_d > 0) || !(margin_mm >= 0))
    return false;  // not certified: the caller searches each time
  Hit hit;
  hit.reach = max_d + margin_mm;  // an empty target holds nothing anywhere
  Search<true>(q, max_d, margin_mm, &hit);
  out->certified = true;
  if (hit.found >= 0 && hit.best < hit.reach * hit.reach) {
    const Grid& g = *GridFor(max_d);
    out->found = true;
    out->point = g.points[static_cast<size_t>(hit.found)];
    out->normal = g.normals[static_cast<size_t>(hit.found)];
    out->distance_mm = std::sqrt(hit.best);
    out->clearance_mm = std::sqrt(std::min(hit.second, hit.bound));
  } else {
    out->clearance_mm =
        hit.reach;  // nothing within reach (a query beyond the grid: nothing near it at all)
  }
  return true;
}

template <bool kCertify>
bool GridTarget::Search(const Eigen::Vector3f& q, float max_d, float margin, Hit* hit) const {
  hit->found = -1;
  const Grid* g = GridFor(max_d);
  if (g == nullptr || !(max_d > 0) || !Finite(q)) return false;
  const float c = g->cell, f = g->sub_cell;
  const int sub = g->sub, sub3 = sub * sub * sub;
  const int ring = std::max(1, static_cast<int>(std::ceil(max_d / c)));
  // Certified: every sample within `reach` of the query is looked at (the ring covers at least
  // ring·c around it), and the skip bound is the nearest so far plus the margin, so that every
  // sample skipped lies farther than the final bound.
  hit->reach = kCertify ? std::min(max_d + margin, static_cast<float>(ring) * c) : max_d;
  const Eigen::Vector3f rel = q - g->origin;
  // The cells within the ring, clamped to the grid (in float first, so far queries do not overflow
  // int).
  const auto range = [ring](float v, int n, int* a, int* b) {
    if (v < -ring || v >= static_cast<float>(n + ring)) return false;
    const int i = static_cast<int>(std::floor(v));
    *a = std::max(0, i - ring);
    *b = std::min(n - 1, i + ring);
    return *a <= *b;
  };
  int x0, x1, y0, y1, z0, z1;
  if (!range(rel.x() / c, g->nx, &x0, &x1) || !range(rel.y() / c, g->ny, &y0, &y1) ||
      !range(rel.z() / c, g->nz, &z0, &z1))
    return false;
  // Find: `best` starts at the gate² and is also the skip bound (a sample is taken when its
  // distance² is below it). Certified: best starts unbounded, `bound` is the skip bound.
  float best = kCertify ? std::numeric_limits<float>::infinity() : max_d * max_d;
  float second = std::numeric_limits<float>::infinity();
  float bound = hit->reach * hit->reach;
  int64_t found = -1;
  const auto scan_slot = [&](size_t slot) {
    const uint32_t e = g->start[slot + 1];
    for (uint32_t k = g->start[slot]; k < e; ++k) {
      const float d2 = L2SimpleDistance2(q, g->points[k]);
      if (d2 < best) {
        if constexpr (kCertify) {
          second = best;
          const float r = std::sqrt(d2) + margin;
          bound = std::min(bound, r * r);
        }
        best = d2;
        found = k;
      } else if constexpr (kCertify) {
        if (d2 < second) second = d2;
      }
    }
  };
  const auto cell_index = [g](int x, int y, int z) {
    return (static_cast<size_t>(z) * g->ny + y) * g->nx + x;
  };
  // The query's own sub-cell first: its nearest sample bounds the search, and every cell or
  // sub-cell whose box lies farther than the best match so far is skipped.
  size_t own = std::numeric_limits<size_t>::max();
  {
    const int cx = static_cast<int>(std::floor(rel.x() / c)),
              cy = static_cast<int>(std::floor(rel.y() / c)),
              cz = static_cast<int>(std::floor(rel.z() / c));
    if (cx >= 0 && cx < g->nx && cy >= 0 && cy < g->ny && cz >= 0 && cz < g->nz) {
      const int a = Clamp(static_cast<int>((rel.x() - static_cast<float>(cx) * c) / f), sub),
                b = Clamp(static_cast<int>((rel.y() - static_cast<float>(cy) * c) / f), sub),
                d = Clamp(static_cast<int>((rel.z() - static_cast<float>(cz) * c) / f), sub);
      own = cell_index(cx, cy, cz) * static_cast<size_t>(sub3) +
            static_cast<size_t>((d * sub + b) * sub + a);
      scan_slot(own);
    }
  }
  const auto beyond = [&](float gap2) { return gap2 > (kCertify ? bound : best); };
  for (int z = z0; z <= z1; ++z) {
    const float oz = static_cast<float>(z) * c;
    const float gz = AxisGap2(rel.z(), oz, c);
    if (beyond(gz)) continue;
    for (int y = y0; y <= y1; ++y) {
      const float oy = static_cast<float>(y) * c;
      const float gyz = gz + AxisGap2(rel.y(), oy, c);
      if (beyond(gyz)) continue;
      for (int x = x0; x <= x1; ++x) {
        const float ox = static_cast<float>(x) * c;
        if (beyond(gyz + AxisGap2(rel.x(), ox, c))) continue;
        const size_t base = cell_index(x, y, z) * static_cast<size_t>(sub3);
        if (sub == 1) {
          if (base != own) scan_slot(base);
          continue;
        }
        if (g->start[base] == g->start[base + static_cast<size_t>(sub3)])
          continue;  // an empty cell
        for (int d = 0; d < sub; ++d) {
          const float hz = AxisGap2(rel.z(), oz + static_cast<float>(d) * f, f);
          if (beyond(hz)) continue;
          for (int b = 0; b < sub; ++b) {
            const float hyz = hz + AxisGap2(rel.y(), oy + static_cast<float>(b) * f, f);
            if (beyond(hyz)) continue;
            for (int a = 0; a < sub; ++a) {
              const size_t slot = base + static_cast<size_t>((d * sub + b) * sub + a);
              if (slot == own || beyond(hyz + AxisGap2(rel.x(), ox + static_cast<float>(a) * f, f)))
                continue;
              scan_slot(slot);
            }
          }
        }
      }
    }
  }
  hit->found = found;
  hit->best = best;
  hit->second = second;
  hit->bound = bound;
  return found >= 0;
}

}  // namespace d3d
