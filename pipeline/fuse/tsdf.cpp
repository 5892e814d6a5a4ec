#include "pipeline/fuse/tsdf.h"

#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/VolumeToMesh.h>
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <unordered_set>

namespace d3d {

void TsdfOptions::Check() const {
  D3D_CHECK_MSG(voxel_mm > 0 && voxel_mm <= 1.0,
                "TsdfOptions: voxel_mm must be in (0, 1], got " << voxel_mm);
  D3D_CHECK_MSG(truncation_mm >= voxel_mm, "TsdfOptions: truncation_mm must be >= voxel_mm");
  D3D_CHECK_MSG(max_weight > 0 && min_point_weight >= 0, "TsdfOptions: weights must be positive");
  D3D_CHECK_MSG(max_incidence_deg > 0 && max_incidence_deg <= 90,
                "TsdfOptions: max_incidence_deg in (0, 90]");
  D3D_CHECK_MSG(pixel_stride >= 1, "TsdfOptions: pixel_stride >= 1");
  D3D_CHECK_MSG(min_mesh_weight >= 0 && mesh_seed_weight >= 0,
                "TsdfOptions: mesh weights must be >= 0");
  D3D_CHECK_MSG(max_cell_sdf_span == 0 || max_cell_sdf_span >= 1,
                "TsdfOptions: max_cell_sdf_span must be 0 (no test) or >= 1 cell diagonal, got "
                    << max_cell_sdf_span);
  D3D_CHECK_MSG(occlusion_margin_mm >= 0 &&
                    (occlusion_margin_mm == 0 || occlusion_reach_mm > occlusion_margin_mm),
                "TsdfOptions: occlusion_margin_mm must be >= 0 and below occlusion_reach_mm");
  D3D_CHECK_MSG(occlusion_min_weight > 0 && occlusion_stride >= 1,
                "TsdfOptions: occlusion_min_weight > 0, occlusion_stride >= 1");
  D3D_CHECK_MSG(secondary_fade_weight >= 0,
                "TsdfOptions: secondary_fade_weight must be >= 0, got " << secondary_fade_weight);
}

struct TsdfVolume::Impl {
  openvdb::FloatGrid::Ptr
      tsdf;  // D' (the surface's field) and W of all fused points (file comment)
  openvdb::FloatGrid::Ptr weight;
  // D_s and W_s of the secondary points alone, only where λ > 0 (leaves without any go).
  openvdb::FloatGrid::Ptr secondary_tsdf;
  openvdb::FloatGrid::Ptr secondary_weight;
};

namespace {
constexpr int kLeafDim = 8;  // openvdb::FloatTree::LeafNodeType::DIM
using Leaf = openvdb::FloatTree::LeafNodeType;

struct CoordHash {
  size_t operator()(const openvdb::Coord& c) const {
    return static_cast<size_t>(c.x()) * 73856093u ^ static_cast<size_t>(c.y()) * 19349663u ^
           static_cast<size_t>(c.z()) * 83492791u;
  }
};

openvdb::Coord LeafOrigin(const openvdb::Coord& ijk) {
  return openvdb::Coord(ijk.x() & ~(kLeafDim - 1), ijk.y() & ~(kLeafDim - 1),
                        ijk.z() & ~(kLeafDim - 1));
}

// std::lround's rounding (half away from zero) for |v| < 2^31, without its library call (the
// occlusion test rounds three coordinates per ray step; lround was 2.5 % of a live host's time).
inline int RoundToInt(double v) { return static_cast<int>(v + (v >= 0 ? 0.5 : -0.5)); }

// The origins of the first and last leaf (per axis) of the voxels within `band` (voxels) of a point
// (index space).
struct LeafRange {
  openvdb::Coord a{std::numeric_limits<int>::min()}, b{std::numeric_limits<int>::min()};
  bool operator==(const LeafRange& o) const { return a == o.a && b == o.b; }
};
LeafRange LeavesWithin(const Eigen::Vector3d& p_index, double band) {
  const openvdb::Coord lo(static_cast<int>(std::floor(p_index.x() - band)),
                          static_cast<int>(std::floor(p_index.y() - band)),
                          static_cast<int>(std::floor(p_index.z() - band)));
  const openvdb::Coord hi(static_cast<int>(std::ceil(p_index.x() + band)),
                          static_cast<int>(std::ceil(p_index.y() + band)),
                          static_cast<int>(std::ceil(p_index.z() + band)));
  return {LeafOrigin(lo), LeafOrigin(hi)};
}

void TouchLeaves(const LeafRange& range, std::unordered_set<openvdb::Coord, CoordHash>* leaves) {
  const openvdb::Coord& a = range.a;
  const openvdb::Coord& b = range.b;
  for (int x = a.x(); x <= b.x(); x += kLeafDim)
    for (int y = a.y(); y <= b.y(); y += kLeafDim)
      for (int z = a.z(); z <= b.z(); z += kLeafDim) leaves->insert(openvdb::Coord(x, y, z));
}

// The camera's projection (PinholeBrownConrady::Project) in single precision, for a row of
// kLeafDim voxel centres x0 + k·step (camera frame, mm): the row-major index of the nearest pixel
// (round half up), or −1 outside the image or behind the camera. Eight lanes at once (GCC/Clang
// vector extension); on x86-64 also built for AVX2 and chosen at run time (function
// multiversioning), else SSE2's two halves. (ProjectionF is named outside the anonymous namespace:
// VoxelPass holds one, and a unity build that includes this file warns of a member of internal
// linkage.)
}  // namespace
namespace tsdf_detail {
struct ProjectionF {
  float fx, fy, cx, cy, k1, k2, k3, p1, p2, u_max, v_max;
  int cols;
};
}  // namespace tsdf_detail
using tsdf_detail::ProjectionF;
namespace {

using Float8 = float __attribute__((vector_size(32)));
using Int8 = int32_t __attribute__((vector_size(32)));

// Not under ThreadSanitizer: the clone's ifunc resolver runs while the program is relocated,
// before the sanitizer's runtime is set up, and crashes the process.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(__SANITIZE_THREAD__)
#define D3D_AVX2_CLONE __attribute__((target_clones("avx2", "default")))
#else
#define D3D_AVX2_CLONE
#endif

D3D_AVX2_CLONE void ProjectRow(const ProjectionF& c, const float* x0, const float* step,
                               int32_t* pixel) {
  const Float8 kf = {0, 1, 2, 3, 4, 5, 6, 7};
  const Float8 x = x0[0] + kf * step[0], y = x0[1] + kf * step[1], z = x0[2] + kf * step[2];
  const Float8 iz = 1.0f / z;
  const Float8 xn = x * iz, yn = y * iz;
  const Float8 r2 = xn * xn + yn * yn;
  const Float8 radial = 1.0f + r2 * (c.k1 + r2 * (c.k2 + r2 * c.k3));
  const Float8 ud =
      c.fx * (xn * radial + 2.0f * c.p1 * xn * yn + c.p2 * (r2 + 2.0f * xn * xn)) + c.cx;
  const Float8 vd =
      c.fy * (yn * radial + c.p1 * (r2 + 2.0f * yn * yn) + 2.0f * c.p2 * xn * yn) + c.cy;
  const Int8 inside = (z > 0.0f) & (ud >= -0.5f) & (vd >= -0.5f) & (ud < c.u_max) & (vd < c.v_max);
  const Float8 zero = {};
  // Round half up; outside lanes are converted from 0 (no out-of-range conversion) and set to −1.
  const Int8 u = __builtin_convertvector(inside ? ud + 0.5f : zero, Int8);
  const Int8 v = __builtin_convertvector(inside ? vd + 0.5f : zero, Int8);
  const Int8 index = (v * c.cols + u) | ~inside;
  for (int k = 0; k < kLeafDim; ++k) pixel[k] = index[k];
}

}  // namespace

// A leaf near a view's points, in each grid.
struct TsdfVolume::ViewLeaf {
  Leaf *tsdf, *weight;                      // D', W
  Leaf *secondary_tsdf, *secondary_weight;  // D_s, W_s, or null (none here)
};

// What FuseLeaf needs of the view (FuseVoxels sets it up).
struct TsdfVolume::VoxelPass {
  Eigen::Matrix3d R_index;  // camera-frame step per index step (double: leaf origins)
  Eigen::Vector3d t;        // cam_from_world's translation
  Eigen::Vector3f step_i, step_j, step_k;  // R_index's columns in float (steps within a leaf)
  ProjectionF proj;
  const FusePixel* pixels;  // fuse_pixels_
  float trunc, maxw, fade_weight;
  bool fade;  // secondary points fade out (secondary_fade_weight > 0)
};

TsdfVolume::TsdfVolume(const TsdfOptions& options) : o_(options), impl_(std::make_unique<Impl>()) {
  o_.Check();
  openvdb::initialize();
  const float trunc = static_cast<float>(o_.truncation_mm);
  impl_->tsdf = openvdb::FloatGrid::create(trunc);
  impl_->weight = openvdb::FloatGrid::create(0.0f);
  const auto xf = openvdb::math::Transform::createLinearTransform(o_.voxel_mm);
  impl_->tsdf->setTransform(xf);
  impl_->weight->setTransform(xf->copy());
  impl_->tsdf->setGridClass(openvdb::GRID_LEVEL_SET);
  impl_->tsdf->setName("tsdf_mm");
  impl_->weight->setName("weight");
  impl_->secondary_tsdf = openvdb::FloatGrid::create(trunc);
  impl_->secondary_weight = openvdb::FloatGrid::create(0.0f);
  impl_->secondary_tsdf->setTransform(xf->copy());
  impl_->secondary_weight->setTransform(xf->copy());
}

TsdfVolume::~TsdfVolume() = default;

Status TsdfVolume::Integrate(const cv::Mat& P, const cv::Mat& N, const cv::Mat& Q,
                             const PinholeBrownConrady& camera, const Rigid3d& world_from_cam,
                             const cv::Mat& S) {
  if (P.type() != CV_32FC3 || N.type() != CV_32FC3 || P.size() != N.size())
    return InvalidArgument("tsdf: points and normals must be CV_32FC3 of one size");
  if (!Q.empty() && (Q.type() != CV_32F || Q.size() != P.size()))
    return InvalidArgument("tsdf: quality must be CV_32F like points");
  if (!S.empty() && (S.type() != CV_8U || S.size() != P.size()))
    return InvalidArgument("tsdf: secondary must be CV_8U like points");
  if (P.cols != camera.width || P.rows != camera.height)
    return InvalidArgument("tsdf: image size differs from the camera's");
  // 0. Occlusion test against the model so far (file comment): occluded_mask_ 1 = not fused.
  const bool test_occlusion = o_.occlusion_margin_mm > 0 && views_ > 0;
  last_occluded_ = 0;
  if (test_occlusion) TestOcclusion(P, world_from_cam);
  // 1. Per pixel, once: what a voxel projecting there adds.
  PreparePixels(P, N, Q, S, test_occlusion);
  // 2. The leaves near the view's points, allocated.
  const std::vector<ViewLeaf> nodes = AllocateLeaves(P, world_from_cam, test_occlusion);
  // 3. Every voxel of those leaves, projectively.
  const std::vector<uint8_t> secondary_left =
      FuseVoxels(nodes, camera, world_from_cam, P.cols, P.rows);
  // 4. Secondary leaves without bookkeeping left go.
  FreeSecondaryLeaves(nodes, secondary_left);
  ++views_;
  return Status::Ok();
}

// 0. Occlusion test against the model so far (file comment): occluded_mask_ 1 = a point behind a
// well-known surface, not fused; counts them in last_occluded_ and occluded_.
void TsdfVolume::TestOcclusion(const cv::Mat& P, const Rigid3d& world_from_cam) {
  const double inv_voxel = 1.0 / o_.voxel_mm;
  occluded_mask_.create(P.size(), CV_8U);
  occluded_mask_.setTo(0);
  const int k = o_.occlusion_stride;
  // Samples behind a known surface (D < −0.1·truncation, within the band's back half, at least
  // 0.9·truncation thick along any ray) are what counts; the step is shorter than that, less a
  // voxel either side (a sample reads its nearest voxel centre: at 0.8·truncation, a band whose
  // back began on a voxel boundary was stepped over). The band's front half is not used: a
  // point's own surface, seen grazing, lies within it along its ray.
  const double step = std::max(0.9 * o_.truncation_mm - 2.0 * o_.voxel_mm, 0.5 * o_.voxel_mm);
  const float behind = static_cast<float>(-0.1 * o_.truncation_mm);
  const Eigen::Vector3d centre = world_from_cam.translation();  // the camera's, world frame
  std::vector<int64_t> per_row((P.rows + k - 1) / k, 0);
  tbb::parallel_for(
      tbb::blocked_range<int>(0, (P.rows + k - 1) / k), [&](const tbb::blocked_range<int>& rows) {
        auto tacc = impl_->tsdf->getConstAccessor();
        auto wacc = impl_->weight->getConstAccessor();
        for (int br = rows.begin(); br < rows.end(); ++br) {
          const int r = br * k;
          const cv::Vec3f* p = P.ptr<cv::Vec3f>(r);
          for (int c = 0; c < P.cols; c += k) {
            if (!std::isfinite(p[c][0]) || !std::isfinite(p[c][2])) continue;
            const Eigen::Vector3d pc(p[c][0], p[c][1], p[c][2]);
            const double range = pc.norm();
            // Toward the camera along the ray, in index space: q(s) = p + s·(centre − p)/range.
            const Eigen::Vector3d p_index = (world_from_cam * pc) * inv_voxel;
            const Eigen::Vector3d toward = (centre * inv_voxel - p_index) / range;
            bool hidden = false;
            for (double s = o_.occlusion_margin_mm;
                 s <= o_.occlusion_reach_mm && s < range && !hidden; s += step) {
              const Eigen::Vector3d q = p_index + s * toward;
              const openvdb::Coord ijk(RoundToInt(q.x()), RoundToInt(q.y()), RoundToInt(q.z()));
              hidden = tacc.getValue(ijk) < behind && wacc.getValue(ijk) >= o_.occlusion_min_weight;
            }
            if (!hidden) continue;
            const int r1 = std::min(r + k, P.rows), c1 = std::min(c + k, P.cols);
            for (int rr = r; rr < r1; ++rr)
              for (int cc = c; cc < c1; ++cc) {
                occluded_mask_.at<uint8_t>(rr, cc) = 1;
                per_row[static_cast<size_t>(br)] +=
                    std::isfinite(P.at<cv::Vec3f>(rr, cc)[2]) ? 1 : 0;
              }
          }
        }
      });
  for (int64_t n : per_row) last_occluded_ += n;
  occluded_ += last_occluded_;
}

// 1. Per pixel, once: what a voxel projecting there adds (the tests that depend on the pixel
// only, taken out of the voxel loop): its point, its normal turned toward the camera (NaN: no
// normal, the range difference is used), its weight (0: not fused: no point, occluded, quality
// below min_point_weight, or seen more grazing than max_incidence_deg).
void TsdfVolume::PreparePixels(const cv::Mat& P, const cv::Mat& N, const cv::Mat& Q,
                               const cv::Mat& S, bool test_occlusion) {
  const float cos_max = static_cast<float>(std::cos(o_.max_incidence_deg * M_PI / 180.0));
  auto occluded = [&](int r, int c) {
    return test_occlusion && occluded_mask_.at<uint8_t>(r, c) != 0;
  };
  fuse_pixels_.resize(static_cast<size_t>(P.rows) * static_cast<size_t>(P.cols));
  tbb::parallel_for(tbb::blocked_range<int>(0, P.rows), [&](const tbb::blocked_range<int>& rows) {
    for (int r = rows.begin(); r < rows.end(); ++r) {
      const cv::Vec3f* p = P.ptr<cv::Vec3f>(r);
      const cv::Vec3f* n = N.ptr<cv::Vec3f>(r);
      const float* q = Q.empty() ? nullptr : Q.ptr<float>(r);
      const uint8_t* sec = S.empty() ? nullptr : S.ptr<uint8_t>(r);
      FusePixel* out = &fuse_pixels_[static_cast<size_t>(r) * static_cast<size_t>(P.cols)];
      for (int c = 0; c < P.cols; ++c) {
        FusePixel& f = out[c];
        f.weight = 0.0f;
        f.secondary = sec != nullptr && sec[c] != 0;
        const float w = q ? q[c] : 1.0f;
        if (!std::isfinite(p[c][0]) || !std::isfinite(p[c][2]) || occluded(r, c) ||
            !(w >= o_.min_point_weight))
          continue;
        const Eigen::Vector3f pt(p[c][0], p[c][1], p[c][2]);
        Eigen::Vector3f nt = Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN());
        if (std::isfinite(n[c][0]) && std::isfinite(n[c][2])) {
          nt = Eigen::Vector3f(n[c][0], n[c][1], n[c][2]);
          float cos_inc = -nt.dot(pt.normalized());
          if (cos_inc < 0) {
            nt = -nt;
            cos_inc = -cos_inc;
          }
          if (cos_inc < cos_max) continue;
        }
        f.point = pt;
        f.normal = nt;
        f.range = pt.norm();
        f.weight = w;
      }
    }
  });
}

// 2. Leaves near the view's points: collected in parallel (a set per worker thread), then
// allocated serially (topology changes). Their order does not matter: each voxel is written once
// per view, by the task that owns its leaf. The secondary grids get the leaves near the view's
// secondary points (a subset), and keep those where secondary bookkeeping remains (step 4).
std::vector<TsdfVolume::ViewLeaf> TsdfVolume::AllocateLeaves(const cv::Mat& P,
                                                             const Rigid3d& world_from_cam,
                                                             bool test_occlusion) {
  const double inv_voxel = 1.0 / o_.voxel_mm;
  const double band = o_.truncation_mm * inv_voxel + 1.0;
  auto occluded = [&](int r, int c) {
    return test_occlusion && occluded_mask_.at<uint8_t>(r, c) != 0;
  };
  const bool fade = o_.secondary_fade_weight > 0;
  using LeafSet = std::unordered_set<openvdb::Coord, CoordHash>;
  tbb::enumerable_thread_specific<LeafSet> leaves_per_thread, secondary_per_thread;
  tbb::parallel_for(
      tbb::blocked_range<int>(0, (P.rows + o_.pixel_stride - 1) / o_.pixel_stride),
      [&](const tbb::blocked_range<int>& strided_rows) {
        LeafSet& leaves = leaves_per_thread.local();
        LeafSet& secondary_leaves = secondary_per_thread.local();
        for (int br = strided_rows.begin(); br < strided_rows.end(); ++br) {
          const int r = br * o_.pixel_stride;
          const cv::Vec3f* p = P.ptr<cv::Vec3f>(r);
          const FusePixel* fp = &fuse_pixels_[static_cast<size_t>(r) * static_cast<size_t>(P.cols)];
          // Neighbouring pixels mostly touch the same leaves: insert only on a change.
          LeafRange last, last_secondary;
          for (int c = 0; c < P.cols; c += o_.pixel_stride) {
            if (!std::isfinite(p[c][0]) || !std::isfinite(p[c][2]) || occluded(r, c)) continue;
            const Eigen::Vector3d w = world_from_cam * Eigen::Vector3d(p[c][0], p[c][1], p[c][2]);
            const LeafRange range = LeavesWithin(w * inv_voxel, band);
            if (fade && fp[c].secondary && fp[c].weight > 0 && !(range == last_secondary)) {
              last_secondary = range;
              TouchLeaves(range, &secondary_leaves);
            }
            if (range == last) continue;
            last = range;
            TouchLeaves(range, &leaves);
          }
        }
      });
  auto merge = [](tbb::enumerable_thread_specific<LeafSet>& parts) {
    LeafSet all;
    for (LeafSet& part : parts) {
      if (all.empty())
        all.swap(part);
      else
        all.insert(part.begin(), part.end());
    }
    return all;
  };
  const LeafSet leaves = merge(leaves_per_thread);
  const LeafSet secondary_leaves = merge(secondary_per_thread);
  auto& ttree = impl_->tsdf->tree();
  auto& wtree = impl_->weight->tree();
  auto& sttree = impl_->secondary_tsdf->tree();
  auto& swtree = impl_->secondary_weight->tree();
  std::vector<ViewLeaf> nodes;
  nodes.reserve(leaves.size());
  for (const auto& o : leaves) {
    ViewLeaf n{ttree.touchLeaf(o), wtree.touchLeaf(o), nullptr, nullptr};
    if (secondary_leaves.count(o) != 0) {
      n.secondary_tsdf = sttree.touchLeaf(o);
      n.secondary_weight = swtree.touchLeaf(o);
    } else if (fade) {  // bookkeeping earlier views left here, if any
      n.secondary_tsdf = sttree.probeLeaf(o);
      n.secondary_weight = n.secondary_tsdf ? swtree.probeLeaf(o) : nullptr;
      if (n.secondary_weight == nullptr) n.secondary_tsdf = nullptr;
    }
    nodes.push_back(n);
  }
  return nodes;
}

// 3. Every voxel of the view's leaves, projectively (parallel over leaves: each leaf is one
// task's). Single precision: camera-frame coordinates are tens of mm, a voxel step 0.05 mm. Returns
// per leaf whether its secondary leaf still holds bookkeeping (W_s > 0 somewhere) after the view.
std::vector<uint8_t> TsdfVolume::FuseVoxels(const std::vector<ViewLeaf>& nodes,
                                            const PinholeBrownConrady& camera,
                                            const Rigid3d& world_from_cam, int cols, int rows) {
  VoxelPass v;
  const Rigid3d cam_from_world = world_from_cam.inverse();
  v.t = cam_from_world.translation();
  // Camera-frame step per index step along i, j, k: in double for each leaf's origin (indices in
  // the thousands), in float for the steps within a leaf.
  v.R_index = cam_from_world.linear() * o_.voxel_mm;
  const Eigen::Matrix3f R_voxel = v.R_index.cast<float>();
  v.trunc = static_cast<float>(o_.truncation_mm);
  v.maxw = o_.max_weight;
  v.fade_weight = o_.secondary_fade_weight;
  v.fade = o_.secondary_fade_weight > 0;
  // The camera's projection (PinholeBrownConrady::Project, inlined: it runs for every voxel of
  // every touched leaf, a row of 8 at a time).
  auto f = [](double x) { return static_cast<float>(x); };
  v.proj = {f(camera.fx), f(camera.fy), f(camera.cx), f(camera.cy),  f(camera.k1),  f(camera.k2),
            f(camera.k3), f(camera.p1), f(camera.p2), f(cols - 0.5), f(rows - 0.5), cols};
  v.pixels = fuse_pixels_.data();
  v.step_i = R_voxel.col(0);
  v.step_j = R_voxel.col(1);
  v.step_k = R_voxel.col(2);
  std::vector<uint8_t> secondary_left(nodes.size(), 0);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, nodes.size(), 16),
                    [&](const tbb::blocked_range<size_t>& range) {
                      for (size_t li = range.begin(); li < range.end(); ++li)
                        secondary_left[li] = FuseLeaf(nodes[li], v) ? 1 : 0;
                    });
  return secondary_left;
}

// 3, one leaf: adds the view to each of its voxels (rows of 8 along k projected at once). Returns
// whether its secondary leaf holds bookkeeping (W_s > 0 somewhere) afterwards.
bool TsdfVolume::FuseLeaf(const ViewLeaf& node, const VoxelPass& v) {
  const Eigen::Vector3f step_i = v.step_i, step_j = v.step_j, step_k = v.step_k;
  const ProjectionF& proj = v.proj;
  const FusePixel* pixels = v.pixels;
  const float trunc = v.trunc, maxw = v.maxw, fade_weight = v.fade_weight;
  const bool fade = v.fade;
  auto lambda = [fade_weight](float primary_weight) {
    return std::max(0.0f, 1.0f - primary_weight / fade_weight);
  };
  int32_t pixel[kLeafDim];
  Leaf* tl = node.tsdf;
  Leaf* wl = node.weight;
  const openvdb::Coord origin = tl->origin();
  const Eigen::Vector3f x_origin =
      (v.R_index * Eigen::Vector3d(origin.x(), origin.y(), origin.z()) + v.t).cast<float>();
  float* tdata = tl->buffer().data();
  float* wdata = wl->buffer().data();
  float* sdata = node.secondary_tsdf ? node.secondary_tsdf->buffer().data() : nullptr;
  float* swdata = node.secondary_weight ? node.secondary_weight->buffer().data() : nullptr;
  // Leaf offset = (i << 6) | (j << 3) | k (OpenVDB's LeafNode::coordToOffset): rows of 8 along k.
  for (int i = 0; i < kLeafDim; ++i) {
    for (int j = 0; j < kLeafDim; ++j) {
      const Eigen::Vector3f row =
          x_origin + static_cast<float>(i) * step_i + static_cast<float>(j) * step_j;
      ProjectRow(proj, row.data(), step_k.data(), pixel);
      const openvdb::Index row_off = static_cast<openvdb::Index>((i << 6) | (j << 3));
      for (int k = 0; k < kLeafDim; ++k) {
        if (pixel[k] < 0) continue;
        const FusePixel& px = pixels[pixel[k]];
        const float q = px.weight;
        if (q <= 0.0f) continue;
        const bool secondary = fade && px.secondary;
        if (secondary && swdata == nullptr) continue;  // beyond the leaves near its point: left out
        const Eigen::Vector3f x = row + static_cast<float>(k) * step_k;
        float sdf =
            std::isfinite(px.normal.x()) ? px.normal.dot(x - px.point) : px.range - x.norm();
        if (sdf < -trunc) continue;
        if (sdf > trunc) sdf = trunc;
        const openvdb::Index off = row_off + static_cast<openvdb::Index>(k);
        // A new leaf's buffers hold the grids' backgrounds (weight 0): W = 0 where nothing was
        // fused.
        const float W = wdata[off];
        const float D = W > 0 ? tdata[off] : 0.0f;
        const float Ws = swdata != nullptr ? swdata[off] : 0.0f;
        if (!secondary && Ws <= 0.0f) {  // no secondary points here: the plain running average
          const float Wn = W + q;
          tdata[off] = (D * W + sdf * q) / Wn;
          wdata[off] = std::min(Wn, maxw);
        } else {
          // Two channels (file comment): recover D_p from D' = (W_p·D_p + λ·W_s·D_s)/(W_p + λ·W_s),
          // add the measurement to its channel, blend again; a voxel whose λ reaches 0 keeps D_p
          // only.
          float Wp = std::max(0.0f, W - Ws);
          if (secondary && Wp >= fade_weight) continue;  // λ = 0: the primary points' surface
          const float Ds = Ws > 0 ? sdata[off] : 0.0f;
          const float l0 = lambda(Wp);
          float Dp = Wp > 0 ? ((Wp + l0 * Ws) * D - l0 * Ws * Ds) / Wp : 0.0f;
          float Dsn = Ds, Wsn = Ws;
          if (secondary) {
            Wsn = Ws + q;
            Dsn = (Ds * Ws + sdf * q) / Wsn;
          } else {
            Dp = (Dp * Wp + sdf * q) / (Wp + q);
            Wp += q;
          }
          const float l1 = lambda(Wp);
          if (l1 <= 0.0f) {
            tdata[off] = Dp;
            wdata[off] = std::min(Wp, maxw);
            Wsn = 0.0f;
            Dsn = trunc;
          } else {
            tdata[off] = (Wp * Dp + l1 * Wsn * Dsn) / (Wp + l1 * Wsn);
            wdata[off] = std::min(Wp + Wsn, maxw);
          }
          sdata[off] = Dsn;
          swdata[off] = Wsn;
        }
        tl->setValueOn(off);
        wl->setValueOn(off);
      }
    }
  }
  return swdata != nullptr &&
         std::any_of(swdata, swdata + Leaf::SIZE, [](float w) { return w > 0.0f; });
}

// 4. Secondary leaves without bookkeeping left go (they hold only backgrounds): the secondary
// grids stay as sparse as the surface that only secondary points (or weak primary ones) saw.
void TsdfVolume::FreeSecondaryLeaves(const std::vector<ViewLeaf>& nodes,
                                     const std::vector<uint8_t>& secondary_left) {
  auto& sttree = impl_->secondary_tsdf->tree();
  auto& swtree = impl_->secondary_weight->tree();
  for (size_t li = 0; li < nodes.size(); ++li)
    if (nodes[li].secondary_weight != nullptr && !secondary_left[li]) {
      const openvdb::Coord o = nodes[li].tsdf->origin();
      sttree.addTile(1, o, sttree.background(), false);
      swtree.addTile(1, o, swtree.background(), false);
    }
}

void TsdfVolume::IntegratePoints(const std::vector<Eigen::Vector3f>& points,
                                 const std::vector<Eigen::Vector3f>& normals,
                                 const std::vector<float>& weights) {
  D3D_CHECK_MSG(normals.size() == points.size(), "IntegratePoints: a normal per point");
  D3D_CHECK_MSG(weights.empty() || weights.size() == points.size(),
                "IntegratePoints: weights empty or one per point");
  const double inv_voxel = 1.0 / o_.voxel_mm;
  const int band = static_cast<int>(std::ceil(o_.truncation_mm * inv_voxel));
  const float trunc = static_cast<float>(o_.truncation_mm);
  openvdb::FloatGrid::Accessor ta = impl_->tsdf->getAccessor();
  openvdb::FloatGrid::Accessor wa = impl_->weight->getAccessor();
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3d p = points[i].cast<double>();
    const Eigen::Vector3d n = normals[i].cast<double>().normalized();
    const float q = weights.empty() ? 1.0f : weights[i];
    if (!(q >= o_.min_point_weight)) continue;
    // Voxels within half a voxel of the point's normal line, ±truncation.
    const Eigen::Vector3d c = p * inv_voxel;
    for (int dx = -band; dx <= band; ++dx)
      for (int dy = -band; dy <= band; ++dy)
        for (int dz = -band; dz <= band; ++dz) {
          const openvdb::Coord ijk(static_cast<int>(std::lround(c.x())) + dx,
                                   static_cast<int>(std::lround(c.y())) + dy,
                                   static_cast<int>(std::lround(c.z())) + dz);
          const Eigen::Vector3d x = Eigen::Vector3d(ijk.x(), ijk.y(), ijk.z()) * o_.voxel_mm;
          const Eigen::Vector3d d = x - p;
          const double along = n.dot(d);
          if ((d - along * n).norm() > 0.5 * o_.voxel_mm || std::abs(along) > o_.truncation_mm)
            continue;
          const float sdf = std::clamp(static_cast<float>(along), -trunc, trunc);
          const float W = wa.getValue(ijk);
          const float D = W > 0 ? ta.getValue(ijk) : 0.0f;
          ta.setValue(ijk, (D * W + sdf * q) / (W + q));
          wa.setValue(ijk, std::min(W + q, o_.max_weight));
        }
  }
  ++views_;
}

TriangleMesh TsdfVolume::ExtractMesh(float min_weight) const {
  if (min_weight < 0) min_weight = o_.min_mesh_weight;
  std::vector<openvdb::Vec3s> pts;
  std::vector<openvdb::Vec3I> tris;
  std::vector<openvdb::Vec4I> quads;
  openvdb::tools::volumeToMesh(*impl_->tsdf, pts, tris, quads, 0.0, 0.0, true);
  TriangleMesh mesh;
  // A vertex's weight: the least of the 8 voxel centres around it. Kept when ≥ min_weight.
  // A vertex whose corners span more signed distance than a distance field can (see the
  // options) gets weight 0: it is not kept and seeds nothing.
  std::vector<float> vertex_weight(pts.size(), 0.0f);
  const auto wacc = impl_->weight->getConstAccessor();
  const auto dacc = impl_->tsdf->getConstAccessor();
  const double inv_voxel = 1.0 / o_.voxel_mm;
  const float max_span =
      o_.max_cell_sdf_span > 0
          ? static_cast<float>(o_.max_cell_sdf_span * std::sqrt(3.0) * o_.voxel_mm)
          : std::numeric_limits<float>::max();
  for (size_t i = 0; i < pts.size(); ++i) {
    const int x = static_cast<int>(std::floor(pts[i].x() * inv_voxel)),
              y = static_cast<int>(std::floor(pts[i].y() * inv_voxel)),
              z = static_cast<int>(std::floor(pts[i].z() * inv_voxel));
    float w = std::numeric_limits<float>::max(), dmin = w, dmax = -w;
    for (int k = 0; k < 8 && w >= min_weight; ++k) {
      const openvdb::Coord c(x + (k & 1), y + ((k >> 1) & 1), z + ((k >> 2) & 1));
      w = std::min(w, wacc.getValue(c));
      const float d = dacc.getValue(c);
      dmin = std::min(dmin, d);
      dmax = std::max(dmax, d);
    }
    vertex_weight[i] = w >= min_weight && dmax - dmin > max_span ? 0.0f : w;
  }
  // Kept polygons as triangles (OpenVDB's indices), reversed: OpenVDB orients polygons with
  // normals toward the inside (negative) of the level set; we want them toward the front
  // (positive, the camera side).
  auto kept = [&](openvdb::Index i) { return vertex_weight[i] >= min_weight; };
  std::vector<std::array<openvdb::Index, 3>> faces;
  faces.reserve(tris.size() + 2 * quads.size());
  for (const auto& t : tris)
    if (kept(t[0]) && kept(t[1]) && kept(t[2])) faces.push_back({t[0], t[2], t[1]});
  for (const auto& q : quads)
    if (kept(q[0]) && kept(q[1]) && kept(q[2]) && kept(q[3])) {
      faces.push_back({q[0], q[2], q[1]});
      faces.push_back({q[0], q[3], q[2]});
    }
  // Hysteresis: connected pieces (union–find over the kept faces' vertices) without a seed vertex
  // go.
  std::vector<uint8_t> piece_seeded;
  std::vector<openvdb::Index> parent;
  const bool hysteresis = o_.mesh_seed_weight > min_weight;
  auto find = [&](openvdb::Index i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  };
  if (hysteresis) {
    parent.resize(pts.size());
    for (size_t i = 0; i < pts.size(); ++i) parent[i] = static_cast<openvdb::Index>(i);
    for (const auto& f : faces)
      for (int e = 1; e < 3; ++e) {
        const openvdb::Index a = find(f[0]), b = find(f[static_cast<size_t>(e)]);
        if (a != b) parent[std::max(a, b)] = std::min(a, b);
      }
    piece_seeded.assign(pts.size(), 0);
    for (size_t i = 0; i < pts.size(); ++i)
      if (vertex_weight[i] >= o_.mesh_seed_weight)
        piece_seeded[find(static_cast<openvdb::Index>(i))] = 1;
  }
  std::vector<int> remap(pts.size(), -1);
  auto vid = [&](openvdb::Index i) {
    if (remap[i] < 0) {
      remap[i] = static_cast<int>(mesh.vertices.size());
      mesh.vertices.emplace_back(pts[i].x(), pts[i].y(), pts[i].z());
    }
    return remap[i];
  };
  for (const auto& f : faces) {
    if (hysteresis && !piece_seeded[find(f[0])]) continue;
    const int a = vid(f[0]), b = vid(f[1]), c = vid(f[2]);
    mesh.faces.emplace_back(a, b, c);
  }
  return mesh;
}

float TsdfVolume::SignedDistance(const Eigen::Vector3d& p) const {
  openvdb::tools::GridSampler<openvdb::FloatGrid, openvdb::tools::BoxSampler> s(*impl_->tsdf);
  return s.wsSample(openvdb::Vec3d(p.x(), p.y(), p.z()));
}

float TsdfVolume::Weight(const Eigen::Vector3d& p) const {
  openvdb::tools::GridSampler<openvdb::FloatGrid, openvdb::tools::BoxSampler> s(*impl_->weight);
  return s.wsSample(openvdb::Vec3d(p.x(), p.y(), p.z()));
}

int64_t TsdfVolume::ActiveVoxels() const {
  return static_cast<int64_t>(impl_->tsdf->activeVoxelCount());
}

int64_t TsdfVolume::SecondaryLeaves() const {
  return static_cast<int64_t>(impl_->secondary_weight->tree().leafCount());
}

int64_t TsdfVolume::MemoryBytes() const {
  return static_cast<int64_t>(impl_->tsdf->memUsage() + impl_->weight->memUsage() +
                              impl_->secondary_tsdf->memUsage() +
                              impl_->secondary_weight->memUsage());
}

}  // namespace d3d
