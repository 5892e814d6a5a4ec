#include "viewer/preview.h"

namespace d3d {

const char* PreviewCueText(PreviewCue c) {
  switch (c) {
    case PreviewCue::kWaiting:
      return "WAITING FOR PROBE";
    case PreviewCue::kTracking:
      return "TRACKING";
    case PreviewCue::kLost:
      return "LOST";
    case PreviewCue::kRelocalised:
      return "RELOCALISED";
    case PreviewCue::kProbeLost:
      return "PROBE LOST";
    case PreviewCue::kPaused:
      return "PAUSED";
    case PreviewCue::kNewSegment:
      return "NEW SEGMENT";
    case PreviewCue::kSlowDown:
      return "SLOW DOWN";
    case PreviewCue::kLostSlowDown:
      return "LOST - SLOW DOWN";
  }
  return "?";
}

bool PanelRefresh::Due(PreviewCue cue, const std::string& message, const std::string& text,
                       int64_t now_ns, bool force) {
  const bool state_changed = !drawn_ || force || cue != cue_ || message != message_;
  if (!state_changed && (text == text_ || now_ns - drawn_ns_ < period_ns_)) return false;
  drawn_ = true;
  cue_ = cue;
  message_ = message;
  text_ = text;
  drawn_ns_ = now_ns;
  return true;
}

}  // namespace d3d
