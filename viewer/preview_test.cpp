// PanelRefresh: the status panel's counters are redrawn at most once per period, a change of
// tracking cue or message at once (the dentist must see "LOST" in the next frame).
#include "viewer/preview.h"

#include <gtest/gtest.h>

namespace d3d {
namespace {

constexpr int64_t kMs = 1'000'000;

TEST(PanelRefresh, CountersWaitForThePeriodACueChangeDoesNot) {
  PanelRefresh r(250 * kMs);
  EXPECT_TRUE(r.Due(PreviewCue::kTracking, "", "10 bursts", 0, false))
      << "the first frame draws the panel";
  EXPECT_FALSE(r.Due(PreviewCue::kTracking, "", "10 bursts", 10 * kMs, false)) << "nothing changed";
  EXPECT_FALSE(r.Due(PreviewCue::kTracking, "", "11 bursts", 50 * kMs, false))
      << "counters only, within the period";
  EXPECT_TRUE(r.Due(PreviewCue::kLost, "", "12 bursts", 60 * kMs, false))
      << "a new cue shows at once";
  EXPECT_FALSE(r.Due(PreviewCue::kLost, "", "13 bursts", 100 * kMs, false));
  EXPECT_TRUE(r.Due(PreviewCue::kLost, "saved scan.ply", "13 bursts", 110 * kMs, false))
      << "a new message shows at once";
  EXPECT_FALSE(r.Due(PreviewCue::kLost, "saved scan.ply", "14 bursts", 359 * kMs, false));
  EXPECT_TRUE(r.Due(PreviewCue::kLost, "saved scan.ply", "14 bursts", 360 * kMs, false))
      << "the period passed";
  EXPECT_FALSE(r.Due(PreviewCue::kLost, "saved scan.ply", "14 bursts", 2000 * kMs, false))
      << "the same text is not drawn again";
  EXPECT_TRUE(r.Due(PreviewCue::kLost, "saved scan.ply", "14 bursts", 2001 * kMs, true))
      << "forced (a resize, a capture)";
}

}  // namespace
}  // namespace d3d
