// The projector side of the probe: a DLP controller that shows pattern k of the loaded pattern set
// on a trigger. Real hardware (e.g. a DLPC over I²C for configuration and a GPIO trigger line) sits
// behind this interface; on our machines LoggingProjectorDriver stands in and logs what it would
// do.
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>

#include "calib/model/probe_calibration.h"
#include "common/core/status.h"

namespace d3d {

class ProjectorDriver {
 public:
  virtual ~ProjectorDriver() = default;
  virtual std::string model() const = 0;
  // Loads the pattern set (num_patterns frames of `spec`). UNAVAILABLE if the controller is absent.
  [[nodiscard]] virtual Status Configure(const FringePatternSpec& spec, int num_patterns) = 0;
  [[nodiscard]] virtual Status SetBrightness(double brightness_0_1) = 0;
  // Shows pattern `pattern_index` from t_ns on (ns, Unix epoch). `trigger_seq` counts triggers
  // since start; the camera latches the same counter with each frame (the strobe line), which is
  // how frames are paired with patterns (frame_sync.h).
  [[nodiscard]] virtual Status Trigger(int pattern_index, uint64_t trigger_seq, int64_t t_ns) = 0;
};

// Logs configuration changes and every `log_every`-th trigger to `log` (stderr by default; nullptr
// = silent) and counts triggers. Thread-compatible (one caller thread).
class LoggingProjectorDriver final : public ProjectorDriver {
 public:
  explicit LoggingProjectorDriver(std::FILE* log = stderr, uint64_t log_every = 300)
      : log_(log), log_every_(log_every) {}
  std::string model() const override { return "logging-stub (DLP controller not present)"; }
  [[nodiscard]] Status Configure(const FringePatternSpec& spec, int num_patterns) override;
  [[nodiscard]] Status SetBrightness(double brightness_0_1) override;
  [[nodiscard]] Status Trigger(int pattern_index, uint64_t trigger_seq, int64_t t_ns) override;
  uint64_t triggers() const { return triggers_; }
  double brightness() const { return brightness_; }
  int num_patterns() const { return num_patterns_; }

 private:
  std::FILE* log_;
  uint64_t log_every_;
  uint64_t triggers_ = 0;
  double brightness_ = 1.0;
  int num_patterns_ = 0;
};

}  // namespace d3d
