// Test-only synthetic dental arches with known geometry, for the scan-path tests. Header-only.
#pragma once

#include <algorithm>
#include <cmath>
#include <numbers>
#include <vector>

#include "common/core/rigid.h"
#include "common/mesh/mesh.h"
#include "sim/trajectory/scan_path.h"

namespace d3d::testing {

// Synthetic arches: a box profile (9 mm wide, 8 mm high, open underneath, capped at both ends)
// swept along a centreline in the local XZ plane. Local frame: X across, Y occlusal (up), Z
// anterior. Faces above 3 mm are labelled tooth, below gingiva.
//  - U: two 12 mm legs and a half ellipse (26 mm across, 32 mm deep): 115 mm, like a real arch.
//  - Parabola: z = 40 − x²/25 for |x| ≤ 25: 74 mm.

inline constexpr double kWidth = 9.0, kHeight = 8.0, kToothFrom = 3.0;

enum class Shape { kU, kParabola };

// The centreline sampled every `step` mm of arc; returns its length.
inline double ArchCentreline(Shape shape, double step, std::vector<Eigen::Vector3d>* pts) {
  std::vector<Eigen::Vector3d> fine;
  if (shape == Shape::kU) {
    for (int i = 0; i <= 120; ++i) fine.emplace_back(-26.0, 0, 0.1 * i);  // leg
    for (int i = 1; i <= 20000; ++i) {
      const double phi = std::numbers::pi - std::numbers::pi * i / 20000;
      fine.emplace_back(26.0 * std::cos(phi), 0, 12.0 + 32.0 * std::sin(phi));
    }
    for (int i = 119; i >= 0; --i) fine.emplace_back(26.0, 0, 0.1 * i);  // other leg
  } else {
    for (int i = -50000; i <= 50000; ++i) {
      const double x = 25.0 * i / 50000;
      fine.emplace_back(x, 0, 40.0 - x * x / 25.0);
    }
  }
  double length = 0, next = 0;
  pts->clear();
  for (size_t i = 0; i < fine.size(); ++i) {
    if (i > 0) length += (fine[i] - fine[i - 1]).norm();
    if (length >= next) {
      pts->push_back(fine[i]);
      next += step;
    }
  }
  if ((pts->back() - fine.back()).norm() > 1e-9) pts->push_back(fine.back());
  return length;
}

inline void AddTriangle(TriangleMesh* m, int a, int b, int c, const Eigen::Vector3d& outward) {
  const Eigen::Vector3d n =
      (m->vertices[b] - m->vertices[a]).cross(m->vertices[c] - m->vertices[a]);
  if (n.dot(outward) >= 0)
    m->faces.emplace_back(a, b, c);
  else
    m->faces.emplace_back(a, c, b);
  const double h = (m->vertices[a].y() + m->vertices[b].y() + m->vertices[c].y()) / 3.0;
  m->face_labels.push_back(h > kToothFrom ? SurfaceLabel::kTooth : SurfaceLabel::kGingiva);
}

inline TriangleMesh RidgeArch(const Rigid3d& world_from_local, bool with_labels,
                              Shape shape = Shape::kU) {
  std::vector<Eigen::Vector3d> c;
  ArchCentreline(shape, 1.0, &c);
  // Open box profile (lateral offset, height) from outer bottom over the top to inner bottom.
  std::vector<Eigen::Vector2d> profile;
  for (int k = 0; k <= 8; ++k) profile.emplace_back(kWidth / 2, kHeight * k / 8);
  for (int k = 1; k <= 9; ++k) profile.emplace_back(kWidth / 2 - kWidth * k / 9, kHeight);
  for (int k = 7; k >= 0; --k) profile.emplace_back(-kWidth / 2, kHeight * k / 8);
  const Eigen::Vector3d up = Eigen::Vector3d::UnitY();
  TriangleMesh m;
  const int np = static_cast<int>(profile.size());
  std::vector<Eigen::Vector3d> tangents, outs;
  for (size_t i = 0; i < c.size(); ++i) {
    const size_t a = i == 0 ? 0 : i - 1, b = std::min(i + 1, c.size() - 1);
    const Eigen::Vector3d t = (c[b] - c[a]).normalized();
    Eigen::Vector3d out = t.cross(up);
    if (out.dot(c[i] - Eigen::Vector3d(0, 0, 10)) < 0) out = -out;  // away from the arch's interior
    tangents.push_back(t);
    outs.push_back(out);
    for (const auto& p : profile) m.vertices.push_back(c[i] + p.x() * out + p.y() * up);
  }
  auto vid = [&](size_t i, int k) { return static_cast<int>(i) * np + k; };
  for (size_t i = 0; i + 1 < c.size(); ++i) {
    for (int k = 0; k + 1 < np; ++k) {
      const Eigen::Vector2d mid = 0.5 * (profile[k] + profile[k + 1]);
      const Eigen::Vector3d outward =
          mid.y() >= kHeight - 1e-9 ? up : (mid.x() > 0 ? outs[i] : Eigen::Vector3d(-outs[i]));
      AddTriangle(&m, vid(i, k), vid(i + 1, k), vid(i + 1, k + 1), outward);
      AddTriangle(&m, vid(i, k), vid(i + 1, k + 1), vid(i, k + 1), outward);
    }
  }
  // End caps: a grid over the profile rectangle at both ends.
  for (const size_t i : {size_t{0}, c.size() - 1}) {
    const Eigen::Vector3d outward = i == 0 ? Eigen::Vector3d(-tangents[i]) : tangents[i];
    const int base = static_cast<int>(m.vertices.size());
    constexpr int kNx = 9, kNy = 8;
    for (int y = 0; y <= kNy; ++y)
      for (int x = 0; x <= kNx; ++x)
        m.vertices.push_back(c[i] + (kWidth * x / kNx - kWidth / 2) * outs[i] +
                             (kHeight * y / kNy) * up);
    for (int y = 0; y < kNy; ++y) {
      for (int x = 0; x < kNx; ++x) {
        const int v00 = base + y * (kNx + 1) + x;
        AddTriangle(&m, v00, v00 + 1, v00 + kNx + 2, outward);
        AddTriangle(&m, v00, v00 + kNx + 2, v00 + kNx + 1, outward);
      }
    }
  }
  for (auto& v : m.vertices) v = world_from_local * v;
  if (!with_labels) m.face_labels.clear();
  return m;
}

inline Rigid3d SomeWorldFromLocal() {
  Rigid3d T = Rigid3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(5, -3, 10);
  return T;
}

// The analysed synthetic U arch (labelled, in SomeWorldFromLocal), computed once.
inline const ArchFrame& SyntheticArch() {
  static const ArchFrame arch = AnalyzeArch(RidgeArch(SomeWorldFromLocal(), true));
  return arch;
}

}  // namespace d3d::testing
