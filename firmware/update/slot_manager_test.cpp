#include "firmware/update/slot_manager.h"

#include <gtest/gtest.h>

#include "firmware/update/test_images.h"

namespace d3d::fw {
namespace {

using testing::MakeImage;
using testing::MakeTestKey;

constexpr uint64_t kSlot = 64 * 1024;

FlashGeometry Geometry() {
  FlashGeometry g;
  g.erase_block_bytes = 4096;
  g.page_bytes = 256;
  return SlotFlashGeometry(g, kSlot);
}

SlotManagerOptions Options() {
  SlotManagerOptions o;
  o.hw_id = 1;
  o.slot_bytes = kSlot;
  o.trial_boots = 2;
  return o;
}

// Streams an image in DFU-sized blocks; returns the first failure.
UpdateResult Send(SlotManager& m, const std::vector<uint8_t>& img, size_t block = 1000) {
  UpdateResult r = m.BeginUpdate();
  for (size_t off = 0; r.ok() && off < img.size(); off += block) {
    r = m.WriteChunk(std::span<const uint8_t>(img).subspan(off, std::min(block, img.size() - off)));
  }
  if (!r.ok()) return r;
  return m.FinishUpdate();
}

class SlotManagerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    flash = Flash::InMemory(Geometry());
    v10 = MakeImage(&key, {1, 0, 0}, 1, 1, 20000, 1);
    v11 = MakeImage(&key, {1, 1, 0}, 1, 1, 23000, 2);
    v20 = MakeImage(&key, {2, 0, 0}, 2, 1, 21000, 3);
    SlotManager m(flash.get(), key.pk, Options());
    ASSERT_TRUE(m.Provision(v10).ok());
  }
  BootOutcome BootFresh() {
    mgr = std::make_unique<SlotManager>(flash.get(), key.pk, Options());
    BootOutcome b;
    EXPECT_TRUE(mgr->Boot(&b).ok());
    return b;
  }
  testing::TestKey key = MakeTestKey(1);
  std::unique_ptr<Flash> flash;
  std::unique_ptr<SlotManager> mgr;
  std::vector<uint8_t> v10, v11, v20;
};

TEST_F(SlotManagerTest, UpdateTrialBootConfirm) {
  BootOutcome b = BootFresh();
  ASSERT_TRUE(b.booted);
  EXPECT_EQ(b.slot, 0);
  EXPECT_EQ(b.header.version, (SemVer{1, 0, 0}));
  const UpdateResult r = Send(*mgr, v11);
  ASSERT_TRUE(r.ok()) << r.message;
  b = BootFresh();
  EXPECT_EQ(b.slot, 1);
  EXPECT_EQ(b.event, BootEvent::kUpdated);
  EXPECT_TRUE(mgr->on_trial());
  ASSERT_TRUE(mgr->Confirm().ok());
  b = BootFresh();
  EXPECT_EQ(b.slot, 1);
  EXPECT_EQ(b.header.version, (SemVer{1, 1, 0}));
  EXPECT_EQ(b.event, BootEvent::kConfirmed);
  EXPECT_EQ(mgr->record()->slots[0].state,
            SlotState::kBootable);  // same counter: v1.0 stays as fallback
}

TEST_F(SlotManagerTest, UnhealthyTrialRollsBack) {
  BootFresh();
  ASSERT_TRUE(Send(*mgr, v11).ok());
  BootOutcome b = BootFresh();
  ASSERT_TRUE(mgr->on_trial());
  ASSERT_TRUE(mgr->ReportHealthFailure().ok());
  b = BootFresh();
  EXPECT_EQ(b.slot, 0);
  EXPECT_EQ(b.header.version, (SemVer{1, 0, 0}));
  EXPECT_EQ(b.event, BootEvent::kRolledBack);
  EXPECT_EQ(mgr->record()->slots[1].state, SlotState::kFailed);
}

TEST_F(SlotManagerTest, TrialThatNeverConfirmsRollsBackAfterItsTrialBoots) {
  BootFresh();
  ASSERT_TRUE(Send(*mgr, v11).ok());
  for (int i = 0; i < Options().trial_boots; ++i) {
    const BootOutcome b = BootFresh();  // crash / watchdog before confirming
    EXPECT_EQ(b.slot, 1);
    EXPECT_EQ(b.event, BootEvent::kUpdated);
  }
  const BootOutcome b = BootFresh();
  EXPECT_EQ(b.slot, 0);
  EXPECT_EQ(b.event, BootEvent::kRolledBack);
}

TEST_F(SlotManagerTest, ConfirmRaisesTheFloorAndRetiresOlderCounters) {
  BootFresh();
  ASSERT_TRUE(Send(*mgr, v20).ok());
  BootFresh();
  ASSERT_TRUE(mgr->Confirm().ok());
  EXPECT_EQ(mgr->record()->security_floor, 2u);
  EXPECT_EQ(mgr->record()->slots[0].state, SlotState::kEmpty);
  BootFresh();
  const UpdateResult r = Send(*mgr, v11);  // counter 1 < floor 2
  EXPECT_FALSE(r.ok());
  EXPECT_EQ(r.message.rfind("downgrade", 0), 0u) << r.message;
  const BootOutcome b = BootFresh();
  EXPECT_EQ(b.header.version, (SemVer{2, 0, 0}));
}

TEST_F(SlotManagerTest, RefusalsLeaveTheRunningSlotAlone) {
  BootFresh();
  const auto other = MakeTestKey(2);
  struct Case {
    std::vector<uint8_t> image;
    const char* token;
  };
  auto flipped = v11;
  flipped[v11.size() / 2] ^= 1;
  std::vector<Case> cases = {
      {MakeImage(nullptr, {1, 1, 0}, 1, 1, 1000), "unsigned"},
      {MakeImage(&other, {1, 1, 0}, 1, 1, 1000), "unknown-key"},
      {flipped, "payload-hash"},
      {MakeImage(&key, {1, 1, 0}, 1, 2, 1000), "wrong-hardware"},
      {MakeImage(&key, {1, 1, 0}, 1, 1, kSlot), "oversize"},
      {MakeImage(&key, {0, 9, 0}, 0, 1, 1000), "downgrade"},
  };
  for (const Case& c : cases) {
    const UpdateResult r = Send(*mgr, c.image);
    EXPECT_FALSE(r.ok());
    EXPECT_EQ(r.message.rfind(c.token, 0), 0u) << r.message;
    const BootOutcome b = BootFresh();
    EXPECT_EQ(b.slot, 0);
    EXPECT_EQ(b.header.version, (SemVer{1, 0, 0}));
  }
}

TEST_F(SlotManagerTest, CorruptedActiveSlotFallsBackToTheOther) {
  BootFresh();
  ASSERT_TRUE(Send(*mgr, v11).ok());
  BootFresh();
  ASSERT_TRUE(mgr->Confirm().ok());  // active B (1.1), A (1.0) kept as fallback
  // Bit rot in slot B's payload: erase its first block (a crude but certain corruption).
  ASSERT_TRUE(flash->EraseBlock(mgr->SlotOffset(1)).ok());
  const BootOutcome b = BootFresh();
  ASSERT_TRUE(b.booted);
  EXPECT_EQ(b.slot, 0);
  EXPECT_EQ(b.event, BootEvent::kFallback);
}

// Power cut at every flash operation of a full update cycle (begin, every block, manifestation,
// trial boot, confirm): after power returns the probe boots a good signed version, and a repeated
// update then succeeds.
TEST_F(SlotManagerTest, PowerCutAtEveryFlashOperationAlwaysBootsAGoodVersion) {
  const auto snapshot = [&] {
    std::vector<uint8_t> all(flash->geometry().size_bytes);
    EXPECT_TRUE(flash->Read(0, all).ok());
    return all;
  }();
  auto restore = [&] {
    flash = Flash::InMemory(Geometry());  // the provisioned state, byte for byte
    ASSERT_TRUE(flash->Program(0, snapshot).ok());
  };
  auto cycle = [&]() -> bool {  // false when the power was cut
    mgr = std::make_unique<SlotManager>(flash.get(), key.pk, Options());
    BootOutcome b;
    if (!mgr->Boot(&b).ok()) return false;
    const UpdateResult r = Send(*mgr, v11, 1500);
    if (!r.ok()) return false;
    mgr = std::make_unique<SlotManager>(flash.get(), key.pk, Options());
    if (!mgr->Boot(&b).ok()) return false;
    return mgr->Confirm().ok();
  };
  restore();  // count the operations of one uninterrupted cycle
  const int64_t start = flash->ops();
  ASSERT_TRUE(cycle());
  const int64_t total = flash->ops() - start;
  ASSERT_GT(total, 100);
  int new_version = 0, old_version = 0;
  for (int64_t k = 0; k < total; ++k) {
    restore();
    flash->CutPowerAfterOps(flash->ops() + k);
    ASSERT_FALSE(cycle()) << "cut at op " << k << " did not interrupt";
    flash->PowerCycle();
    const BootOutcome b = BootFresh();
    ASSERT_TRUE(b.booted) << "unbootable after a cut at op " << k << ": " << b.message;
    ASSERT_TRUE(mgr->VerifySlot(b.slot).ok());
    const bool is_new = b.header.version == SemVer{1, 1, 0};
    ASSERT_TRUE(is_new || b.header.version == (SemVer{1, 0, 0}));
    (is_new ? new_version : old_version)++;
    // The probe can always be updated again afterwards.
    if (mgr->on_trial()) {
      ASSERT_TRUE(mgr->Confirm().ok());
    }
    const UpdateResult r = Send(*mgr, v20);
    ASSERT_TRUE(r.ok()) << "cut at op " << k << ": " << r.message;
    const BootOutcome b2 = BootFresh();
    ASSERT_EQ(b2.header.version, (SemVer{2, 0, 0}));
  }
  EXPECT_GT(old_version, 0);
  EXPECT_GT(new_version, 0);
  RecordProperty("cut_points", static_cast<int>(total));
}

TEST_F(SlotManagerTest, WritesNeedErasedFlashAndRespectGranularity) {
  BootFresh();
  ASSERT_TRUE(Send(*mgr, v11, 333).ok());  // odd block size: partial pages buffered
  EXPECT_GE(flash->stats().page_programs, static_cast<int64_t>(v11.size() / 256));
  BootOutcome b = BootFresh();
  EXPECT_EQ(b.header.version, (SemVer{1, 1, 0}));
}

}  // namespace
}  // namespace d3d::fw
