#include "common/core/progress.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>

namespace d3d {

ProgressBar::ProgressBar(std::string label, int64_t total, bool enabled)
    : label_(std::move(label)),
      total_(std::max<int64_t>(total, 1)),
      enabled_(enabled),
      tty_(isatty(fileno(stderr)) != 0),
      start_(std::chrono::steady_clock::now()) {}

ProgressBar::~ProgressBar() { Finish(); }

void ProgressBar::Update(int64_t done) {
  if (!enabled_ || finished_) return;
  const double f = std::clamp(static_cast<double>(done) / static_cast<double>(total_), 0.0, 1.0);
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  const double eta = f > 0 ? s * (1.0 - f) / f : 0.0;
  if (tty_) {
    constexpr int kWidth = 30;
    const int filled = static_cast<int>(f * kWidth);
    std::fprintf(stderr, "\r%s [%.*s%*s] %3d%% %lld/%lld  %.1fs, eta %.1fs", label_.c_str(), filled,
                 "##############################", kWidth - filled, "", static_cast<int>(f * 100),
                 static_cast<long long>(done), static_cast<long long>(total_), s, eta);
    std::fflush(stderr);
  } else {
    const int decile = static_cast<int>(f * 10);
    if (decile != last_decile_) {
      last_decile_ = decile;
      std::fprintf(stderr, "%s %3d%% (%lld/%lld, %.1fs)\n", label_.c_str(), decile * 10,
                   static_cast<long long>(done), static_cast<long long>(total_), s);
    }
  }
}

void ProgressBar::Finish() {
  if (!enabled_ || finished_) return;
  finished_ = true;
  if (tty_) std::fprintf(stderr, "\n");
}

}  // namespace d3d
