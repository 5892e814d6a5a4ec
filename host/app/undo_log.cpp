#include "host/app/undo_log.h"

#include <algorithm>
#include <cstdio>
#include <limits>

namespace d3d {

bool UndoLog::Request() {
  if (!enabled_) return false;
  requests_.fetch_add(1);
  return true;
}

bool UndoLog::Record(const ScanRegistrar::UndoResult& u) {
  char text[160];
  if (u.ok)
    std::snprintf(text, sizeof text, "undid %.1f s: %lld views%s", u.seconds_undone,
                  static_cast<long long>(u.views_undone),
                  u.clamped ? " (as far back as undo reaches)" : "");
  else
    std::snprintf(text, sizeof text, "nothing undone: %s", u.reason.c_str());
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (u.ok) log_.push_back(u.first_view);
    message_ = text;
  }
  if (u.ok)
    views_undone_.fetch_add(static_cast<uint64_t>(u.views_undone));
  else
    refused_.fetch_add(1);
  done_.fetch_add(1);
  return u.ok;
}

int64_t UndoLog::Cut(uint64_t from_gen, uint64_t to_gen) const {
  std::lock_guard<std::mutex> lock(mu_);
  int64_t cut = std::numeric_limits<int64_t>::max();
  for (uint64_t g = from_gen; g < to_gen && g < log_.size(); ++g) cut = std::min(cut, log_[g]);
  return cut;
}

std::string UndoLog::LastMessage() const {
  std::lock_guard<std::mutex> lock(mu_);
  return message_;
}

}  // namespace d3d
