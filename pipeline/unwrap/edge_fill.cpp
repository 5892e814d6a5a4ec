#include "pipeline/unwrap/edge_fill.h"

#include <algorithm>
#include <cmath>

#include "pipeline/unwrap/quality_map.h"
#include "pipeline/unwrap/wrap_util.h"

namespace d3d {

void EdgeFillOptions::Check() const {
  D3D_CHECK_MSG(passes >= 0 && passes <= 64,
                "EdgeFillOptions: passes must be in [0, 64], got " << passes);
  D3D_CHECK_MSG(std::isfinite(max_modulation_ratio) && max_modulation_ratio > 1,
                "EdgeFillOptions: max_modulation_ratio must be > 1, got " << max_modulation_ratio);
  D3D_CHECK_MSG(std::isfinite(max_spread) && max_spread > 0,
                "EdgeFillOptions: max_spread must be > 0, got " << max_spread);
  D3D_CHECK_MSG(std::isfinite(quality_factor) && quality_factor > 0 && quality_factor <= 1,
                "EdgeFillOptions: quality_factor must be in (0, 1], got " << quality_factor);
}

EdgeFiller::EdgeFiller(const EdgeFillOptions& options, const UnwrapOptions& unwrap)
    : options_(options), unwrap_(unwrap) {
  options_.Check();
  unwrap_.Check();
}

Status EdgeFiller::Fill(const cv::Mat& phi, const cv::Mat& modulation, const cv::Mat& reason,
                        const cv::Mat& phase_min, const cv::Mat& phase_max, cv::Mat* Phi,
                        cv::Mat* order, cv::Mat* quality, EdgeFillStats* stats) {
  if (stats) *stats = EdgeFillStats{};
  if (!Phi || !order || !quality) return InvalidArgument("edge fill: null output");
  const cv::Size size = phi.size();
  auto same = [&](const cv::Mat& m, int type) { return m.size() == size && m.type() == type; };
  if (phi.empty() || !same(phi, CV_32F) || !same(modulation, CV_32F) || !same(reason, CV_8U) ||
      !same(*Phi, CV_32F) || !same(*order, CV_32S) || !same(*quality, CV_32F))
    return InvalidArgument(
        "edge fill: phi, modulation, Phi, quality must be H×W CV_32F, reason CV_8U, order CV_32S");
  const bool bounded = !phase_min.empty() || !phase_max.empty();
  if (bounded && (!same(phase_min, CV_32F) || !same(phase_max, CV_32F)))
    return InvalidArgument(
        "edge fill: phase_min / phase_max must both be H×W CV_32F or both empty");
  if (options_.passes == 0) return Status::Ok();

  const int w = size.width, h = size.height;
  const size_t n = static_cast<size_t>(w) * static_cast<size_t>(h);
  layer_.assign(n, 0);
  base_.resize(n);
  for (int y = 0; y < h; ++y) {
    const float* P = Phi->ptr<float>(y);
    const float* Q = quality->ptr<float>(y);
    for (int x = 0; x < w; ++x)
      base_[static_cast<size_t>(y) * w + x] = std::isfinite(P[x]) ? Q[x] : 0.0f;
  }
  const float ratio = static_cast<float>(options_.max_modulation_ratio);
  const float max_jump = static_cast<float>(unwrap_.max_jump),
              max_reverse = static_cast<float>(unwrap_.max_reverse);
  const float spread = static_cast<float>(options_.max_spread);
  const int mono = unwrap_.monotonic_x;
  const uint8_t kEdge = static_cast<uint8_t>(QualityReason::kModulationEdge);
  int64_t filled = 0;
  for (int pass = 1; pass <= options_.passes; ++pass) {
    added_.clear();
    added_phi_.clear();
    added_base_.clear();
    for (int y = 0; y < h; ++y) {
      const uint8_t* R = reason.ptr<uint8_t>(y);
      const float* P = Phi->ptr<float>(y);
      const float* ph = phi.ptr<float>(y);
      const float* B = modulation.ptr<float>(y);
      for (int x = 0; x < w; ++x) {
        if (R[x] != kEdge || std::isfinite(P[x]) || !std::isfinite(ph[x]) || !(B[x] > 0)) continue;
        // The 4 neighbours: dx, dy; a neighbour filled in this pass is not read (layers grow one
        // pixel per pass, independent of the scan order).
        static constexpr int kDx[4] = {1, -1, 0, 0}, kDy[4] = {0, 0, 1, -1};
        float lo = INFINITY, hi = -INFINITY, best_base = 0;
        int joined = 0;
        for (int d = 0; d < 4; ++d) {
          const int qx = x + kDx[d], qy = y + kDy[d];
          if (qx < 0 || qy < 0 || qx >= w || qy >= h) continue;
          const size_t qi = static_cast<size_t>(qy) * w + qx;
          const float Pq = Phi->at<float>(qy, qx);
          if (!std::isfinite(Pq) || layer_[qi] == pass) continue;
          const float Bq = modulation.at<float>(qy, qx);
          if (!(B[x] <= ratio * Bq && Bq <= ratio * B[x])) continue;
          const float dphi = internal::WrapPi(internal::WrapTo2Pi(ph[x]) -
                                              internal::WrapTo2Pi(phi.at<float>(qy, qx)));
          if (!(std::abs(dphi) <= max_jump)) continue;
          // Step along +x: Φ(right) − Φ(left); q right of p: −dphi, q left of p: dphi.
          if (mono != 0 && kDx[d] != 0 && mono * (kDx[d] > 0 ? -dphi : dphi) < -max_reverse)
            continue;
          const float pred = Pq + dphi;
          lo = std::min(lo, pred);
          hi = std::max(hi, pred);
          best_base = std::max(best_base, base_[qi]);
          ++joined;
        }
        if (joined == 0 || hi - lo > spread) continue;
        const float Pp = 0.5f * (lo + hi);
        if (bounded) {
          const float a = phase_min.at<float>(y, x), b = phase_max.at<float>(y, x);
          if (std::isfinite(a) && std::isfinite(b) && a <= b && (Pp < a || Pp > b)) continue;
        }
        added_.push_back(y * w + x);
        added_phi_.push_back(Pp);
        added_base_.push_back(best_base);
      }
    }
    if (added_.empty()) break;
    for (size_t i = 0; i < added_.size(); ++i) {
      const int y = added_[i] / w, x = added_[i] % w;
      Phi->at<float>(y, x) = added_phi_[i];
      order->at<int32_t>(y, x) =
          static_cast<int32_t>(std::floor(added_phi_[i] / internal::kTwoPiF));
      quality->at<float>(y, x) = options_.quality_factor * added_base_[i];
      layer_[static_cast<size_t>(added_[i])] = static_cast<uint8_t>(pass);
      base_[static_cast<size_t>(added_[i])] = added_base_[i];
    }
    filled += static_cast<int64_t>(added_.size());
  }
  if (stats) stats->pixels_filled = filled;
  return Status::Ok();
}

}  // namespace d3d
