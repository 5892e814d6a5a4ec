#include "host/app/pace_monitor.h"

#include <algorithm>
#include <stdexcept>
#include <vector>

namespace d3d {

void PaceOptions::Check() const {
  if (!(window_s > 0) || !(hold_s >= 0))
    throw std::invalid_argument("PaceOptions: window_s > 0 and hold_s >= 0");
  if (!(max_kept_share > 0 && max_kept_share <= 1))
    throw std::invalid_argument("PaceOptions: max_kept_share in (0, 1]");
  if (!(min_step_mm >= 0) || min_views < 2 || min_lost_views < 1)
    throw std::invalid_argument(
        "PaceOptions: min_step_mm >= 0, min_views >= 2 and min_lost_views >= 1");
}

PaceMonitor::PaceMonitor(const PaceOptions& options) : o_(options) { o_.Check(); }

void PaceMonitor::Reset() {
  window_.clear();
  advising_ = false;
  kept_share_ = 1.0;
  step_mm_ = 0.0;
  lost_views_ = 0;
}

bool PaceMonitor::Add(uint64_t burst_seq, int64_t capture_ns, const Rigid3d* world_from_cam,
                      bool lost) {
  // A probe that restarted its numbering (or time) starts the window again.
  if (!window_.empty() &&
      (burst_seq <= window_.back().burst_seq || capture_ns < window_.back().capture_ns))
    window_.clear();
  window_.push_back({burst_seq, capture_ns, world_from_cam != nullptr,
                     lost && world_from_cam == nullptr,
                     world_from_cam ? *world_from_cam : Rigid3d::Identity()});
  const auto window_ns = static_cast<int64_t>(o_.window_s * 1e9);
  while (window_.size() > 1 && window_.front().capture_ns < capture_ns - window_ns)
    window_.pop_front();
  const size_t n = window_.size();
  const uint64_t sent = window_.back().burst_seq - window_.front().burst_seq + 1;
  kept_share_ = static_cast<double>(n) / static_cast<double>(sent);
  std::vector<double>& steps = steps_;
  steps.clear();
  for (size_t i = 1; i < n; ++i)
    if (window_[i - 1].tracked && window_[i].tracked)
      steps.push_back(TranslationDistanceMm(window_[i - 1].pose, window_[i].pose));
  step_mm_ = 0.0;
  if (!steps.empty()) {
    std::nth_element(steps.begin(), steps.begin() + static_cast<std::ptrdiff_t>(steps.size() / 2),
                     steps.end());
    step_mm_ = steps[steps.size() / 2];
  }
  lost_views_ = static_cast<int>(
      std::count_if(window_.begin(), window_.end(), [](const View& v) { return v.lost; }));
  const bool by_step = static_cast<int>(n) >= o_.min_views &&
                       static_cast<int>(steps.size()) + 1 >= o_.min_views &&
                       step_mm_ > o_.min_step_mm;
  const bool by_lost = lost_views_ >= o_.min_lost_views && 2 * static_cast<size_t>(lost_views_) > n;
  const bool rule = kept_share_ < o_.max_kept_share && (by_step || by_lost);
  if (rule && !advising_) {
    advising_ = true;
    ++advices_;
  }
  if (rule)
    advised_since_ns_ = capture_ns;  // held for hold_s after the rule last held
  else if (advising_ && capture_ns - advised_since_ns_ >= static_cast<int64_t>(o_.hold_s * 1e9))
    advising_ = false;
  return advising_;
}

}  // namespace d3d
