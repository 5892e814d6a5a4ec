#include "host/app/gap_bridge.h"

#include <algorithm>
#include <cstdio>
#include <limits>
#include <stdexcept>

#include "pipeline/recon/reconstruct.h"

namespace d3d {

BurstRing::BurstRing(size_t capacity, int width, int height, int frames, int bin) : bin_(bin) {
  if (capacity < 1 || width < 1 || height < 1 || frames < 1 || bin < 1 || width % bin != 0 ||
      height % bin != 0)
    throw std::invalid_argument(
        "BurstRing: capacity, width, height, frames and bin must be >= 1, the size divisible by "
        "bin");
  slots_.resize(capacity);
  for (IngestedBurst& s : slots_) {
    s.frames.resize(static_cast<size_t>(frames));
    for (cv::Mat& f : s.frames) f.create(height / bin, width / bin, CV_8U);
  }
}

void BurstRing::Put(const IngestedBurst& b) {
  std::lock_guard<std::mutex> lock(mu_);
  IngestedBurst& s = slots_[next_];
  s.frames.resize(b.frames.size());
  for (size_t i = 0; i < b.frames.size(); ++i) {
    // Same size and type as the slot's: no allocation.
    const bool ok = bin_ == 1 ? (b.frames[i].copyTo(s.frames[i]), true)
                              : BinFrame(b.frames[i], bin_, &s.frames[i]).ok();
    if (!ok) {
      // Not kept; the slot (the oldest burst, now overwritten in part) is no burst any more.
      s.capture_ns = std::numeric_limits<int64_t>::min();
      return;
    }
  }
  s.burst_seq = b.burst_seq;
  s.capture_ns = b.capture_ns;
  s.receive_ns = b.receive_ns;
  next_ = (next_ + 1) % slots_.size();
  size_ = std::min(size_ + 1, slots_.size());
}

bool BurstRing::TakeNearest(int64_t after_ns, int64_t before_ns, int64_t target_ns,
                            const std::vector<uint64_t>& exclude, IngestedBurst* out) const {
  std::lock_guard<std::mutex> lock(mu_);
  const IngestedBurst* best = nullptr;
  int64_t best_d = std::numeric_limits<int64_t>::max();
  for (size_t i = 0; i < size_; ++i) {
    const IngestedBurst& s = slots_[i];
    if (s.capture_ns <= after_ns || s.capture_ns >= before_ns) continue;
    if (std::find(exclude.begin(), exclude.end(), s.burst_seq) != exclude.end()) continue;
    const int64_t d =
        s.capture_ns > target_ns ? s.capture_ns - target_ns : target_ns - s.capture_ns;
    if (d < best_d || (d == best_d && best != nullptr && s.capture_ns > best->capture_ns)) {
      best = &s;
      best_d = d;
    }
  }
  if (best == nullptr) return false;
  out->burst_seq = best->burst_seq;
  out->capture_ns = best->capture_ns;
  out->receive_ns = best->receive_ns;
  out->frames.resize(best->frames.size());
  for (size_t i = 0; i < best->frames.size(); ++i) best->frames[i].copyTo(out->frames[i]);
  return true;
}

size_t BurstRing::size() const {
  std::lock_guard<std::mutex> lock(mu_);
  return size_;
}

void GapBridgeOptions::Check() const {
  if (ring_bursts < 0 || max_attempts < 1 || max_bursts < max_attempts || min_gap_ns < 0)
    throw std::invalid_argument(
        "GapBridgeOptions: ring_bursts >= 0, 1 <= max_attempts <= max_bursts, min_gap_ns >= 0");
}

GapBridge::GapBridge(const GapBridgeOptions& options, const BurstRing* ring,
                     const ProbeCalibration& view_calibration, const ReconstructOptions& recon)
    : o_(options), ring_(ring), recon_(view_calibration, recon, 1) {
  o_.Check();
  if (ring_ == nullptr) throw std::invalid_argument("GapBridge: no burst ring");
  skip_.reserve(static_cast<size_t>(o_.max_bursts));
}

void GapBridge::WarmUp() {
  const int w = recon_.calibration().camera.width, h = recon_.calibration().camera.height;
  burst_.frames.resize(4);
  for (cv::Mat& f : burst_.frames) f = cv::Mat::zeros(h, w, CV_8U);
  (void)recon_.Reconstruct(burst_.frames, &view_);  // dark: no points, every map allocated
}

bool BridgeApplies(const GapBridgeOptions& o, TrackingState state_before,
                   const TrackResult& refused, int64_t view_capture_ns, int64_t last_placed_ns) {
  const bool held =
      state_before == TrackingState::kTracking || state_before == TrackingState::kRelocalised;
  return o.ring_bursts > 0 && held && !refused.accepted && !refused.too_few_points &&
         last_placed_ns > 0 && view_capture_ns - last_placed_ns >= o.min_gap_ns;
}

bool GapBridge::Bridge(ScanRegistrar* registrar, int64_t last_placed_ns, int64_t view_capture_ns,
                       int64_t* placed_ns) {
  // The refused view's loss taken back: a burst from before it is tracked as if it had come first
  // (not for a view the tracker coasted: nothing to take back, no bridge).
  if (!registrar->RetractLoss()) return false;
  ++stats_.views;
  skip_.clear();
  const std::vector<ScanViewRecord>& views = registrar->views();
  for (auto v = views.rbegin(); v != views.rend() && !v->accepted; ++v)
    skip_.push_back(v->burst_seq);
  const int64_t gap = view_capture_ns - last_placed_ns;
  int64_t target = last_placed_ns + gap / 2;
  for (int fits = 0, bursts = 0; fits < o_.max_attempts && bursts < o_.max_bursts; ++bursts) {
    if (!ring_->TakeNearest(last_placed_ns, view_capture_ns, target, skip_, &burst_)) break;
    skip_.push_back(burst_.burst_seq);
    ++stats_.attempts;
    if (!recon_.Reconstruct(burst_.frames, &view_).ok()) continue;
    const TrackResult r =
        registrar->Register(view_, burst_.burst_seq, burst_.capture_ns, /*bridge=*/true);
    if (r.accepted) {
      ++stats_.placed;
      *placed_ns = burst_.capture_ns;
      return true;
    }
    // Too few points (the fast turn's motion blur, and no model anchoring while lost): its later
    // neighbour, a reconstruction's cost; a fit refused: one nearer the model.
    if (r.too_few_points) {
      target = burst_.capture_ns + 1;
    } else {
      ++fits;
      target = last_placed_ns + gap / 3;
    }
    (void)registrar->RetractLoss();  // the next one tracked as this one was
  }
  (void)registrar->ReinstateLoss();  // nothing placed: lost, as the refused view left the tracker
  return false;
}

}  // namespace d3d
