#include "viewer/preview.h"

namespace d3d {

const char* PreviewCueText(PreviewCue c) {
  switch (c) {
    case PreviewCue::kWaiting: return "WAITING FOR PROBE";
    case PreviewCue::kTracking: return "TRACKING";
    case PreviewCue::kLost: return "LOST";
    case PreviewCue::kRelocalised: return "RELOCALISED";
    case PreviewCue::kProbeLost: return "PROBE LOST";
    case PreviewCue::kPaused: return "PAUSED";
  }
  return "?";
}

}  // namespace d3d
