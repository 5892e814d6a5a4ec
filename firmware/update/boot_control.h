// The boot-control record: which A/B slot is active, which one is on a trial boot, which slots
// hold a verified image, and the anti-rollback floor. Power-loss safe: the record lives in two
// copies, each in its own erase block, with a sequence number and a CRC-32 (zlib). A write goes to
// the copy *not* holding the newest record (erase, then program one page); a cut at any point
// leaves the other copy intact, and a reader takes the valid copy with the highest sequence number.
//
// Record layout (64 bytes, little-endian): 0 u32 magic "D3BC", 4 u16 format 1, 6 u16 length 64,
// 8 u32 sequence, 12 u8 active slot, 13 u8 trial slot (0xFF none), 14 u8 trial boots left,
// 15 u8 last event, 16 u32 security floor, 20 + 12·s slot s: u8 state, u8 0, u16×3 version,
// u32 security counter; 44..59 zero; 60 u32 CRC-32 of bytes 0..59.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <span>

#include "common/core/status.h"
#include "firmware/update/flash_model.h"
#include "firmware/update/image_format.h"

namespace d3d::fw {

inline constexpr size_t kBootRecordBytes = 64;
inline constexpr uint8_t kNoSlot = 0xFF;

enum class SlotState : uint8_t {
  kEmpty = 0,     // no verified image (being written, erased, or never written): never booted
  kBootable = 1,  // holds an image that passed verification
  kFailed = 2,    // its trial boot did not confirm: never booted again until rewritten
};
const char* SlotStateName(SlotState s);

enum class BootEvent : uint8_t {
  kNone = 0,
  kUpdated = 1,     // a new image was verified and awaits its trial boot / confirmation
  kConfirmed = 2,   // the running slot confirmed its health check
  kRolledBack = 3,  // a trial slot did not confirm; back on the previous slot
  kFallback = 4,    // the active slot failed verification at boot; booted the other one
};

struct SlotRecord {
  SlotState state = SlotState::kEmpty;
  SemVer version;
  uint32_t security_counter = 0;
  bool operator==(const SlotRecord&) const = default;
};

struct BootRecord {
  uint32_t sequence = 0;
  uint8_t active_slot = 0;
  uint8_t trial_slot = kNoSlot;
  uint8_t trial_boots_left = 0;
  BootEvent last_event = BootEvent::kNone;
  uint32_t security_floor = 0;
  std::array<SlotRecord, 2> slots{};
  bool operator==(const BootRecord&) const = default;

  std::array<uint8_t, kBootRecordBytes> Serialize() const;
  // Nullopt when the magic, format, length, CRC or a field range is wrong (an erased or torn copy).
  static std::optional<BootRecord> Parse(std::span<const uint8_t> bytes);
};

// The two copies at erase blocks 0 and 1 of `flash`.
class BootControlStore {
 public:
  explicit BootControlStore(Flash* flash) : flash_(flash) {}
  // The newest valid record, or nullopt if neither copy is valid (a blank part).
  // kIoError/kUnavailable when the flash cannot be read.
  Status Load(std::optional<BootRecord>* out);
  // Writes `record` with sequence = newest + 1 into the older copy; updates record->sequence.
  Status Write(BootRecord* record);
  static uint64_t RegionBytes(const FlashGeometry& g) { return 2ull * g.erase_block_bytes; }

 private:
  Flash* flash_;
  uint32_t newest_sequence_ = 0;
  int newest_copy_ = -1;  // -1: none valid
};

}  // namespace d3d::fw
