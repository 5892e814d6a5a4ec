#include "firmware/update/slot_manager.h"

#include <algorithm>
#include <cstring>

namespace d3d::fw {

namespace {
constexpr uint8_t kErrWrite = 0x03, kErrErase = 0x04, kErrCheckErased = 0x05, kErrProg = 0x06,
                  kErrFirmware = 0x0A, kErrVendor = 0x0B, kErrUnknown = 0x0E;
const char* SlotName(int s) { return s == 0 ? "A" : "B"; }
}  // namespace

void SlotManagerOptions::Check(const FlashGeometry& g) const {
  D3D_CHECK_MSG(slot_bytes > 0 && slot_bytes % g.erase_block_bytes == 0,
                "slot size " << slot_bytes << " must be a positive multiple of the erase block "
                             << g.erase_block_bytes);
  D3D_CHECK_MSG(slot_bytes > kImageOverheadBytes,
                "slot size " << slot_bytes << " cannot hold an image");
  D3D_CHECK_MSG(trial_boots >= 1, "a new slot needs at least one trial boot");
}

FlashGeometry SlotFlashGeometry(FlashGeometry base, uint64_t slot_bytes) {
  base.size_bytes = BootControlStore::RegionBytes(base) + 2 * slot_bytes;
  return base;
}

UpdateResult UpdateResult::Reject(const Verdict& v) { return {DfuStatusFor(v.reason), v.message}; }
UpdateResult UpdateResult::Error(uint8_t dfu_status, std::string message) {
  return {dfu_status, std::move(message)};
}

SlotManager::SlotManager(Flash* flash, const PublicKey& trusted_key,
                         const SlotManagerOptions& options)
    : flash_(flash), key_(trusted_key), options_(options), store_(flash) {
  options_.Check(flash->geometry());
  D3D_CHECK_MSG(flash->geometry().size_bytes >= SlotOffset(1) + options_.slot_bytes,
                "flash of " << flash->geometry().size_bytes << " bytes cannot hold two slots of "
                            << options_.slot_bytes);
}

uint64_t SlotManager::SlotOffset(int slot) const {
  return BootControlStore::RegionBytes(flash_->geometry()) +
         static_cast<uint64_t>(slot) * options_.slot_bytes;
}

Status SlotManager::LoadRecord() { return store_.Load(&record_); }

Status SlotManager::WriteRecord() { return store_.Write(&*record_); }

Status SlotManager::IsProvisioned(bool* provisioned) {
  D3D_RETURN_IF_ERROR(LoadRecord());
  *provisioned = record_.has_value();
  return Status::Ok();
}

ImagePolicy SlotManager::UpdatePolicy() const {
  ImagePolicy p;
  p.check_hw_id = true;
  p.hw_id = options_.hw_id;
  p.min_security_counter = record_ ? record_->security_floor : 0;
  p.max_image_bytes = options_.slot_bytes;
  return p;
}

Status SlotManager::Provision(std::span<const uint8_t> image) {
  ImagePolicy p;
  p.check_hw_id = true;
  p.hw_id = options_.hw_id;
  p.max_image_bytes = options_.slot_bytes;
  ImageHeader h;
  const Verdict v = VerifyImageBytes(image, key_, p, &h);
  if (!v.ok()) return InvalidArgument("provisioning image refused: " + v.message);
  D3D_RETURN_IF_ERROR(LoadRecord());
  const uint32_t eb = flash_->geometry().erase_block_bytes;
  for (uint64_t a = 0; a < image.size(); a += eb)
    D3D_RETURN_IF_ERROR(flash_->EraseBlock(SlotOffset(0) + a));
  D3D_RETURN_IF_ERROR(flash_->Program(SlotOffset(0), image));
  BootRecord r;
  r.active_slot = 0;
  r.last_event = BootEvent::kConfirmed;
  r.security_floor = h.security_counter;
  r.slots[0] = {SlotState::kBootable, h.version, h.security_counter};
  record_ = r;
  return WriteRecord();
}

Verdict SlotManager::VerifySlot(int slot, ImageHeader* header) {
  std::array<uint8_t, kHeaderBytes> hb;
  if (!flash_->Read(SlotOffset(slot), hb).ok())
    return Verdict::Fail(Reject::kTruncated, "cannot read the slot");
  ImageHeader h;
  Verdict v = ParseHeader(hb, &h);
  if (!v.ok()) return v;
  const uint64_t available = std::min(h.ImageSize(), options_.slot_bytes);
  const uint64_t base = SlotOffset(slot);
  auto read = [&](uint64_t off, std::span<uint8_t> out) {
    return off <= available && out.size() <= available - off && flash_->Read(base + off, out).ok();
  };
  return VerifyImage(read, available, key_, UpdatePolicy(), header);
}

bool SlotManager::on_trial() const {
  return running_.booted && running_.event == BootEvent::kUpdated && record_ &&
         record_->trial_slot == running_.slot;
}

Status SlotManager::Boot(BootOutcome* out) {
  running_ = {};
  updating_ = false;
  D3D_RETURN_IF_ERROR(LoadRecord());
  if (!record_) {
    running_.message = "no valid boot-control record: the flash was never provisioned";
    *out = running_;
    return Status::Ok();
  }
  BootRecord& r = *record_;
  std::string log;
  if (r.trial_slot != kNoSlot) {
    const int t = r.trial_slot;
    ImageHeader h;
    Verdict v;
    v.message = "slot is not marked bootable";
    if (r.trial_boots_left > 0 && r.slots[t].state == SlotState::kBootable &&
        (v = VerifySlot(t, &h)).ok()) {
      --r.trial_boots_left;  // counted before running it: a crash during the trial uses it up
      D3D_RETURN_IF_ERROR(WriteRecord());
      running_ = {true, static_cast<uint8_t>(t), h, BootEvent::kUpdated,
                  std::string("trial boot of slot ") + SlotName(t) + " (" + h.version.ToString() +
                      ", " + std::to_string(r.trial_boots_left) + " trial boots left)"};
      *out = running_;
      return Status::Ok();
    }
    log = std::string("slot ") + SlotName(t) + " did not confirm its trial (" +
          (r.trial_boots_left == 0 ? std::string("no trial boots left") : v.message) +
          "): rolled back; ";
    r.slots[t].state = SlotState::kFailed;
    r.trial_slot = kNoSlot;
    r.trial_boots_left = 0;
    r.last_event = BootEvent::kRolledBack;
    D3D_RETURN_IF_ERROR(WriteRecord());
  }
  const int first = r.active_slot;
  for (int s : {first, 1 - first}) {
    if (r.slots[s].state != SlotState::kBootable) continue;
    ImageHeader h;
    const Verdict v = VerifySlot(s, &h);
    if (!v.ok()) {
      log.append("slot ")
          .append(SlotName(s))
          .append(" fails verification (")
          .append(v.message)
          .append("); ");
      continue;
    }
    if (s != first) {
      r.active_slot = static_cast<uint8_t>(s);
      r.last_event = BootEvent::kFallback;
      D3D_RETURN_IF_ERROR(WriteRecord());
    }
    const BootEvent ev = r.last_event == BootEvent::kNone || r.last_event == BootEvent::kUpdated
                             ? BootEvent::kConfirmed
                             : r.last_event;
    running_ = {true, static_cast<uint8_t>(s), h, ev,
                log + "boot of slot " + SlotName(s) + " (" + h.version.ToString() + ")"};
    *out = running_;
    return Status::Ok();
  }
  running_.message = log + "no slot holds a good image";
  *out = running_;
  return Status::Ok();
}

Status SlotManager::Confirm() {
  if (!on_trial()) return Status::Ok();
  BootRecord& r = *record_;
  const int s = running_.slot;
  r.active_slot = static_cast<uint8_t>(s);
  r.trial_slot = kNoSlot;
  r.trial_boots_left = 0;
  r.last_event = BootEvent::kConfirmed;
  r.security_floor = std::max(r.security_floor, running_.header.security_counter);
  SlotRecord& other = r.slots[1 - s];
  if (other.state == SlotState::kBootable && other.security_counter < r.security_floor)
    other.state = SlotState::kEmpty;
  D3D_RETURN_IF_ERROR(WriteRecord());
  running_.event = BootEvent::kConfirmed;
  return Status::Ok();
}

Status SlotManager::ReportHealthFailure() {
  if (!on_trial()) return Status::Ok();
  BootRecord& r = *record_;
  r.slots[running_.slot].state = SlotState::kFailed;
  r.trial_slot = kNoSlot;
  r.trial_boots_left = 0;
  r.last_event = BootEvent::kRolledBack;
  return WriteRecord();
}

UpdateResult SlotManager::FlashError(const Status& s, uint8_t dfu_status) const {
  if (s.code() == StatusCode::kCorrupt) dfu_status = kErrCheckErased;
  if (s.code() == StatusCode::kUnavailable) dfu_status = kErrWrite;
  return UpdateResult::Error(dfu_status, "flash: " + s.message());
}

UpdateResult SlotManager::BeginUpdate() {
  if (!running_.booted) return UpdateResult::Error(kErrFirmware, "no running firmware");
  if (on_trial()) {
    return UpdateResult::Error(kErrVendor, "busy: the running firmware " +
                                               running_.header.version.ToString() +
                                               " has not confirmed its trial boot yet");
  }
  target_ = 1 - running_.slot;
  BootRecord& r = *record_;
  if (r.slots[target_].state != SlotState::kEmpty || r.trial_slot == target_) {
    r.slots[target_] = SlotRecord{};
    if (r.trial_slot == target_) r.trial_slot = kNoSlot;
    const Status s = WriteRecord();
    if (!s.ok()) return FlashError(s, kErrWrite);
  }
  updating_ = true;
  received_ = programmed_ = erased_end_ = 0;
  pending_.clear();
  header_bytes_.clear();
  header_.reset();
  return {};
}

double SlotManager::ModelledWriteMs(uint64_t len) const {
  const FlashGeometry& g = flash_->geometry();
  const uint64_t end = received_ + len;
  const uint64_t blocks_end =
      (end + g.erase_block_bytes - 1) / g.erase_block_bytes * g.erase_block_bytes;
  const uint64_t new_blocks =
      blocks_end > erased_end_ ? (blocks_end - erased_end_) / g.erase_block_bytes : 0;
  const uint64_t pages = (pending_.size() + len) / g.page_bytes;
  return static_cast<double>(new_blocks) * g.block_erase_ms +
         static_cast<double>(pages) * g.page_program_ms;
}

UpdateResult SlotManager::ProgramPages(std::span<const uint8_t> data) {
  const FlashGeometry& g = flash_->geometry();
  std::vector<uint8_t> buf;
  buf.reserve(pending_.size() + data.size());
  buf.insert(buf.end(), pending_.begin(), pending_.end());
  buf.insert(buf.end(), data.begin(), data.end());
  const bool final_flush = data.empty();
  const size_t n = final_flush ? buf.size() : buf.size() / g.page_bytes * g.page_bytes;
  const uint64_t end = programmed_ + n;
  while (erased_end_ < end) {
    const Status s = flash_->EraseBlock(SlotOffset(target_) + erased_end_);
    if (!s.ok()) return FlashError(s, kErrErase);
    erased_end_ += g.erase_block_bytes;
  }
  if (n > 0) {
    const Status s =
        flash_->Program(SlotOffset(target_) + programmed_, std::span<const uint8_t>(buf).first(n));
    if (!s.ok()) return FlashError(s, kErrProg);
  }
  programmed_ += n;
  pending_.assign(buf.begin() + static_cast<long>(n), buf.end());
  return {};
}

UpdateResult SlotManager::WriteChunk(std::span<const uint8_t> data) {
  if (!updating_) return UpdateResult::Error(kErrUnknown, "no update in progress");
  auto fail = [this](const UpdateResult& r) {
    updating_ = false;
    return r;
  };
  if (data.size() > options_.slot_bytes - received_) {
    return fail(UpdateResult::Reject(Verdict::Fail(
        Reject::kOversize,
        "more than the slot's " + std::to_string(options_.slot_bytes) + " bytes received")));
  }
  if (!header_) {
    const size_t take = std::min(data.size(), kHeaderBytes - header_bytes_.size());
    header_bytes_.insert(header_bytes_.end(), data.begin(), data.begin() + static_cast<long>(take));
    if (header_bytes_.size() == kHeaderBytes) {
      ImageHeader h;
      Verdict v = ParseHeader(header_bytes_, &h);
      if (v.ok()) v = CheckPolicy(h, UpdatePolicy());
      if (!v.ok()) return fail(UpdateResult::Reject(v));
      header_ = h;
    }
  }
  if (header_ && received_ + data.size() > header_->ImageSize()) {
    return fail(UpdateResult::Reject(Verdict::Fail(
        Reject::kTrailingData, "received more than the " + std::to_string(header_->ImageSize()) +
                                   " bytes the header announces")));
  }
  const UpdateResult r = ProgramPages(data);
  if (!r.ok()) return fail(r);
  received_ += data.size();
  return {};
}

bool SlotManager::UpdateComplete() const { return header_ && received_ == header_->ImageSize(); }

UpdateResult SlotManager::FinishUpdate() {
  if (!updating_) return UpdateResult::Error(kErrUnknown, "no update in progress");
  updating_ = false;
  if (!pending_.empty()) {
    const UpdateResult r = ProgramPages({});
    if (!r.ok()) return r;
  }
  const uint64_t available = received_;
  const uint64_t base = SlotOffset(target_);
  auto read = [&](uint64_t off, std::span<uint8_t> out) {
    return off <= available && out.size() <= available - off && flash_->Read(base + off, out).ok();
  };
  ImageHeader h;
  const Verdict v = VerifyImage(read, available, key_, UpdatePolicy(), &h);  // read back from flash
  if (!v.ok()) return UpdateResult::Reject(v);
  BootRecord& r = *record_;
  r.slots[target_] = {SlotState::kBootable, h.version, h.security_counter};
  r.trial_slot = static_cast<uint8_t>(target_);
  r.trial_boots_left = options_.trial_boots;
  r.last_event = BootEvent::kUpdated;
  const Status s = WriteRecord();
  if (!s.ok()) return FlashError(s, kErrWrite);
  return {};
}

void SlotManager::AbortUpdate() {
  updating_ = false;
  pending_.clear();
}

}  // namespace d3d::fw
