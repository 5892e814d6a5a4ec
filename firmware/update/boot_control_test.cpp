#include "firmware/update/boot_control.h"

#include <gtest/gtest.h>

namespace d3d::fw {
namespace {

FlashGeometry TwoBlockFlash() {
  FlashGeometry g;
  g.erase_block_bytes = 4096;
  g.page_bytes = 256;
  g.size_bytes = 2 * 4096;
  return g;
}

BootRecord Sample() {
  BootRecord r;
  r.active_slot = 1;
  r.trial_slot = 0;
  r.trial_boots_left = 2;
  r.last_event = BootEvent::kUpdated;
  r.security_floor = 7;
  r.slots[0] = {SlotState::kBootable, {1, 2, 3}, 8};
  r.slots[1] = {SlotState::kFailed, {1, 1, 0}, 7};
  return r;
}

TEST(BootRecord, RoundTripsAndTheCrcCatchesEveryFlippedBit) {
  const BootRecord r = Sample();
  const auto b = r.Serialize();
  auto back = BootRecord::Parse(b);
  ASSERT_TRUE(back);
  EXPECT_EQ(*back, r);
  for (size_t i = 0; i < b.size(); ++i)
    for (int bit = 0; bit < 8; ++bit) {
      auto c = b;
      c[i] ^= static_cast<uint8_t>(1 << bit);
      EXPECT_FALSE(BootRecord::Parse(c)) << "byte " << i << " bit " << bit;
    }
  std::array<uint8_t, kBootRecordBytes> erased;
  erased.fill(0xFF);
  EXPECT_FALSE(BootRecord::Parse(erased));
}

TEST(BootControlStore, AlternatesCopiesAndATornWriteKeepsThePreviousRecord) {
  auto f = Flash::InMemory(TwoBlockFlash());
  BootControlStore store(f.get());
  std::optional<BootRecord> got;
  ASSERT_TRUE(store.Load(&got).ok());
  EXPECT_FALSE(got);  // blank part
  BootRecord r = Sample();
  ASSERT_TRUE(store.Write(&r).ok());
  EXPECT_EQ(r.sequence, 1u);
  r.security_floor = 9;
  ASSERT_TRUE(store.Write(&r).ok());
  EXPECT_EQ(r.sequence, 2u);
  ASSERT_TRUE(store.Load(&got).ok());
  ASSERT_TRUE(got);
  EXPECT_EQ(got->security_floor, 9u);
  // Cut the power at each operation of the next write (erase, program): the newest complete record
  // wins.
  for (int cut = 0; cut < 2; ++cut) {
    BootControlStore s2(f.get());
    ASSERT_TRUE(s2.Load(&got).ok());
    const uint32_t before = got->sequence;
    BootRecord next = *got;
    next.security_floor = 100 + static_cast<uint32_t>(cut);
    f->CutPowerAfterOps(f->ops() + cut);
    EXPECT_FALSE(s2.Write(&next).ok());
    f->PowerCycle();
    BootControlStore s3(f.get());
    ASSERT_TRUE(s3.Load(&got).ok());
    ASSERT_TRUE(got);
    EXPECT_EQ(got->sequence, before);
    EXPECT_EQ(got->security_floor, 9u);
  }
}

}  // namespace
}  // namespace d3d::fw
