#include "firmware/update/boot_control.h"

#include <zlib.h>

#include <algorithm>

#include "firmware/update/little_endian.h"

namespace d3d::fw {

namespace {
constexpr uint32_t kBootMagic = 0x43423344;  // "D3BC"
uint32_t Crc(const uint8_t* p, size_t n) {
  return static_cast<uint32_t>(crc32(crc32(0L, Z_NULL, 0), p, static_cast<uInt>(n)));
}
}  // namespace

const char* SlotStateName(SlotState s) {
  switch (s) {
    case SlotState::kEmpty:
      return "empty";
    case SlotState::kBootable:
      return "bootable";
    case SlotState::kFailed:
      return "failed";
  }
  return "?";
}

std::array<uint8_t, kBootRecordBytes> BootRecord::Serialize() const {
  std::array<uint8_t, kBootRecordBytes> b{};
  PutLe32(&b[0], kBootMagic);
  PutLe16(&b[4], 1);
  PutLe16(&b[6], kBootRecordBytes);
  PutLe32(&b[8], sequence);
  b[12] = active_slot;
  b[13] = trial_slot;
  b[14] = trial_boots_left;
  b[15] = static_cast<uint8_t>(last_event);
  PutLe32(&b[16], security_floor);
  for (int s = 0; s < 2; ++s) {
    uint8_t* p = &b[20 + 12 * s];
    p[0] = static_cast<uint8_t>(slots[s].state);
    PutLe16(p + 2, slots[s].version.major);
    PutLe16(p + 4, slots[s].version.minor);
    PutLe16(p + 6, slots[s].version.patch);
    PutLe32(p + 8, slots[s].security_counter);
  }
  PutLe32(&b[60], Crc(b.data(), 60));
  return b;
}

std::optional<BootRecord> BootRecord::Parse(std::span<const uint8_t> b) {
  if (b.size() < kBootRecordBytes) return std::nullopt;
  if (GetLe32(&b[0]) != kBootMagic || GetLe16(&b[4]) != 1 || GetLe16(&b[6]) != kBootRecordBytes)
    return std::nullopt;
  if (GetLe32(&b[60]) != Crc(b.data(), 60)) return std::nullopt;
  BootRecord r;
  r.sequence = GetLe32(&b[8]);
  r.active_slot = b[12];
  r.trial_slot = b[13];
  r.trial_boots_left = b[14];
  if (r.active_slot > 1 || (r.trial_slot > 1 && r.trial_slot != kNoSlot) || b[15] > 4)
    return std::nullopt;
  r.last_event = static_cast<BootEvent>(b[15]);
  r.security_floor = GetLe32(&b[16]);
  for (int s = 0; s < 2; ++s) {
    const uint8_t* p = &b[20 + 12 * s];
    if (p[0] > 2) return std::nullopt;
    r.slots[s].state = static_cast<SlotState>(p[0]);
    r.slots[s].version = SemVer{GetLe16(p + 2), GetLe16(p + 4), GetLe16(p + 6)};
    r.slots[s].security_counter = GetLe32(p + 8);
  }
  return r;
}

Status BootControlStore::Load(std::optional<BootRecord>* out) {
  std::optional<BootRecord> best;
  newest_copy_ = -1;
  for (int c = 0; c < 2; ++c) {
    std::array<uint8_t, kBootRecordBytes> b;
    D3D_RETURN_IF_ERROR(
        flash_->Read(static_cast<uint64_t>(c) * flash_->geometry().erase_block_bytes, b));
    auto r = BootRecord::Parse(b);
    if (r && (!best || r->sequence > best->sequence)) {
      best = r;
      newest_copy_ = c;
    }
  }
  newest_sequence_ = best ? best->sequence : 0;
  *out = best;
  return Status::Ok();
}

Status BootControlStore::Write(BootRecord* record) {
  const int target = newest_copy_ == 0 ? 1 : 0;
  record->sequence = newest_sequence_ + 1;
  const auto bytes = record->Serialize();
  const uint64_t addr = static_cast<uint64_t>(target) * flash_->geometry().erase_block_bytes;
  D3D_RETURN_IF_ERROR(flash_->EraseBlock(addr));
  D3D_RETURN_IF_ERROR(flash_->Program(addr, bytes));
  newest_copy_ = target;
  newest_sequence_ = record->sequence;
  return Status::Ok();
}

}  // namespace d3d::fw
