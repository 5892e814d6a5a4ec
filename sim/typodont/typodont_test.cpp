// Tests of the procedural typodont: layout and arch measures, crown widths, interproximal gaps,
// mesh sanity, cusps, determinism and option checks. Measures are taken on the mesh itself.
//
// Set D3D_TYPODONT_DUMP=/path/to/file.ply (or =1 for ./typodont.ply) to save the default mesh as
// ASCII PLY (face properties: label, tooth id) for inspection.
#include "sim/typodont/typodont.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <vector>

#include "common/mesh/closest_point.h"

namespace d3d {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;
using Eigen::Vector3i;

constexpr std::array<int, 14> kArchOrder = {17, 16, 15, 14, 13, 12, 11, 21, 22, 23, 24, 25, 26, 27};
// Table values of the brief (mm), index = position - 1 (central .. second molar).
constexpr std::array<double, 7> kMesiodistal = {8.5, 6.5, 7.5, 7.0, 6.5, 10.0, 9.0};
constexpr std::array<double, 7> kBuccolingual = {7.0, 6.0, 8.0, 9.0, 9.0, 11.0, 11.0};
constexpr std::array<double, 7> kCrownHeight = {10.5, 9.0, 10.0, 8.5, 8.0, 7.5, 7.0};

void MaybeDump(const TriangleMesh& mesh) {
  const char* env = std::getenv("D3D_TYPODONT_DUMP");
  if (env == nullptr || *env == '\0') return;
  std::string path = env;
  if (path.size() < 4 || path.substr(path.size() - 4) != ".ply") path = "typodont.ply";
  std::ofstream out(path);
  out << "ply\nformat ascii 1.0\ncomment d3dscan procedural typodont (mm)\n"
      << "element vertex " << mesh.vertices.size()
      << "\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty "
         "float ny\n"
         "property float nz\nelement face "
      << mesh.faces.size()
      << "\nproperty list uchar int vertex_indices\nproperty uchar label\nproperty uchar "
         "tooth_id\nend_header\n";
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    const Vector3d& v = mesh.vertices[i];
    const Vector3d& n = mesh.vertex_normals[i];
    out << v.x() << ' ' << v.y() << ' ' << v.z() << ' ' << n.x() << ' ' << n.y() << ' ' << n.z()
        << '\n';
  }
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    out << "3 " << mesh.faces[f][0] << ' ' << mesh.faces[f][1] << ' ' << mesh.faces[f][2] << ' '
        << static_cast<int>(mesh.face_labels[f]) << ' ' << static_cast<int>(mesh.face_tooth_ids[f])
        << '\n';
  }
  std::printf("typodont written to %s\n", path.c_str());
}

struct Fixture {
  TriangleMesh mesh;
  TypodontInfo info;
  double seconds = 0;
};

// The default typodont, built once for all tests.
const Fixture& Default() {
  static const Fixture* fixture = [] {
    auto* f = new Fixture;
    const auto t0 = std::chrono::steady_clock::now();
    f->mesh = MakeTypodont(TypodontOptions{}, &f->info);
    f->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("typodont: %zu triangles, %zu vertices, %.3f s\n", f->mesh.faces.size(),
                f->mesh.vertices.size(), f->seconds);
    MaybeDump(f->mesh);
    return f;
  }();
  return *fixture;
}

TypodontOptions Coarse() {
  TypodontOptions o;
  o.crown_edge_mm = 0.4;
  o.gingiva_edge_mm = 0.8;
  return o;
}

struct Crown {
  std::vector<int> faces;
  std::vector<int> vertices;  // distinct
  Vector3d centroid = Vector3d::Zero();
};

std::map<int, Crown> SplitCrowns(const TriangleMesh& mesh) {
  std::map<int, Crown> crowns;
  std::map<int, std::set<int>> verts;
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    if (mesh.face_labels[f] != SurfaceLabel::kTooth) continue;
    const int id = mesh.face_tooth_ids[f];
    crowns[id].faces.push_back(static_cast<int>(f));
    for (int k = 0; k < 3; ++k) verts[id].insert(mesh.faces[f][k]);
  }
  for (auto& [id, c] : crowns) {
    c.vertices.assign(verts[id].begin(), verts[id].end());
    for (int v : c.vertices) c.centroid += mesh.vertices[v];
    c.centroid /= static_cast<double>(c.vertices.size());
  }
  return crowns;
}

double FaceArea(const TriangleMesh& m, int f) {
  const Vector3i& t = m.faces[f];
  return 0.5 *
         (m.vertices[t[1]] - m.vertices[t[0]]).cross(m.vertices[t[2]] - m.vertices[t[0]]).norm();
}

Vector3d FaceNormal(const TriangleMesh& m, int f) {
  const Vector3i& t = m.faces[f];
  return (m.vertices[t[1]] - m.vertices[t[0]])
      .cross(m.vertices[t[2]] - m.vertices[t[0]])
      .normalized();
}

// Uniform grid over points or triangles (by centroid) for neighbourhood queries.
class Grid {
 public:
  explicit Grid(double cell) : cell_(cell) {}
  void Insert(const Vector3d& p, int id) { cells_[Key(p)].push_back(id); }
  template <typename F>
  void ForNear(const Vector3d& p, F&& visit) const {
    const Eigen::Vector3i c = Cell(p);
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          const auto it = cells_.find(Pack(c + Eigen::Vector3i(dx, dy, dz)));
          if (it == cells_.end()) continue;
          for (int id : it->second) visit(id);
        }
  }

 private:
  Eigen::Vector3i Cell(const Vector3d& p) const {
    return {static_cast<int>(std::floor(p.x() / cell_)),
            static_cast<int>(std::floor(p.y() / cell_)),
            static_cast<int>(std::floor(p.z() / cell_))};
  }
  static int64_t Pack(const Eigen::Vector3i& c) {
    return (static_cast<int64_t>(c.x() + 100000) * 200003 + (c.y() + 100000)) * 200003 +
           (c.z() + 100000);
  }
  int64_t Key(const Vector3d& p) const { return Pack(Cell(p)); }
  double cell_;
  std::unordered_map<int64_t, std::vector<int>> cells_;
};

// Smallest distance from the vertices of crown a to the triangles of crown b (within 1 mm).
double VertexToTriangleDistance(const TriangleMesh& m, const Crown& a, const Crown& b) {
  Grid grid(1.0);
  for (int f : b.faces) {
    const Vector3i& t = m.faces[f];
    grid.Insert((m.vertices[t[0]] + m.vertices[t[1]] + m.vertices[t[2]]) / 3.0, f);
  }
  double best = 1.0;
  for (int v : a.vertices) {
    const Vector3d& p = m.vertices[v];
    grid.ForNear(p, [&](int f) {
      const Vector3i& t = m.faces[f];
      best = std::min(
          best,
          (p - ClosestOnTriangle(p, m.vertices[t[0]], m.vertices[t[1]], m.vertices[t[2]])).norm());
    });
  }
  return best;
}

// Cusp tips: vertices highest (-y) among all crown vertices within `radius` (horizontally) and
// standing at least `prominence` above the lowest of them.
std::vector<Vector3d> CuspTips(const TriangleMesh& m, const Crown& c, double radius,
                               double prominence) {
  Grid grid(radius);
  double top = -1e9;
  for (int v : c.vertices) {
    const Vector3d& p = m.vertices[v];
    grid.Insert(Vector3d(p.x(), 0, p.z()), v);
    top = std::max(top, -p.y());
  }
  // Candidates: not lower than any neighbour along an edge.
  std::unordered_map<int, bool> candidate;
  for (int v : c.vertices) candidate[v] = -m.vertices[v].y() >= top - 3.0;
  for (int f : c.faces) {
    for (int k = 0; k < 3; ++k) {
      const int a = m.faces[f][k], b = m.faces[f][(k + 1) % 3];
      if (m.vertices[a].y() > m.vertices[b].y()) candidate[a] = false;
      if (m.vertices[b].y() > m.vertices[a].y()) candidate[b] = false;
    }
  }
  std::vector<Vector3d> tips;
  for (int v : c.vertices) {
    const Vector3d& p = m.vertices[v];
    if (!candidate[v]) continue;
    bool is_max = true;
    double lowest = -p.y();
    grid.ForNear(Vector3d(p.x(), 0, p.z()), [&](int u) {
      const Vector3d& q = m.vertices[u];
      if (Vector2d(q.x() - p.x(), q.z() - p.z()).norm() > radius) return;
      if (-q.y() > -p.y() || (-q.y() == -p.y() && u < v)) is_max = false;
      lowest = std::min(lowest, -q.y());
    });
    if (is_max && -p.y() - lowest >= prominence) tips.push_back(p);
  }
  return tips;
}

// ---------------------------------------------------------------------------------------------

// The checks on the default mesh are grouped in a few tests: each CTest process builds it once.

void CheckArchOrderAndSymmetry(const TriangleMesh& m, const std::map<int, Crown>& crowns) {
  ASSERT_EQ(crowns.size(), 14u);
  for (int id : kArchOrder) ASSERT_TRUE(crowns.count(id)) << "missing tooth " << id;
  // Angle of each centroid around a point inside the arch increases from 17 to 27.
  const auto [lo, hi] = m.Bounds();
  const double zc = 0.5 * (lo.z() + hi.z());
  double prev = -1e9;
  for (int id : kArchOrder) {
    const Vector3d& c = crowns.at(id).centroid;
    const double angle = std::atan2(c.x(), c.z() - zc);
    EXPECT_GT(angle, prev) << "tooth " << id << " out of arch order";
    prev = angle;
    EXPECT_EQ(c.x() > 0, id > 20) << "tooth " << id << " on the wrong side";
  }
  // Left and right roughly mirror images (seeded asymmetry is small).
  for (int pos = 1; pos <= 7; ++pos) {
    Vector3d right = crowns.at(10 + pos).centroid;
    right.x() = -right.x();
    EXPECT_LT((right - crowns.at(20 + pos).centroid).norm(), 1.0) << "position " << pos;
  }
  // Info agrees with the mesh.
  ASSERT_EQ(Default().info.teeth.size(), 14u);
  for (size_t i = 0; i < 14; ++i) EXPECT_EQ(Default().info.teeth[i].fdi, kArchOrder[i]);
}

void CheckExtentAndArchDimensions(const TriangleMesh& m, const std::map<int, Crown>& crowns) {
  const auto [lo, hi] = m.Bounds();
  const Vector3d extent = hi - lo;
  std::printf("extent %.1f x %.1f x %.1f mm\n", extent.x(), extent.y(), extent.z());
  EXPECT_NEAR(extent.x(), 62.0, 6.0);
  EXPECT_NEAR(extent.y(), 19.0, 3.0);
  EXPECT_NEAR(extent.z(), 51.0, 6.0);
  EXPECT_NEAR(0.5 * (lo.x() + hi.x()), 0.0, 1.0);  // midline at x = 0
  // Occlusal plane near y = 0: the lowest crown points (incisal edges, cusps) within 1 mm of it.
  double lowest = 1e9;
  for (const auto& [id, c] : crowns)
    for (int v : c.vertices) lowest = std::min(lowest, m.vertices[v].y());
  EXPECT_NEAR(lowest, 0.0, 1.0);

  auto tip_of = [&](int id) {  // canine cusp tip = lowest vertex
    Vector3d best(0, 1e9, 0);
    for (int v : crowns.at(id).vertices)
      if (m.vertices[v].y() < best.y()) best = m.vertices[v];
    return best;
  };
  const double intercanine = (tip_of(13) - tip_of(23)).norm();
  auto mesiobuccal = [&](int id) {  // of the 4 molar cusps: the 2 most buccal, then the more mesial
    auto tips = CuspTips(m, crowns.at(id), 1.2, 0.3);
    EXPECT_GE(tips.size(), 4u);
    std::sort(tips.begin(), tips.end(), [](const Vector3d& a, const Vector3d& b) {
      return std::abs(a.x()) > std::abs(b.x());
    });
    if (tips.size() < 2) return Vector3d(0, 0, 0);
    return tips[0].z() > tips[1].z() ? tips[0] : tips[1];
  };
  const double intermolar = (mesiobuccal(16) - mesiobuccal(26)).norm();
  double z_front = -1e9, z_back = 1e9;
  for (int id : {11, 21})
    for (int v : crowns.at(id).vertices) z_front = std::max(z_front, m.vertices[v].z());
  for (int id : {17, 27})
    for (int v : crowns.at(id).vertices) z_back = std::min(z_back, m.vertices[v].z());
  const double depth = z_front - z_back;
  std::printf("inter-canine %.2f mm, inter-first-molar (MB cusps) %.2f mm, arch depth %.2f mm\n",
              intercanine, intermolar, depth);
  EXPECT_NEAR(intercanine, 34.0, 1.5);
  EXPECT_NEAR(intermolar, 52.0, 2.0);
  EXPECT_NEAR(depth, 45.0, 2.0);
  EXPECT_NEAR(0.5 * (z_front + z_back), 0.0, 1e-9);  // origin half-way in z
}

void CheckCrownWidths(const TriangleMesh& m, const std::map<int, Crown>& crowns) {
  for (size_t i = 0; i < kArchOrder.size(); ++i) {
    const int id = kArchOrder[i];
    const int pos = id % 10;
    // Mesiodistal direction: horizontal, between the neighbouring crowns' centroids.
    const Vector3d& prev = crowns.at(kArchOrder[i == 0 ? 0 : i - 1]).centroid;
    const Vector3d& next = crowns.at(kArchOrder[i + 1 == kArchOrder.size() ? i : i + 1]).centroid;
    Vector3d md = next - prev;
    md.y() = 0;
    md.normalize();
    const Vector3d bl = Vector3d::UnitY().cross(md);
    double md_lo = 1e9, md_hi = -1e9, bl_lo = 1e9, bl_hi = -1e9;
    for (int v : crowns.at(id).vertices) {
      md_lo = std::min(md_lo, m.vertices[v].dot(md)),
      md_hi = std::max(md_hi, m.vertices[v].dot(md));
      bl_lo = std::min(bl_lo, m.vertices[v].dot(bl)),
      bl_hi = std::max(bl_hi, m.vertices[v].dot(bl));
    }
    const double md_width = md_hi - md_lo, bl_width = bl_hi - bl_lo;
    std::printf("tooth %d: MD %.2f (table %.1f), BL %.2f (table %.1f)\n", id, md_width,
                kMesiodistal[pos - 1], bl_width, kBuccolingual[pos - 1]);
    EXPECT_NEAR(md_width, kMesiodistal[pos - 1], 0.1 * kMesiodistal[pos - 1]) << "tooth " << id;
    EXPECT_NEAR(bl_width, kBuccolingual[pos - 1], 0.15 * kBuccolingual[pos - 1]) << "tooth " << id;
    // Anatomical crown height (cervical line to tip) from the landmarks.
    const TypodontTooth& t = Default().info.teeth[i];
    EXPECT_NEAR((t.tip - t.cej_center).norm(), kCrownHeight[pos - 1], 0.05 * kCrownHeight[pos - 1]);
  }
}

TEST(Typodont, LayoutArchDimensionsAndCrownWidths) {
  const TriangleMesh& m = Default().mesh;
  const auto crowns = SplitCrowns(m);
  {
    SCOPED_TRACE("14 teeth in arch order, left/right mirrored");
    CheckArchOrderAndSymmetry(m, crowns);
  }
  {
    SCOPED_TRACE("extent, inter-canine, inter-molar, depth");
    CheckExtentAndArchDimensions(m, crowns);
  }
  {
    SCOPED_TRACE("crown widths");
    CheckCrownWidths(m, crowns);
  }
}

void CheckGaps(const TriangleMesh& m, const std::map<int, Crown>& crowns) {
  const double gap = TypodontOptions{}.gap_mm;
  for (size_t i = 0; i + 1 < kArchOrder.size(); ++i) {
    const Crown& a = crowns.at(kArchOrder[i]);
    const Crown& b = crowns.at(kArchOrder[i + 1]);
    const double d = std::min(VertexToTriangleDistance(m, a, b), VertexToTriangleDistance(m, b, a));
    std::printf("gap %d-%d: %.3f mm\n", kArchOrder[i], kArchOrder[i + 1], d);
    EXPECT_GE(d, 0.9 * gap) << kArchOrder[i] << "-" << kArchOrder[i + 1];
    EXPECT_LE(d, 0.5) << kArchOrder[i] << "-" << kArchOrder[i + 1] << " should almost touch";
  }
}

void CheckMeshSanity(const TriangleMesh& m) {
  EXPECT_NO_THROW(m.Check());
  ASSERT_EQ(m.face_labels.size(), m.faces.size());
  ASSERT_EQ(m.face_tooth_ids.size(), m.faces.size());
  ASSERT_EQ(m.vertex_normals.size(), m.vertices.size());
  EXPECT_LT(m.faces.size(), 600000u);
  EXPECT_GT(m.faces.size(), 100000u);
  const int nv = static_cast<int>(m.vertices.size());
  const double crown_edge = TypodontOptions{}.crown_edge_mm;
  double max_crown_edge = 0, max_gum_edge = 0, gum_down = 0;
  size_t gum_faces = 0;
  for (size_t f = 0; f < m.faces.size(); ++f) {
    const Vector3i& t = m.faces[f];
    for (int k = 0; k < 3; ++k) ASSERT_TRUE(t[k] >= 0 && t[k] < nv);
    ASSERT_GT(FaceArea(m, static_cast<int>(f)), 1e-8) << "degenerate face " << f;
    double e = 0;
    for (int k = 0; k < 3; ++k)
      e = std::max(e, (m.vertices[t[k]] - m.vertices[t[(k + 1) % 3]]).norm());
    if (m.face_labels[f] == SurfaceLabel::kTooth) {
      ASSERT_TRUE(m.face_tooth_ids[f] >= 11 && m.face_tooth_ids[f] <= 27);
      max_crown_edge = std::max(max_crown_edge, e);
    } else {
      ASSERT_EQ(m.face_labels[f], SurfaceLabel::kGingiva);
      ASSERT_EQ(m.face_tooth_ids[f], 0);
      max_gum_edge = std::max(max_gum_edge, e);
      gum_down += 2.0 * FaceArea(m, static_cast<int>(f)) * FaceNormal(m, static_cast<int>(f)).y();
      ++gum_faces;
    }
  }
  std::printf("max edge: crowns %.3f mm, gingiva %.3f mm; %zu gingiva faces\n", max_crown_edge,
              max_gum_edge, gum_faces);
  EXPECT_LE(max_crown_edge, 2.0 * crown_edge);
  EXPECT_LE(max_gum_edge, 3.0 * TypodontOptions{}.gingiva_edge_mm);
  EXPECT_GT(gum_faces, 10000u);
  EXPECT_LT(gum_down, 0.0) << "the gingiva must face the occlusal side (-y)";
  for (const Vector3d& n : m.vertex_normals) ASSERT_NEAR(n.norm(), 1.0, 1e-6);

  // Outward orientation of every crown: normals point away from its centroid.
  for (const auto& [id, c] : SplitCrowns(m)) {
    double flux = 0, area = 0, outward = 0;
    for (int f : c.faces) {
      const Vector3i& t = m.faces[f];
      const Vector3d centre = (m.vertices[t[0]] + m.vertices[t[1]] + m.vertices[t[2]]) / 3.0;
      const double a = FaceArea(m, f);
      const double dot = FaceNormal(m, f).dot((centre - c.centroid).normalized());
      flux += a * dot, area += a;
      if (dot > 0) outward += a;
    }
    EXPECT_GT(flux, 0.3 * area) << "tooth " << id;
    EXPECT_GT(outward, 0.9 * area) << "tooth " << id;
  }
}

void CheckCutEdgesCovered(const TriangleMesh& m) {
  // Boundary edges of the crowns (used by one face) lie where the crowns are cut: on the gingiva.
  std::map<std::pair<int, int>, int> edge_count;
  Grid gum(1.0);
  for (size_t f = 0; f < m.faces.size(); ++f) {
    const Vector3i& t = m.faces[f];
    if (m.face_labels[f] == SurfaceLabel::kTooth) {
      for (int k = 0; k < 3; ++k) ++edge_count[std::minmax(t[k], t[(k + 1) % 3])];
    } else {
      for (int k = 0; k < 3; ++k) gum.Insert(m.vertices[t[k]], t[k]);
    }
  }
  double worst = 0;
  size_t boundary = 0;
  for (const auto& [edge, count] : edge_count) {
    if (count != 1) continue;
    ++boundary;
    const Vector3d& p = m.vertices[edge.first];
    double nearest = 1.0;
    gum.ForNear(p, [&](int g) { nearest = std::min(nearest, (m.vertices[g] - p).norm()); });
    worst = std::max(worst, nearest);
  }
  std::printf("%zu crown boundary edges, farthest from the gingiva %.3f mm\n", boundary, worst);
  EXPECT_GT(boundary, 1000u);
  EXPECT_LT(worst, 0.8);
}

// Area (mm²) of crown surface inside the gingiva: tooth faces whose centroid lies more than
// `tolerance_mm` apical (+y) of the lowest gingiva crossing on the vertical line through it (the
// crest the crowns pierce). A probe cannot see such surface; a lab scan of the model has none.
double ToothAreaInsideGingiva(const TriangleMesh& m, double tolerance_mm) {
  constexpr double kCell = 1.0;  // mm, xz buckets of gingiva triangles
  auto key = [](double x, double z) {
    return std::make_pair(static_cast<int>(std::floor(x / kCell)),
                          static_cast<int>(std::floor(z / kCell)));
  };
  std::map<std::pair<int, int>, std::vector<int>> buckets;
  for (size_t f = 0; f < m.faces.size(); ++f) {
    if (m.face_labels[f] != SurfaceLabel::kGingiva) continue;
    Vector2d lo(1e9, 1e9), hi(-1e9, -1e9);
    for (int k = 0; k < 3; ++k) {
      const Vector3d& v = m.vertices[m.faces[f][k]];
      lo = lo.cwiseMin(Vector2d(v.x(), v.z())), hi = hi.cwiseMax(Vector2d(v.x(), v.z()));
    }
    const auto a = key(lo.x(), lo.y()), b = key(hi.x(), hi.y());
    for (int i = a.first; i <= b.first; ++i)
      for (int j = a.second; j <= b.second; ++j) buckets[{i, j}].push_back(static_cast<int>(f));
  }
  double area = 0;
  for (size_t f = 0; f < m.faces.size(); ++f) {
    if (m.face_labels[f] != SurfaceLabel::kTooth) continue;
    const Vector3i& t = m.faces[f];
    const Vector3d c = (m.vertices[t[0]] + m.vertices[t[1]] + m.vertices[t[2]]) / 3.0;
    auto it = buckets.find(key(c.x(), c.z()));
    if (it == buckets.end()) continue;
    double lowest = 1e9;
    for (int g : it->second) {  // barycentric coordinates of (x, z) in the projected triangle
      const Vector3d& a = m.vertices[m.faces[g][0]];
      const Vector3d& b = m.vertices[m.faces[g][1]];
      const Vector3d& d = m.vertices[m.faces[g][2]];
      const double det = (b.x() - a.x()) * (d.z() - a.z()) - (d.x() - a.x()) * (b.z() - a.z());
      if (std::abs(det) < 1e-12) continue;
      const double u =
          ((c.x() - a.x()) * (d.z() - a.z()) - (d.x() - a.x()) * (c.z() - a.z())) / det;
      const double v =
          ((b.x() - a.x()) * (c.z() - a.z()) - (c.x() - a.x()) * (b.z() - a.z())) / det;
      if (u < 0 || v < 0 || u + v > 1) continue;
      lowest = std::min(lowest, a.y() + u * (b.y() - a.y()) + v * (d.y() - a.y()));
    }
    if (c.y() > lowest + tolerance_mm) area += FaceArea(m, static_cast<int>(f));
  }
  return area;
}

TEST(Typodont, NoCrownSurfaceInsideTheGingiva) {
  // Crowns are clipped exactly at the gum surface; the gum mesh's 0.4 mm facets stray a few µm
  // from it. A 0.2 mm overlap (the former cut) left 102 mm² (4.2 % of the teeth) deeper than 20 µm.
  const TriangleMesh& m = Default().mesh;
  const double inside = ToothAreaInsideGingiva(m, 0.02);
  std::printf("crown surface more than 20 um inside the gingiva: %.2f mm2\n", inside);
  EXPECT_LT(inside, 0.5);
}

TEST(Typodont, GapsMeshSanityAndGingivaCover) {
  const TriangleMesh& m = Default().mesh;
  {
    SCOPED_TRACE("interproximal gaps");
    CheckGaps(m, SplitCrowns(m));
  }
  {
    SCOPED_TRACE("mesh sanity");
    CheckMeshSanity(m);
  }
  {
    SCOPED_TRACE("gingiva covers the crowns' cut edges");
    CheckCutEdgesCovered(m);
  }
  std::printf("generation %.3f s (printed only: speed is not a pass/fail test)\n",
              Default().seconds);
}

TEST(Typodont, CuspsOnPosteriorTeethAndCanines) {
  const TriangleMesh& m = Default().mesh;
  const auto crowns = SplitCrowns(m);
  for (int id : kArchOrder) {
    const int pos = id % 10;
    if (pos < 3) continue;
    const size_t n = CuspTips(m, crowns.at(id), 1.2, 0.3).size();
    std::printf("tooth %d: %zu cusp tips\n", id, n);
    if (pos == 3) {
      EXPECT_EQ(n, 1u) << "canine " << id;
    } else if (pos <= 5) {
      EXPECT_GE(n, 2u) << "premolar " << id;
    } else {
      EXPECT_GE(n, 4u) << "molar " << id;
    }
  }
}

TEST(Typodont, DeterministicPerSeed) {
  const TypodontOptions options = Coarse();
  const TriangleMesh a = MakeTypodont(options);
  const TriangleMesh b = MakeTypodont(options);
  ASSERT_EQ(a.vertices.size(), b.vertices.size());
  ASSERT_EQ(a.faces.size(), b.faces.size());
  for (size_t i = 0; i < a.vertices.size(); ++i) ASSERT_EQ(a.vertices[i], b.vertices[i]);
  for (size_t i = 0; i < a.faces.size(); ++i) ASSERT_EQ(a.faces[i], b.faces[i]);
  EXPECT_EQ(a.face_tooth_ids, b.face_tooth_ids);

  TypodontOptions other = options;
  other.seed = options.seed + 1;
  const TriangleMesh c = MakeTypodont(other);
  bool differs = c.vertices.size() != a.vertices.size();
  for (size_t i = 0; !differs && i < a.vertices.size(); ++i)
    differs = (a.vertices[i] - c.vertices[i]).norm() > 1e-6;
  EXPECT_TRUE(differs);
}

TEST(Typodont, NoAsymmetryGivesAMirrorImage) {
  TypodontOptions options = Coarse();
  options.asymmetry = 0;
  const TriangleMesh m = MakeTypodont(options);
  const auto crowns = SplitCrowns(m);
  for (int pos = 1; pos <= 7; ++pos) {
    Vector3d right = crowns.at(10 + pos).centroid;
    right.x() = -right.x();
    EXPECT_LT((right - crowns.at(20 + pos).centroid).norm(), 1e-6) << "position " << pos;
  }
}

TEST(Typodont, ScaleAndGapOptions) {
  TypodontOptions options = Coarse();
  options.scale = 1.1;
  options.gap_mm = 0.4;
  const TriangleMesh m = MakeTypodont(options);
  const auto [lo, hi] = m.Bounds();
  const auto [lo1, hi1] = MakeTypodont(Coarse()).Bounds();
  EXPECT_NEAR((hi - lo).x() / (hi1 - lo1).x(), 1.1, 0.05);
  const auto crowns = SplitCrowns(m);
  const double d = VertexToTriangleDistance(m, crowns.at(11), crowns.at(12));
  EXPECT_GE(d, 0.9 * 0.4);
  EXPECT_LE(d, 0.7);
}

TEST(Typodont, CheckRejectsNonsense) {
  EXPECT_NO_THROW(TypodontOptions{}.Check());
  TypodontOptions o;
  o.gap_mm = -0.1;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  EXPECT_THROW(MakeTypodont(o), std::invalid_argument);
  o = {};
  o.scale = 0;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = {};
  o.crown_edge_mm = 0;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = {};
  o.gingiva_edge_mm = std::nan("");
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = {};
  o.asymmetry = -1;
  EXPECT_THROW(o.Check(), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
