#include "pipeline/chain/model_anchor.h"

#include <algorithm>
#include <chrono>
#include <climits>
#include <cmath>

#include "pipeline/register/icp.h"

namespace d3d {
namespace {
constexpr double kTwoPi = 2.0 * M_PI;
constexpr int kMaxCandidates = 64;  // offsets considered per group (the volume admits a handful)

struct Group {
  int begin = 0, end = 0;               // range in the sorted pixel list
  std::vector<int> candidates;          // offsets K
  std::vector<int> samples;             // pixel indices tested
  std::vector<Eigen::Vector3f> points;  // world points: candidates × samples, NaN where none
  std::vector<Eigen::Vector3f> rays;    // per sample: unit camera ray in the world frame
};
}  // namespace

void ModelAnchorOptions::Check() const {
  D3D_CHECK_MSG(min_pixels >= 1 && max_samples >= 10,
                "ModelAnchorOptions: min_pixels >= 1 and max_samples >= 10");
  D3D_CHECK_MSG(inlier_mm > 0 && inlier_mm <= gate_mm,
                "ModelAnchorOptions: need 0 < inlier_mm <= gate_mm");
  D3D_CHECK_MSG(min_inlier_share > 0 && min_inlier_share <= 1 && max_rival_share >= 0 &&
                    max_rival_share < min_inlier_share,
                "ModelAnchorOptions: need 0 <= max_rival_share < min_inlier_share <= 1");
  D3D_CHECK_MSG(min_admit_share > 0 && min_admit_share <= 1 && model_margin_mm >= 0,
                "ModelAnchorOptions: need 0 < min_admit_share <= 1 and model_margin_mm >= 0");
  D3D_CHECK_MSG(max_incidence_deg > 0 && max_incidence_deg < 90,
                "ModelAnchorOptions: need 0 < max_incidence_deg < 90");
}

ModelAnchorer::ModelAnchorer(const ProbeCalibration& calibration, const ModelAnchorOptions& options,
                             double normal_max_gap_mm)
    : options_(options), normal_max_gap_mm_(normal_max_gap_mm), triangulator_(calibration) {
  options_.Check();
  D3D_CHECK_MSG(normal_max_gap_mm > 0, "ModelAnchorer: normal_max_gap_mm must be positive");
  triangulator_.PhaseRange(&phase_min_, &phase_max_);
}

int64_t ModelAnchorer::Anchor(const PointMap& model, const Rigid3d& world_from_cam,
                              ReconstructedView* view, ModelAnchorStats* stats) {
  const auto t0 = std::chrono::steady_clock::now();
  ModelAnchorStats st;
  auto finish = [&](int64_t anchored) {
    st.pixels_anchored = anchored;
    st.ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    if (stats != nullptr) *stats = st;
    return anchored;
  };
  if (!options_.enabled || view == nullptr || model.empty()) return finish(0);
  UnwrapResult& u = view->unwrap;
  const cv::Size size = phase_min_.size();
  const cv::Mat& phi = view->phase.phi;
  if (u.region.size() != size || u.relative.size() != size || u.order.size() != size ||
      u.Phi.size() != size || phi.size() != size || view->points_in_cam.size() != size ||
      view->quality.size() != size || u.region.type() != CV_32SC1 ||
      u.relative.type() != CV_32SC1 || phi.type() != CV_32FC1)
    return finish(0);
  const int w = size.width, h = size.height;
  const int n_regions = static_cast<int>(u.regions.size());
  // Group key: the region for an unanchored region's pixels; n_regions + region for the dropped
  // pixels of an anchored one (neck pruning, outside the volume).
  auto key_of = [&](int i) -> int {
    const int rid = u.region.ptr<int32_t>()[i];
    if (rid < 0 || rid >= n_regions || u.order.ptr<int32_t>()[i] >= 0 ||
        u.relative.ptr<int32_t>()[i] == INT32_MIN || !std::isfinite(phi.ptr<float>()[i]) ||
        !(view->quality.ptr<float>()[i] > 0))
      return -1;
    return IsAnchored(u.regions[static_cast<size_t>(rid)].anchor) ? n_regions + rid : rid;
  };
  keys_.resize(static_cast<size_t>(w) * static_cast<size_t>(h));
  std::vector<int> count(static_cast<size_t>(2 * n_regions) + 1, 0);
  for (int i = 0; i < w * h; ++i) {
    const int k = key_of(i);
    keys_[static_cast<size_t>(i)] = k;
    if (k >= 0) ++count[static_cast<size_t>(k) + 1];
  }
  for (size_t k = 1; k < count.size(); ++k) count[k] += count[k - 1];
  std::vector<int> pixels(static_cast<size_t>(count.back()));
  {
    std::vector<int> next(count.begin(), count.end() - 1);
    for (int i = 0; i < w * h; ++i)
      if (const int k = keys_[static_cast<size_t>(i)]; k >= 0)
        pixels[static_cast<size_t>(next[static_cast<size_t>(k)]++)] = i;
  }
  const float* pmin = phase_min_.ptr<float>();
  const float* pmax = phase_max_.ptr<float>();
  const int32_t* rel = u.relative.ptr<int32_t>();
  const float* ph = phi.ptr<float>();
  const Eigen::Matrix3f R = world_from_cam.linear().cast<float>();
  const Eigen::Vector3f t = world_from_cam.translation().cast<float>();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::vector<Group> groups;
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(1e30f), hi = -lo;
  for (int key = 0; key < 2 * n_regions; ++key) {
    Group g;
    g.begin = count[static_cast<size_t>(key)];
    g.end = count[static_cast<size_t>(key) + 1];
    if (g.end - g.begin < options_.min_pixels) continue;
    // Candidate offsets: admissible (Φ within the pixel's [phase_min, phase_max]) at enough pixels.
    int kmin = INT_MAX, kmax = INT_MIN, bounded = 0;
    std::vector<std::pair<int, int>> range;
    range.reserve(static_cast<size_t>(g.end - g.begin));
    for (int j = g.begin; j < g.end; ++j) {
      const int i = pixels[static_cast<size_t>(j)];
      if (!std::isfinite(pmin[i]) || !std::isfinite(pmax[i])) continue;
      const int a = static_cast<int>(std::ceil((pmin[i] - ph[i]) / kTwoPi)) - rel[i];
      const int b = static_cast<int>(std::floor((pmax[i] - ph[i]) / kTwoPi)) - rel[i];
      ++bounded;
      if (a > b) continue;
      range.emplace_back(a, b);
      kmin = std::min(kmin, a);
      kmax = std::max(kmax, b);
    }
    if (range.empty() || kmax - kmin >= kMaxCandidates) continue;
    std::vector<int> admit(static_cast<size_t>(kmax - kmin + 2), 0);
    for (const auto& [a, b] : range) {
      ++admit[static_cast<size_t>(a - kmin)];
      --admit[static_cast<size_t>(b - kmin + 1)];
    }
    for (int K = kmin, run = 0; K <= kmax; ++K) {
      run += admit[static_cast<size_t>(K - kmin)];
      if (run >= options_.min_admit_share * bounded) g.candidates.push_back(K);
    }
    if (g.candidates.empty()) continue;
    const int n = g.end - g.begin;
    const int step = std::max(1, n / options_.max_samples);
    for (int j = g.begin; j < g.end && static_cast<int>(g.samples.size()) < options_.max_samples;
         j += step)
      g.samples.push_back(pixels[static_cast<size_t>(j)]);
    g.points.resize(g.candidates.size() * g.samples.size());
    g.rays.assign(g.samples.size(), Eigen::Vector3f::Zero());
    for (size_t c = 0; c < g.candidates.size(); ++c)
      for (size_t s = 0; s < g.samples.size(); ++s) {
        const int i = g.samples[s];
        const int k = rel[i] + g.candidates[c];
        Eigen::Vector3f& out = g.points[c * g.samples.size() + s];
        out = Eigen::Vector3f::Constant(nan);
        if (k < 0) continue;
        const Eigen::Vector3d p = triangulator_.PointForPhase(i % w, i / w, ph[i] + kTwoPi * k);
        if (!p.allFinite()) continue;
        out = R * p.cast<float>() + t;
        g.rays[s] = (R * p.cast<float>()).normalized();
        lo = lo.cwiseMin(out);
        hi = hi.cwiseMax(out);
      }
    ++st.groups_tested;
    groups.push_back(std::move(g));
  }
  if (groups.empty() || !(lo.x() <= hi.x())) return finish(0);
  const Eigen::Vector3f margin =
      Eigen::Vector3f::Constant(static_cast<float>(options_.model_margin_mm));
  model.Gather(lo - margin, hi + margin, &near_samples_);
  if (near_samples_.size() < 10 || near_samples_.normals.size() != near_samples_.points.size())
    return finish(0);
  near_.Build(near_samples_, {options_.gate_mm});
  const GridTarget& target = near_;
  const float gate = static_cast<float>(options_.gate_mm),
              inlier = static_cast<float>(options_.inlier_mm);
  const float min_cos = static_cast<float>(std::cos(options_.max_incidence_deg * M_PI / 180.0));
  // A point the model confirms: a model sample within the gate whose tangent plane is within
  // inlier_mm, facing the camera at most max_incidence_deg from its ray (model normals face the
  // cameras that saw them). A wrong K moves the point along its ray by whole fringe orders: on a
  // wall nearly parallel to the ray that move stays on the wall, and two or three orders back it
  // can land on the far side of the tooth the ray went through (seen on the real arch, 4 mm
  // behind); such matches cannot tell K apart and do not count.
  auto Verified = [&](const Eigen::Vector3f& p, const Eigen::Vector3f& ray_in_world) {
    Eigen::Vector3f q, nq;
    return target.Find(p, gate, &q, &nq) && std::abs(nq.dot(p - q)) <= inlier &&
           -nq.dot(ray_in_world) >= min_cos;
  };
  // A pixel's own check at order k: its point confirmed by the model, and not also one order nearer
  // or farther (where the model holds two surfaces along the ray, the pixel cannot tell which one
  // it sees). A part of a group beyond a hidden order jump inside it (why many such regions were
  // rejected) lies a fringe order away from anything the model holds and fails the first test.
  // The pixel's point at order k, within its admissible range and the measurement volume.
  auto point_at = [&](int i, int k, Eigen::Vector3d* p) {
    const double value = ph[i] + kTwoPi * k;
    if (k < 0 ||
        (std::isfinite(pmin[i]) && std::isfinite(pmax[i]) && (value < pmin[i] || value > pmax[i])))
      return false;
    *p = triangulator_.PointForPhase(i % w, i / w, value);
    return p->allFinite();
  };
  auto confirm = [&](int i, int k, const Eigen::Vector3d& p) {
    const Eigen::Vector3f ray = (R * p.cast<float>()).normalized();
    if (!Verified(R * p.cast<float>() + t, ray)) return false;
    for (const int dk : {-1, 1}) {
      if (k + dk < 0) continue;
      const Eigen::Vector3d p2 =
          triangulator_.PointForPhase(i % w, i / w, ph[i] + kTwoPi * (k + dk));
      if (p2.allFinite() && Verified(R * p2.cast<float>() + t, ray)) return false;
    }
    return true;
  };
  // The check runs on the 2 × 2 lattice: a pixel takes the verdict of its block's corner pixel when
  // that is in the same group (the parts the check separates are far larger than a block), else
  // its own. 4× fewer model look-ups.
  verdict_.assign(keys_.size(), -1);
  changed_.clear();
  int64_t anchored = 0;
  for (const Group& g : groups) {
    const size_t ns = g.samples.size();
    double best = -1, rival = 0;
    int best_k = 0;
    for (size_t c = 0; c < g.candidates.size(); ++c) {
      int inliers = 0;
      for (size_t s = 0; s < ns; ++s) {
        const Eigen::Vector3f& p = g.points[c * ns + s];
        if (!p.allFinite()) continue;
        if (Verified(p, g.rays[s])) ++inliers;
      }
      const double share = static_cast<double>(inliers) / static_cast<double>(ns);
      if (share > best) {
        rival = std::max(rival, best);
        best = share;
        best_k = g.candidates[c];
      } else {
        rival = std::max(rival, share);
      }
    }
    if (best < options_.min_inlier_share || rival > options_.max_rival_share) continue;
    ++st.groups_anchored;
    const int key = keys_[static_cast<size_t>(pixels[static_cast<size_t>(g.begin)])];
    for (int j = g.begin; j < g.end; ++j) {
      const int i = pixels[static_cast<size_t>(j)];
      const int k = rel[i] + best_k;
      Eigen::Vector3d p;
      if (!point_at(i, k, &p)) continue;
      const int corner = ((i / w) & ~1) * w + ((i % w) & ~1);
      if (corner != i && keys_[static_cast<size_t>(corner)] == key) {
        int8_t& v = verdict_[static_cast<size_t>(corner)];
        if (v < 0) {
          const int kc = rel[corner] + best_k;
          Eigen::Vector3d pc;
          v = point_at(corner, kc, &pc) && confirm(corner, kc, pc) ? 1 : 0;
        }
        if (v == 0) continue;
      } else if (!confirm(i, k, p)) {
        continue;
      }
      u.Phi.ptr<float>()[i] = static_cast<float>(ph[i] + kTwoPi * k);
      u.order.ptr<int32_t>()[i] = k;
      view->points_in_cam.ptr<cv::Vec3f>()[i] = cv::Vec3f(
          static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z()));
      changed_.push_back(i);
      ++anchored;
    }
  }
  if (anchored > 0) {
    UpdateOrganisedNormals(view->points_in_cam, normal_max_gap_mm_, changed_, &view->normals);
    view->points += anchored;
    u.stats.pixels_valid += anchored;
  }
  return finish(anchored);
}

}  // namespace d3d
