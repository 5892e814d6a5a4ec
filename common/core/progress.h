// A terminal progress bar for long tools (stderr; redraws in place when stderr is a TTY,
// otherwise prints a line every 10 %). Single-threaded: call Update from one thread.
#pragma once

#include <chrono>
#include <cstdint>
#include <string>

namespace d3d {

class ProgressBar {
 public:
  ProgressBar(std::string label, int64_t total, bool enabled = true);
  ~ProgressBar();
  void Update(int64_t done);
  void Finish();

 private:
  std::string label_;
  int64_t total_;
  bool enabled_;
  bool tty_;
  bool finished_ = false;
  int last_decile_ = -1;
  std::chrono::steady_clock::time_point start_;
};

}  // namespace d3d
