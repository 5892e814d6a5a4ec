#include "host/app/undo_log.h"

#include <gtest/gtest.h>

#include <limits>

namespace d3d {
namespace {

ScanRegistrar::UndoResult Undid(int64_t first_view, int64_t views, double seconds) {
  ScanRegistrar::UndoResult u;
  u.ok = true;
  u.first_view = first_view;
  u.views_undone = views;
  u.seconds_undone = seconds;
  return u;
}

TEST(UndoLog, OffTakesNoRequests) {
  UndoLog log(false);
  EXPECT_FALSE(log.Request());
  EXPECT_EQ(log.requests(), 0u);
}

TEST(UndoLog, RecordsWhatEachUndoDidAndCutsAtTheEarliestFirstView) {
  UndoLog log(true);
  EXPECT_TRUE(log.Request());
  EXPECT_TRUE(log.Request());
  EXPECT_EQ(log.requests(), 2u);
  EXPECT_TRUE(log.Record(Undid(40, 12, 2.0)));
  EXPECT_EQ(log.LastMessage(), "undid 2.0 s: 12 views");
  ScanRegistrar::UndoResult none;
  none.reason = "no views to undo";
  EXPECT_FALSE(log.Record(none));
  EXPECT_EQ(log.LastMessage(), "nothing undone: no views to undo");
  ScanRegistrar::UndoResult clamped = Undid(25, 15, 1.4);
  clamped.clamped = true;
  EXPECT_TRUE(log.Record(clamped));
  EXPECT_EQ(log.LastMessage(), "undid 1.4 s: 15 views (as far back as undo reaches)");
  EXPECT_EQ(log.done(), 3u);
  EXPECT_EQ(log.refused(), 1u);
  EXPECT_EQ(log.views_undone(), 27u);
  // Generations are the undos applied (the refused one is not in the log).
  EXPECT_EQ(log.Cut(0, 1), 40);
  EXPECT_EQ(log.Cut(0, 2), 25);
  EXPECT_EQ(log.Cut(1, 2), 25);
  EXPECT_EQ(log.Cut(2, 2), std::numeric_limits<int64_t>::max());
  EXPECT_EQ(log.Cut(1, 9), 25);  // beyond the log: what there is
}

}  // namespace
}  // namespace d3d
