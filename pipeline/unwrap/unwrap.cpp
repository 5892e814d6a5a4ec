#include "pipeline/unwrap/unwrap.h"

#include <algorithm>
#include <climits>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "pipeline/unwrap/wrap_util.h"

namespace d3d {

void UnwrapOptions::Check() const {
  D3D_CHECK_MSG(marker_spacing_orders >= 0,
                "UnwrapOptions: marker_spacing_orders must be >= 0, got " << marker_spacing_orders);
  D3D_CHECK_MSG(std::abs(marker_first_order) < 10000,
                "UnwrapOptions: marker_first_order out of range: " << marker_first_order);
  D3D_CHECK_MSG(
      marker_width_periods > 0 && marker_width_periods <= 1,
      "UnwrapOptions: marker_width_periods must be in (0, 1], got " << marker_width_periods);
  D3D_CHECK_MSG(
      marker_edge_margin >= 0 && marker_edge_margin < M_PI * marker_width_periods,
      "UnwrapOptions: marker_edge_margin must be in [0, π·width), got " << marker_edge_margin);
  D3D_CHECK_MSG(marker_margin_below >= 0 && marker_margin_below <= 100 &&
                    marker_margin_above >= 0 && marker_margin_above <= 100,
                "UnwrapOptions: marker_margin_below/above must be in [0, 100], got "
                    << marker_margin_below << ", " << marker_margin_above);
  D3D_CHECK_MSG(marker_tile_px >= 4 && marker_tile_rival_votes >= 0 &&
                    marker_tile_rival_density > 0 && marker_tile_rival_density <= 1,
                "UnwrapOptions: marker_tile_px must be >= 4, marker_tile_rival_votes >= 0, "
                "marker_tile_rival_density in (0, 1]");
  D3D_CHECK_MSG(std::isfinite(min_quality) && min_quality > 0 && min_quality <= 1,
                "UnwrapOptions: min_quality must be in (0, 1], got " << min_quality);
  D3D_CHECK_MSG(std::isfinite(seed_quality) && seed_quality >= min_quality && seed_quality <= 1,
                "UnwrapOptions: seed_quality must be in [min_quality, 1], got " << seed_quality);
  D3D_CHECK_MSG(quality_levels >= 2 && quality_levels <= 255,
                "UnwrapOptions: quality_levels must be in [2, 255], got " << quality_levels);
  D3D_CHECK_MSG(max_jump > 0 && max_jump < M_PI,
                "UnwrapOptions: max_jump must be in (0, π), got " << max_jump);
  D3D_CHECK_MSG(monotonic_x >= -1 && monotonic_x <= 1,
                "UnwrapOptions: monotonic_x must be -1, 0 or 1, got " << monotonic_x);
  D3D_CHECK_MSG(max_reverse >= 0 && max_reverse <= max_jump,
                "UnwrapOptions: max_reverse must be in [0, max_jump], got " << max_reverse);
  D3D_CHECK_MSG(violation_phase > 0 && violation_phase < 2 * M_PI,
                "UnwrapOptions: violation_phase must be in (0, 2π), got " << violation_phase);
  D3D_CHECK_MSG(max_violations >= 0 && max_violation_share >= 0 && max_violation_share < 1,
                "UnwrapOptions: max_violations must be >= 0 and max_violation_share in [0, 1)");
  D3D_CHECK_MSG(min_region_pixels >= 1,
                "UnwrapOptions: min_region_pixels must be >= 1, got " << min_region_pixels);
  D3D_CHECK_MSG(min_marker_votes >= 1,
                "UnwrapOptions: min_marker_votes must be >= 1, got " << min_marker_votes);
  D3D_CHECK_MSG(
      marker_max_stripe_share > 0 && marker_max_stripe_share <= 1,
      "UnwrapOptions: marker_max_stripe_share must be in (0, 1], got " << marker_max_stripe_share);
  D3D_CHECK_MSG(marker_density > 0 && marker_density <= 1,
                "UnwrapOptions: marker_density must be in (0, 1], got " << marker_density);
  D3D_CHECK_MSG(marker_rival_votes >= 1,
                "UnwrapOptions: marker_rival_votes must be >= 1, got " << marker_rival_votes);
  D3D_CHECK_MSG(
      marker_rival_density > 0 && marker_rival_density <= 1,
      "UnwrapOptions: marker_rival_density must be in (0, 1], got " << marker_rival_density);
  D3D_CHECK_MSG(
      marker_depth_fraction >= 0 && marker_depth_fraction <= 1,
      "UnwrapOptions: marker_depth_fraction must be in [0, 1], got " << marker_depth_fraction);
  D3D_CHECK_MSG(depth_fraction > 0.5 && depth_fraction <= 1,
                "UnwrapOptions: depth_fraction must be in (0.5, 1], got " << depth_fraction);
  D3D_CHECK_MSG(neck_radius >= 0 && neck_radius <= 8,
                "UnwrapOptions: neck_radius must be in [0, 8], got " << neck_radius);
  D3D_CHECK_MSG(std::isfinite(volume_margin) && volume_margin >= 0,
                "UnwrapOptions: volume_margin must be finite and >= 0, got " << volume_margin);
}

const char* RegionAnchorName(RegionAnchor anchor) {
  switch (anchor) {
    case RegionAnchor::kMarker:
      return "marker";
    case RegionAnchor::kDepth:
      return "depth";
    case RegionAnchor::kTooSmall:
      return "too-small";
    case RegionAnchor::kMarkerConflict:
      return "marker-conflict";
    case RegionAnchor::kAmbiguous:
      return "ambiguous";
    case RegionAnchor::kInconsistent:
      return "inconsistent";
  }
  return "?";
}

namespace {

constexpr int16_t kUnknown = INT16_MIN;  // klo_ value: no admissible range known
constexpr int16_t kNone = INT16_MIN;     // kstripe_ value: not a stripe candidate
constexpr int kOrderClamp = 30000;       // admissible orders are clamped to ±this (int16)

enum State : uint8_t {
  kFree = 0,
  kQueued = 1,
  kCurrent = 2,
  kDropped = 3,
  kMember = 4,
  kBarrier = 5
};

// Edge byte: bit 0 right joinable, bits 1-2 right step + 1, bit 3 down joinable, bits 4-5 down
// step + 1. step = k(neighbour) − k(this).
inline bool RightOk(uint8_t e) { return (e & 1u) != 0; }
inline int RightStep(uint8_t e) { return static_cast<int>((e >> 1) & 3u) - 1; }
inline bool DownOk(uint8_t e) { return (e & 8u) != 0; }
inline int DownStep(uint8_t e) { return static_cast<int>((e >> 4) & 3u) - 1; }
constexpr uint8_t kMarkerBit = 64u;

inline int16_t ClampOrder(double k) {
  return static_cast<int16_t>(
      std::clamp(k, static_cast<double>(-kOrderClamp), static_cast<double>(kOrderClamp)));
}

Status CheckInputs(const cv::Mat& phi, const cv::Mat& quality, const cv::Mat& marker,
                   const cv::Mat& phase_min, const cv::Mat& phase_max) {
  if (phi.empty()) return InvalidArgument("UnwrapPhase: phi is empty");
  if (phi.type() != CV_32FC1) return InvalidArgument("UnwrapPhase: phi must be CV_32FC1");
  auto size_str = [](const cv::Mat& m) {
    std::ostringstream os;
    os << m.cols << "x" << m.rows;
    return os.str();
  };
  if (quality.type() != CV_32FC1 || quality.size() != phi.size()) {
    return InvalidArgument("UnwrapPhase: quality must be CV_32FC1 of phi's size " + size_str(phi) +
                           ", got " + size_str(quality));
  }
  if (!marker.empty() && (marker.type() != CV_8UC1 || marker.size() != phi.size())) {
    return InvalidArgument("UnwrapPhase: marker must be empty or CV_8UC1 of phi's size " +
                           size_str(phi));
  }
  if (phase_min.empty() != phase_max.empty()) {
    return InvalidArgument(
        "UnwrapPhase: phase_min and phase_max must both be given or both be empty");
  }
  if (!phase_min.empty()) {
    for (const cv::Mat* m : {&phase_min, &phase_max}) {
      if (m->type() != CV_32FC1 || m->size() != phi.size()) {
        return InvalidArgument("UnwrapPhase: phase_min/phase_max must be CV_32FC1 of phi's size " +
                               size_str(phi) + ", got " + size_str(*m));
      }
    }
  }
  return Status::Ok();
}

}  // namespace

Unwrapper::Unwrapper(const UnwrapOptions& options) : options_(options) {
  options_.Check();
  head_.assign(static_cast<size_t>(options_.quality_levels) + 1, -1);
}

void Unwrapper::Prepare(const cv::Mat& phi, const cv::Mat& quality, const cv::Mat& marker,
                        const cv::Mat& phase_min, const cv::Mat& phase_max) {
  ResizeGrid(phi.cols, phi.rows);
  ReadPixels(phi, quality, marker, phase_min, phase_max);
  const float max_jump = static_cast<float>(options_.max_jump);
  // Admissible horizontal steps W(Δφ) ∈ [lo_x, hi_x] (the ordering constraint), vertical |W| ≤
  // max_jump.
  const float rev = static_cast<float>(options_.max_reverse);
  const float lo_x = options_.monotonic_x > 0 ? -rev : -max_jump;
  const float hi_x = options_.monotonic_x < 0 ? rev : max_jump;
  MarkReverseBarriers(lo_x, hi_x, max_jump);
  AddEdges(lo_x, hi_x, max_jump);
}

// Border pixels are unusable.
void Unwrapper::ClearPixel(size_t i) {
  phi_[i] = 0.0f;
  level_[i] = 0;
  edge_[i] = 0;
  state_[i] = kDropped;
  klo_[i] = kUnknown;
  khi_[i] = kUnknown;
  kstripe_[i] = kNone;
}

// The padded grid for a w×h image (buffers keep their capacity), its top and bottom border rows
// cleared.
void Unwrapper::ResizeGrid(int w, int h) {
  w_ = w;
  h_ = h;
  stride_ = w_ + 2;
  const size_t n = static_cast<size_t>(stride_) * static_cast<size_t>(h_ + 2);
  phi_.resize(n);
  level_.resize(n);
  edge_.resize(n);
  state_.resize(n);
  rel_.resize(n);
  next_.resize(n);
  region_.resize(n);
  klo_.resize(n);
  khi_.resize(n);
  kstripe_.resize(n);
  for (int x = 0; x < stride_; ++x) {
    ClearPixel(static_cast<size_t>(x));
    ClearPixel(static_cast<size_t>(h_ + 1) * stride_ + x);
  }
}

// Per pixel: wrapped phase, quality level, admissible orders [klo, khi], stripe order, marker bit
// (the left and right border columns cleared).
void Unwrapper::ReadPixels(const cv::Mat& phi, const cv::Mat& quality, const cv::Mat& marker,
                           const cv::Mat& phase_min, const cv::Mat& phase_max) {
  const int levels = options_.quality_levels;
  const float qmin = options_.min_quality;
  const bool bounds = !phase_min.empty();
  const bool has_marker = !marker.empty();
  const double margin = options_.volume_margin;
  const double inv_2pi = 1.0 / (2.0 * M_PI);
  const int first = options_.marker_first_order;
  const int spacing = options_.marker_spacing_orders;
  const int margin_below = options_.marker_margin_below,
            margin_above = options_.marker_margin_above;
  const float core_lo = static_cast<float>(M_PI * (1.0 - options_.marker_width_periods) +
                                           options_.marker_edge_margin);
  const float core_hi = static_cast<float>(M_PI * (1.0 + options_.marker_width_periods) -
                                           options_.marker_edge_margin);

  const float inv_2pi_f = static_cast<float>(inv_2pi);
  const float margin_f = static_cast<float>(margin);
  const float clampf = static_cast<float>(kOrderClamp);
  for (int y = 0; y < h_; ++y) {
    const float* p = phi.ptr<float>(y);
    const float* q = quality.ptr<float>(y);
    const uint8_t* mk = has_marker ? marker.ptr<uint8_t>(y) : nullptr;
    const float* pmin = bounds ? phase_min.ptr<float>(y) : nullptr;
    const float* pmax = bounds ? phase_max.ptr<float>(y) : nullptr;
    const size_t row = static_cast<size_t>(y + 1) * stride_ + 1;
    ClearPixel(row - 1);
    ClearPixel(row + w_);
    for (int x = 0; x < w_; ++x) {
      const size_t i = row + x;
      const float qv = q[x];
      const bool usable = std::isfinite(p[x]) && qv >= qmin;  // NaN quality fails the test
      if (!usable) {
        ClearPixel(i);
        continue;
      }
      const float ph = internal::WrapTo2Pi(p[x]);
      phi_[i] = ph;
      const int lv = 1 + std::min(levels - 1, static_cast<int>(std::min(qv, 1.0f) * levels));
      level_[i] = static_cast<uint8_t>(lv);
      state_[i] = kFree;
      int16_t lo = kUnknown, hi = kUnknown;
      if (bounds) {
        const float a = pmin[x], b = pmax[x];
        if (std::isfinite(a) && std::isfinite(b) && a <= b) {
          const float tl = std::clamp((a - margin_f - ph) * inv_2pi_f, -clampf, clampf);
          const float th = std::clamp((b + margin_f - ph) * inv_2pi_f, -clampf, clampf);
          lo = static_cast<int16_t>(std::ceil(tl));
          hi = static_cast<int16_t>(std::floor(th));
        }
      }
      klo_[i] = lo;
      khi_[i] = hi;
      int16_t stripe = kNone;
      if (ph >= core_lo && ph <= core_hi) {
        if (spacing == 0) {
          // One stripe: its order, if the range widened by the margin admits it (or is unknown).
          if (lo == kUnknown || (first >= lo - margin_below && first <= hi + margin_above))
            stripe = static_cast<int16_t>(first);
        } else if (lo != kUnknown && lo <= hi) {
          // Smallest stripe order in the widened window; it must be the only one in it.
          const int slo = lo - margin_below, shi = hi + margin_above;
          const int d = slo - first;
          const int j = d <= 0 ? 0 : (d + spacing - 1) / spacing;
          const int km = first + j * spacing;
          if (km <= shi && km + spacing > shi) stripe = static_cast<int16_t>(km);
        }
      }
      kstripe_[i] = stripe;
      edge_[i] = (mk != nullptr && mk[x] != 0) ? kMarkerBit : 0;  // edges are added below
    }
  }
}

// Both pixels of a horizontal step against the ordering constraint straddle a depth
// discontinuity: they leave the graph, so that the cut has no diagonal leaks.
void Unwrapper::MarkReverseBarriers(float lo_x, float hi_x, float max_jump) {
  barrier_ = 0;
  if (options_.monotonic_x != 0 && options_.reverse_barrier) {
    for (int y = 0; y < h_; ++y) {
      const int row = (y + 1) * stride_ + 1;
      for (int i = row; i < row + w_; ++i) {
        if (level_[i] == 0 || level_[i + 1] == 0) continue;
        const float wd = internal::WrapPi(phi_[i + 1] - phi_[i]);
        if (wd < lo_x || wd > hi_x) {
          if (!(std::fabs(wd) > max_jump)) {  // a reversed small step, not just a large one
            state_[i] = kBarrier;
            state_[i + 1] = kBarrier;
          }
        }
      }
    }
    for (int y = 0; y < h_; ++y) {
      const int row = (y + 1) * stride_ + 1;
      for (int i = row; i < row + w_; ++i) {
        if (state_[i] == kBarrier) {
          level_[i] = 0;
          ++barrier_;
        }
      }
    }
  }
}

// Edges between usable 4-neighbours.
void Unwrapper::AddEdges(float lo_x, float hi_x, float max_jump) {
  for (int y = 0; y < h_; ++y) {
    const size_t row = static_cast<size_t>(y + 1) * stride_ + 1;
    for (int x = 0; x < w_; ++x) {
      const size_t i = row + x;
      uint8_t e = edge_[i] & kMarkerBit;
      if (level_[i] != 0) {
        const size_t r = i + 1;
        if (level_[r] != 0) {
          const float d = phi_[r] - phi_[i];
          const float wd = internal::WrapPi(d);
          if (wd >= lo_x && wd <= hi_x) {
            e |= static_cast<uint8_t>(1u | ((internal::StepOrder(d) + 1) << 1));
          }
        }
        const size_t dn = i + stride_;
        if (level_[dn] != 0) {
          const float d = phi_[dn] - phi_[i];
          if (std::fabs(internal::WrapPi(d)) <= max_jump) {
            e |= static_cast<uint8_t>(8u | ((internal::StepOrder(d) + 1) << 4));
          }
        }
      }
      edge_[i] = e;
    }
  }
}

void Unwrapper::GrowRegion(int seed, UnwrapResult* out) {
  const int region_id = static_cast<int>(out->regions.size());
  out->regions.emplace_back();
  members_.clear();

  const int stride = stride_;
  uint8_t* state = state_.data();
  const uint8_t* edge = edge_.data();
  const uint8_t* level = level_.data();
  int32_t* rel = rel_.data();
  int32_t* next = next_.data();
  int32_t* head = head_.data();
  int top = 0;
  // Bucket queue: one intrusive LIFO list per quality level (head_[level] → next_[pixel] → ...).
  auto push = [&](int nb) {
    if (state[nb] == kFree) {
      state[nb] = kQueued;
      const int lv = level[nb];
      next[nb] = head[lv];
      head[lv] = nb;
      top = std::max(top, lv);
    }
  };
  auto accept = [&](int i, int r) {
    rel[i] = r;
    state[i] = kCurrent;
    members_.push_back(i);
    const uint8_t e = edge[i];
    if (RightOk(e)) push(i + 1);
    if (DownOk(e)) push(i + stride);
    if (RightOk(edge[i - 1])) push(i - 1);
    if (DownOk(edge[i - stride])) push(i - stride);
  };

  accept(seed, 0);
  for (;;) {
    while (top > 0 && head[top] < 0) --top;
    if (top == 0) break;
    const int i = head[top];
    head[top] = next[i];
    // Every unwrapped neighbour joined to i predicts its relative order; all must agree.
    int lo = INT_MAX, hi = INT_MIN;
    auto vote = [&](int nb, bool ok, int step) {
      const bool use = ok && state[nb] == kCurrent;
      const int r = rel[nb] + step;
      lo = use ? std::min(lo, r) : lo;
      hi = use ? std::max(hi, r) : hi;
    };
    const uint8_t e = edge[i];
    const uint8_t el = edge[i - 1];
    const uint8_t eu = edge[i - stride];
    vote(i - 1, RightOk(el), RightStep(el));
    vote(i + 1, RightOk(e), -RightStep(e));
    vote(i - stride, DownOk(eu), DownStep(eu));
    vote(i + stride, DownOk(e), -DownStep(e));
    if (lo != hi) {  // disagreement (or, never, no voter)
      state[i] = kDropped;
      ++conflicts_;
      continue;
    }
    accept(i, lo);
  }

  RegionInfo& info = out->regions.back();
  info.pixels = static_cast<int>(members_.size());
  for (int i : members_) {
    state[i] = kMember;
    region_[i] = region_id;
  }
  if (info.pixels < options_.min_region_pixels) {
    info.anchor = RegionAnchor::kTooSmall;
    return;
  }
  AnchorRegion(&info, region_id);
}

void Unwrapper::AnchorRegion(RegionInfo* info, int region_id) {
  // Pass 1: the span of offsets K any pixel could vote for, and the ordering violations: pairs of
  // horizontal neighbours in the region whose unwrapped step runs backwards (a discontinuity the
  // region grew around).
  int kspan_lo = INT_MAX, kspan_hi = INT_MIN;
  int violations = 0;
  const float two_pi = internal::kTwoPiF;
  const float viol = -static_cast<float>(options_.violation_phase);
  const float sign = static_cast<float>(options_.monotonic_x);
  for (int i : members_) {
    const int r = rel_[i];
    const int16_t lo = klo_[i];
    if (lo != kUnknown) {
      kspan_lo = std::min(kspan_lo, lo - r);
      kspan_hi = std::max(kspan_hi, khi_[i] - r);
    }
    const int16_t st = kstripe_[i];
    if (st != kNone) {
      kspan_lo = std::min(kspan_lo, st - r);
      kspan_hi = std::max(kspan_hi, st - r);
    }
    const int j = i + 1;
    if (state_[j] == kMember && region_[j] == region_id) {
      const float step = phi_[j] - phi_[i] + two_pi * static_cast<float>(rel_[j] - r);
      violations += sign * step < viol;
    }
  }
  info->violations = violations;
  if (options_.monotonic_x != 0 &&
      violations > std::max(static_cast<double>(options_.max_violations),
                            options_.max_violation_share * info->pixels)) {
    info->anchor = RegionAnchor::kInconsistent;
    return;
  }
  info->anchor = RegionAnchor::kAmbiguous;
  if (kspan_lo > kspan_hi) return;  // no bounds and no stripe candidates: nothing to anchor with
  const size_t span = static_cast<size_t>(kspan_hi - kspan_lo + 1);
  hist_.assign(span + 1, 0);
  predicted_.assign(span, 0);
  hits_.assign(span, 0);
  int bounded = 0;
  for (int i : members_) {
    const int r = rel_[i];
    const int16_t lo = klo_[i];
    if (lo != kUnknown) {
      ++bounded;
      const int16_t hi = khi_[i];
      if (lo <= hi) {
        ++hist_[static_cast<size_t>(lo - r - kspan_lo)];
        --hist_[static_cast<size_t>(hi - r - kspan_lo + 1)];
      }
    }
    const int16_t st = kstripe_[i];
    if (st != kNone) {
      const size_t k = static_cast<size_t>(st - r - kspan_lo);
      ++predicted_[k];
      hits_[k] += (edge_[i] & kMarkerBit) != 0;
    }
  }
  for (size_t k = 1; k < span; ++k) hist_[k] += hist_[k - 1];
  info->bounded_pixels = bounded;

  const size_t best =
      static_cast<size_t>(std::max_element(hits_.begin(), hits_.end()) - hits_.begin());
  if (hits_[best] >= options_.min_marker_votes) {
    info->offset = kspan_lo + static_cast<int>(best);
    info->marker_hits = hits_[best];
    info->marker_predicted = predicted_[best];
    info->admitting_pixels = hist_[best];
    bool rival = false;
    for (size_t k = 0; k < span; ++k) {
      if (k == best || hits_[k] < options_.marker_rival_votes) continue;
      if (hits_[k] >= options_.marker_rival_density * predicted_[k]) {
        rival = true;
        info->marker_rival_hits = std::max(info->marker_rival_hits, hits_[k]);
      }
    }
    // The same test within each tile (UnwrapOptions::marker_tile_rival_votes), only where the
    // winner's K is admissible (drop_outside_volume drops the rest whatever its order). Pixels
    // that neck pruning drops later do count: the part of a far patch that shows its stripe can
    // be cut off by a neck while the rest of the patch stays attached (real arch seed 2, burst
    // 778: 416 of 435 hits in one tile lie in the pruned piece).
    if (options_.marker_tile_rival_votes > 0) {
      const int tile = options_.marker_tile_px;
      const int tiles_x = (w_ + tile - 1) / tile, tiles = tiles_x * ((h_ + tile - 1) / tile);
      tile_predicted_.assign(static_cast<size_t>(tiles) * span, 0);
      tile_hits_.assign(tile_predicted_.size(), 0);
      for (int i : members_) {
        const int16_t st = kstripe_[i];
        if (st == kNone) continue;
        const int order = rel_[i] + info->offset;
        if (options_.drop_outside_volume && klo_[i] != kUnknown &&
            (order < klo_[i] || order > khi_[i]))
          continue;
        const int x = i % stride_ - 1, y = i / stride_ - 1;
        const size_t cell = static_cast<size_t>((y / tile) * tiles_x + x / tile) * span +
                            static_cast<size_t>(st - rel_[i] - kspan_lo);
        ++tile_predicted_[cell];
        tile_hits_[cell] += (edge_[i] & kMarkerBit) != 0;
      }
      for (size_t cell = 0; cell < tile_hits_.size(); ++cell) {
        const int32_t h = tile_hits_[cell];
        if (cell % span == best || h < options_.marker_tile_rival_votes ||
            h < options_.marker_tile_rival_density * tile_predicted_[cell])
          continue;
        rival = true;
        info->marker_rival_hits = std::max(info->marker_rival_hits, static_cast<int>(h));
      }
    }
    const bool dense = hits_[best] >= options_.marker_density * predicted_[best];
    const bool extends_beyond = predicted_[best] <= options_.marker_max_stripe_share * info->pixels;
    const bool depth_ok = bounded == 0 || hist_[best] >= options_.marker_depth_fraction * bounded;
    info->anchor = dense && !rival && depth_ok && extends_beyond ? RegionAnchor::kMarker
                                                                 : RegionAnchor::kMarkerConflict;
    return;
  }
  if (bounded < options_.min_region_pixels) return;  // kAmbiguous
  const double need = options_.depth_fraction * bounded;
  int candidates = 0;
  size_t pick = 0;
  for (size_t k = 0; k < span; ++k) {
    if (hist_[k] >= need) {
      ++candidates;
      pick = k;
    }
  }
  info->candidates = candidates;
  if (candidates == 1) {
    info->offset = kspan_lo + static_cast<int>(pick);
    info->admitting_pixels = hist_[pick];
    info->anchor = RegionAnchor::kDepth;
  }
}

void Unwrapper::PruneNecks(const UnwrapResult& out) {
  const size_t n = state_.size();
  const int stride = stride_;
  const int rho = options_.neck_radius;
  keep_.assign(n, 1);
  if (rho <= 0) return;
  lab_.assign(n, -1);
  bool any = false;
  for (size_t i = 0; i < n; ++i) {
    if (state_[i] != kMember) continue;
    const int rid = region_[i];
    if (out.regions[static_cast<size_t>(rid)].anchor != RegionAnchor::kMarker) continue;
    lab_[i] = rid;
    keep_[i] = 0;
    any = true;
  }
  if (!any) return;
  const int nb8[8] = {-1, 1, -stride, stride, -stride - 1, -stride + 1, stride - 1, stride + 1};
  // Erosion by rho (3×3 square, rho times) within a region: a pixel stays if its 8 neighbours carry
  // the same label. The padded border is −1, so indices stay in range for interior pixels.
  ero_ = lab_;
  tmp_.resize(n);
  const int first = stride + 1, last = static_cast<int>(n) - stride - 1;
  for (int it = 0; it < rho; ++it) {
    std::fill(tmp_.begin(), tmp_.end(), -1);
    for (int i = first; i < last; ++i) {
      const int l = ero_[i];
      if (l < 0) continue;
      bool ok = true;
      for (int d : nb8) ok = ok && ero_[i + d] == l;
      tmp_[i] = ok ? l : -1;
    }
    ero_.swap(tmp_);
  }
  // 8-connected parts of the eroded regions, each checked against the marker for its region's K.
  std::fill(tmp_.begin(), tmp_.end(), 0);  // visited
  const double density = options_.marker_density;
  const int votes = options_.min_marker_votes;
  for (int s = first; s < last; ++s) {
    if (ero_[s] < 0 || tmp_[s] != 0) continue;
    const int l = ero_[s];
    const int K = offsets_[static_cast<size_t>(l)];
    stack_.clear();
    stack_.push_back(s);
    tmp_[s] = 1;
    size_t head = 0;
    int hits = 0, predicted = 0;
    while (head < stack_.size()) {
      const int i = stack_[head++];
      const int16_t st = kstripe_[static_cast<size_t>(i)];
      if (st != kNone && st - rel_[static_cast<size_t>(i)] == K) {
        ++predicted;
        hits += (edge_[static_cast<size_t>(i)] & kMarkerBit) != 0;
      }
      for (int d : nb8) {
        const int j = i + d;
        if (ero_[j] == l && tmp_[j] == 0) {
          tmp_[j] = 1;
          stack_.push_back(j);
        }
      }
    }
    // Same test as AnchorRegion's: enough hits, dense, and the piece reaches beyond the stripe.
    if (hits >= votes && hits >= density * predicted &&
        predicted <= options_.marker_max_stripe_share * static_cast<double>(stack_.size())) {
      for (int i : stack_) keep_[static_cast<size_t>(i)] = 2;  // verified core
    }
  }
  // Grow the verified cores back by rho within their region.
  for (int it = 0; it < rho; ++it) {
    const uint8_t mark = static_cast<uint8_t>(3 + it);
    const uint8_t prev_lo = 2;
    for (int i = first; i < last; ++i) {
      if (keep_[i] != 0 || lab_[i] < 0) continue;
      for (int d : nb8) {
        const uint8_t k = keep_[i + d];
        if (k >= prev_lo && k < mark && lab_[i + d] == lab_[i]) {
          keep_[i] = mark;
          break;
        }
      }
    }
  }
}

Status Unwrapper::Run(const cv::Mat& phi, const cv::Mat& quality, const cv::Mat& marker,
                      const cv::Mat& phase_min, const cv::Mat& phase_max, UnwrapResult* out) {
  if (out == nullptr) return InvalidArgument("UnwrapPhase: out is null");
  D3D_RETURN_IF_ERROR(CheckInputs(phi, quality, marker, phase_min, phase_max));
  for (const cv::Mat* m : {&out->Phi, &out->order, &out->region, &out->relative}) {
    for (const cv::Mat* in : {&phi, &quality, &marker, &phase_min, &phase_max}) {
      if (m->data != nullptr && m->data == in->data) {
        return InvalidArgument("UnwrapPhase: an output aliases an input");
      }
    }
  }
  Prepare(phi, quality, marker, phase_min, phase_max);
  out->regions.clear();
  out->stats = UnwrapStats{};
  conflicts_ = 0;
  std::fill(head_.begin(), head_.end(), -1);

  // Seeds in raster order: first good pixels, then any usable one left.
  const float seed_q = options_.seed_quality;
  const int seed_level =
      1 + std::min(options_.quality_levels - 1, static_cast<int>(seed_q * options_.quality_levels));
  for (int pass = 0; pass < 2; ++pass) {
    const int need = pass == 0 ? seed_level : 1;
    for (int y = 0; y < h_; ++y) {
      const int row = (y + 1) * stride_ + 1;
      for (int i = row; i < row + w_; ++i) {
        if (state_[i] == kFree && level_[i] >= need) GrowRegion(i, out);
      }
    }
  }

  // Per-region offset, then one raster pass that writes every output pixel once.
  offsets_.resize(out->regions.size());
  UnwrapStats& st = out->stats;
  st.regions_total = static_cast<int>(out->regions.size());
  for (size_t r = 0; r < out->regions.size(); ++r) {
    const RegionInfo& info = out->regions[r];
    offsets_[r] = IsAnchored(info.anchor) ? info.offset : INT_MIN;
    switch (info.anchor) {
      case RegionAnchor::kMarker:
        ++st.regions_marker;
        break;
      case RegionAnchor::kDepth:
        ++st.regions_depth;
        break;
      case RegionAnchor::kTooSmall:
        ++st.regions_small;
        st.pixels_small += info.pixels;
        break;
      default:
        ++st.regions_rejected;
        st.pixels_rejected += info.pixels;
        break;
    }
  }
  PruneNecks(*out);
  out->Phi.create(h_, w_, CV_32FC1);
  out->order.create(h_, w_, CV_32SC1);
  out->region.create(h_, w_, CV_32SC1);
  out->relative.create(h_, w_, CV_32SC1);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float two_pi = internal::kTwoPiF;
  const bool drop_outside = options_.drop_outside_volume;
  int64_t usable = 0, valid = 0, outside = 0, neck = 0;
  for (int y = 0; y < h_; ++y) {
    float* Phi = out->Phi.ptr<float>(y);
    int32_t* ord = out->order.ptr<int32_t>(y);
    int32_t* reg = out->region.ptr<int32_t>(y);
    int32_t* relo = out->relative.ptr<int32_t>(y);
    const int row = (y + 1) * stride_ + 1;
    for (int x = 0; x < w_; ++x) {
      const int i = row + x;
      usable += level_[i] != 0;
      float value = nan;
      int32_t k = -1, rid = -1, rel = INT32_MIN;
      if (state_[i] == kMember) {
        rid = region_[i];
        rel = rel_[i];
        const int off = offsets_[rid];
        if (off != INT_MIN && keep_[i] == 0) {
          ++neck;
        } else if (off != INT_MIN) {
          const int kk = rel_[i] + off;
          const int16_t lo = klo_[i];
          if (drop_outside && lo != kUnknown && (kk < lo || kk > khi_[i])) {
            ++outside;
          } else {
            k = kk;
            value = phi_[i] + two_pi * static_cast<float>(kk);
            ++valid;
          }
        }
      }
      Phi[x] = value;
      ord[x] = k;
      reg[x] = rid;
      relo[x] = rel;
    }
  }
  st.pixels_usable = usable + barrier_;
  st.pixels_discontinuity = barrier_;
  st.pixels_valid = valid;
  st.pixels_outside = outside;
  st.pixels_neck = neck;
  st.pixels_conflict = conflicts_;
  st.pixels_dropped = usable + barrier_ - valid;
  return Status::Ok();
}

Status UnwrapPhase(const cv::Mat& phi, const cv::Mat& quality, const cv::Mat& marker,
                   const cv::Mat& phase_min, const cv::Mat& phase_max, const UnwrapOptions& options,
                   UnwrapResult* out) {
  try {
    options.Check();
  } catch (const std::invalid_argument& e) {
    return InvalidArgument(std::string("UnwrapPhase: ") + e.what());
  }
  Unwrapper unwrapper(options);
  return unwrapper.Run(phi, quality, marker, phase_min, phase_max, out);
}

}  // namespace d3d
