// A/B firmware slots on the probe's flash: the bootloader's choice of slot (verified boot, trial
// boot, rollback, fallback, anti-rollback floor) and the writer that receives a new image into the
// inactive slot and verifies it from flash before marking it bootable.
//
// Flash layout: [boot-control copy 0 | copy 1] (one erase block each, boot_control.h), slot A,
// slot B (slot_bytes each, erase-block multiples). An image is stored from the start of its slot.
//
// Invariant (tested under power cuts at every flash operation): whatever the sequence of updates,
// cuts and restarts, Boot() finds a slot whose image verifies (signature, hash, hardware id,
// counter ≥ floor) as long as one was provisioned; the slot being written is marked empty in the
// boot-control record before its first erase, and becomes bootable only after its verification.
//
// Update life cycle: BeginUpdate → WriteChunk… → FinishUpdate (verify, mark trial) → Boot (trial
// boot, counts down trial_boots) → Confirm (health check passed: active, floor raised, slots with a
// lower counter retired) or ReportHealthFailure / trial boots exhausted → Boot rolls back.
//
// Thread safety: none; the update agent's thread owns it.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "common/core/status.h"
#include "firmware/update/boot_control.h"
#include "firmware/update/flash_model.h"
#include "firmware/update/image_format.h"

namespace d3d::fw {

struct SlotManagerOptions {
  uint32_t hw_id = 0x0001;            // this probe's hardware compatibility id
  uint64_t slot_bytes = 20ull << 20;  // capacity of each slot (≥ the largest image), bytes
  uint8_t trial_boots = 2;            // boots a new slot gets to confirm itself
  // Throws std::invalid_argument unless slot_bytes is a positive multiple of the erase block.
  void Check(const FlashGeometry& g) const;
};

// Flash geometry holding the boot-control region and two slots of `slot_bytes`.
FlashGeometry SlotFlashGeometry(FlashGeometry base, uint64_t slot_bytes);

// Outcome of an update step: DFU bStatus (0 = ok) and the exact reason.
struct UpdateResult {
  uint8_t dfu_status = 0;  // dfu::DfuStatus value
  std::string message;     // "<token>: <details>"
  bool ok() const { return dfu_status == 0; }
  static UpdateResult Reject(const Verdict& v);
  static UpdateResult Error(uint8_t dfu_status, std::string message);
};

struct BootOutcome {
  bool booted = false;  // false: no slot holds a good image (must never happen once provisioned)
  uint8_t slot = 0;
  ImageHeader header;                  // of the running image
  BootEvent event = BootEvent::kNone;  // kUpdated = trial boot, kRolledBack, kFallback, kConfirmed
  std::string message;                 // what the bootloader did, for logs
};

class SlotManager {
 public:
  SlotManager(Flash* flash, const PublicKey& trusted_key, const SlotManagerOptions& options);

  uint64_t SlotOffset(int slot) const;
  uint64_t slot_bytes() const { return options_.slot_bytes; }
  const SlotManagerOptions& options() const { return options_; }
  const std::optional<BootRecord>& record() const { return record_; }
  Flash* flash() { return flash_; }

  // Factory programming: verifies `image`, writes it to slot A, makes A active and confirmed, B
  // empty, floor = its counter. kInvalidArgument with the reason if the image does not verify.
  Status Provision(std::span<const uint8_t> image);
  // True when the boot-control record is valid (the part was provisioned).
  Status IsProvisioned(bool* provisioned);

  // The bootloader. Errors are flash I/O only (e.g. a power cut); out->booted == false means no
  // slot holds a good image.
  Status Boot(BootOutcome* out);
  const BootOutcome& running() const { return running_; }
  bool on_trial() const;
  // The running trial firmware passed its health check.
  Status Confirm();
  // The running trial firmware failed its health check: its slot is marked failed.
  Status ReportHealthFailure();
  // Verifies the image in `slot` as the bootloader does.
  Verdict VerifySlot(int slot, ImageHeader* header = nullptr);

  // --- Receiving a new image into the inactive slot -----------------------------------------
  ImagePolicy UpdatePolicy() const;
  UpdateResult BeginUpdate();
  // Appends `data` at the current end of the received image: erases blocks as it enters them,
  // programs whole pages (a partial last page waits in a buffer). Checks the header as soon as
  // 128 bytes are in (magic, format, hardware id, size, counter).
  UpdateResult WriteChunk(std::span<const uint8_t> data);
  // True once the header is in and all the bytes it announces were received.
  bool UpdateComplete() const;
  uint64_t received_bytes() const { return received_; }
  // Image size the received header announces; 0 while fewer than 128 bytes are in.
  uint64_t expected_bytes() const { return header_ ? header_->ImageSize() : 0; }
  // Programs what is buffered, verifies the slot from flash, then marks it for a trial boot.
  UpdateResult FinishUpdate();
  // Drops a partial update (the target slot stays empty).
  void AbortUpdate();
  bool update_in_progress() const { return updating_; }
  // Modelled flash busy time of WriteChunk(len) at the current cursor, ms (for bwPollTimeout).
  double ModelledWriteMs(uint64_t len) const;

 private:
  Status LoadRecord();
  Status WriteRecord();
  UpdateResult FlashError(const Status& s, uint8_t dfu_status) const;
  UpdateResult ProgramPages(std::span<const uint8_t> data);

  Flash* flash_;
  PublicKey key_;
  SlotManagerOptions options_;
  BootControlStore store_;
  std::optional<BootRecord> record_;
  BootOutcome running_;

  // Update state (single owner thread).
  bool updating_ = false;
  int target_ = 1;
  uint64_t received_ = 0;
  uint64_t programmed_ = 0;       // bytes programmed into the slot (page-aligned until the end)
  uint64_t erased_end_ = 0;       // slot-relative end of the erased region
  std::vector<uint8_t> pending_;  // partial page not yet programmed (< page_bytes)
  std::vector<uint8_t> header_bytes_;
  std::optional<ImageHeader> header_;
};

}  // namespace d3d::fw
