#include "firmware/probe/projector_driver.h"

namespace d3d {

Status LoggingProjectorDriver::Configure(const FringePatternSpec& spec, int num_patterns) {
  if (num_patterns < 1 || num_patterns > 8)
    return InvalidArgument("projector: 1..8 patterns, got " + std::to_string(num_patterns));
  num_patterns_ = num_patterns;
  if (log_)
    std::fprintf(log_, "projector[stub]: load pattern set '%s', %d frames, period %.2f px\n",
                 spec.name.c_str(), num_patterns, spec.fringe_period_px);
  return Status::Ok();
}

Status LoggingProjectorDriver::SetBrightness(double b) {
  if (!(b >= 0.0 && b <= 1.0))
    return InvalidArgument("projector brightness must be in [0, 1], got " + std::to_string(b));
  brightness_ = b;
  if (log_) std::fprintf(log_, "projector[stub]: brightness %.3f\n", b);
  return Status::Ok();
}

Status LoggingProjectorDriver::Trigger(int pattern_index, uint64_t trigger_seq, int64_t t_ns) {
  if (pattern_index < 0 || pattern_index >= num_patterns_)
    return InvalidArgument("projector: pattern " + std::to_string(pattern_index) + " not loaded");
  ++triggers_;
  if (log_ && log_every_ > 0 && triggers_ % log_every_ == 1)
    std::fprintf(log_, "projector[stub]: trigger #%llu pattern %d at %lld ns\n",
                 static_cast<unsigned long long>(trigger_seq), pattern_index,
                 static_cast<long long>(t_ns));
  return Status::Ok();
}

}  // namespace d3d
