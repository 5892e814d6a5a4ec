#include "firmware/update/dfu_device.h"

#include <chrono>

#include "common/core/status.h"

namespace d3d::dfu {

void DfuDeviceOptions::Check() const {
  D3D_CHECK_MSG(transfer_size > 0, "wTransferSize must be positive");
  D3D_CHECK_MSG((attributes & kAttrCanUpload) == 0,
                "DFU_UPLOAD is not supported (the probe never reads its firmware out)");
  D3D_CHECK_MSG((attributes & kAttrCanDnload) != 0, "the DFU interface must accept downloads");
}

DfuDevice::DfuDevice(DfuBackend* backend, DfuDeviceOptions options)
    : backend_(backend), options_(std::move(options)) {
  options_.Check();
  block_.reserve(options_.transfer_size);
}

FunctionalDescriptor DfuDevice::functional_descriptor() const {
  FunctionalDescriptor d;
  d.attributes = options_.attributes;
  d.detach_timeout_ms = options_.detach_timeout_ms;
  d.transfer_size = options_.transfer_size;
  return d;
}

int64_t DfuDevice::Now() const {
  if (options_.clock_ms) return options_.clock_ms();
  return std::chrono::duration_cast<std::chrono::milliseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

uint32_t DfuDevice::Poll(uint32_t modelled) const {
  const uint32_t p =
      options_.fixed_poll_ms >= 0 ? static_cast<uint32_t>(options_.fixed_poll_ms) : modelled;
  return std::min<uint32_t>(p, 0xFFFFFF);
}

void DfuDevice::ApplyTimedTransitions(int64_t now) {
  if (state_ == kAppDetach && now > deadline_ms_) state_ = kAppIdle;
  if (state_ == kDfuDnBusy && now >= deadline_ms_) state_ = kDfuDnloadSync;
  if (state_ == kDfuManifest && now >= deadline_ms_) {
    state_ = (options_.attributes & kAttrManifestationTolerant) ? kDfuManifestSync
                                                                : kDfuManifestWaitReset;
  }
}

void DfuDevice::Fail(uint8_t status, std::string message) {
  state_ = kDfuError;
  status_ = status;
  error_ = std::move(message);
}

ControlResponse DfuDevice::Report(uint32_t poll_ms) const {
  StatusReport r;
  r.status = status_;
  r.poll_timeout_ms = poll_ms;
  r.state = state_;
  r.string_index = status_ == kOk ? 0 : kStrLastError;
  const auto b = r.Encode();
  return {false, std::vector<uint8_t>(b.begin(), b.end())};
}

ControlResponse DfuDevice::StallError(const SetupPacket& setup) {
  std::string msg = "stalled-request: request ";
  msg.append(std::to_string(setup.request))
      .append(" is not valid in state ")
      .append(StateName(state_));
  if (state_ == kAppIdle || state_ == kAppDetach) {
    // Run-time mode has no error state (A.2.1/A.2.2): stall, appDETACH falls back to appIDLE.
    if (state_ == kAppDetach) state_ = kAppIdle;
    return {true, {}};
  }
  if (state_ == kDfuManifestWaitReset) return {true, {}};  // only a reset is answered
  if (state_ == kDfuError) return {true, {}};              // keep the original reason
  backend_->AbortDownload();
  Fail(kErrStalledPkt, std::move(msg));
  return {true, {}};
}

ControlResponse DfuDevice::Handle(const SetupPacket& setup, std::span<const uint8_t> out_data) {
  ApplyTimedTransitions(Now());
  const bool in = setup.is_in();
  const uint8_t req = setup.request;
  // Direction must match the request (Table 3.2): IN for UPLOAD/GETSTATUS/GETSTATE, OUT otherwise.
  const bool want_in = req == kUpload || req == kGetStatus || req == kGetState;
  if (req > kAbort || in != want_in || (in && setup.request_type != kRequestTypeClassIn) ||
      (!in && setup.request_type != kRequestTypeClassOut) ||
      (!in && out_data.size() != setup.length)) {
    return StallError(setup);
  }
  if (req == kGetState) {
    if (state_ == kDfuDnBusy || state_ == kDfuManifest || state_ == kDfuManifestWaitReset)
      return StallError(setup);
    return {false, {state_}};
  }
  if (req == kGetStatus && setup.length < 6) return StallError(setup);

  switch (state_) {
    case kAppIdle:
      if (req == kGetStatus) return Report(0);
      if (req == kDetach) {
        const BackendReply r = backend_->Detach();
        if (!r.ok()) {
          status_ = r.status;  // reported by GETSTATUS in appIDLE until the next attempt
          error_ = r.message;
          return {true, {}};
        }
        status_ = kOk;
        error_.clear();
        state_ = kAppDetach;
        deadline_ms_ = Now() + std::min<int64_t>(setup.value, options_.detach_timeout_ms);
        return {};
      }
      return StallError(setup);

    case kAppDetach:
      if (req == kGetStatus) return Report(0);
      return StallError(setup);

    case kDfuIdle:
      if (req == kGetStatus) return Report(0);
      if (req == kAbort) return {};
      if (req == kDnload && setup.length > 0) {
        if (setup.length > options_.transfer_size) return StallError(setup);
        const BackendReply r = backend_->BeginDownload();
        if (!r.ok()) {
          Fail(r.status, r.message);
          return {true, {}};
        }
        block_.assign(out_data.begin(), out_data.end());
        next_block_ = static_cast<uint16_t>(setup.value + 1);
        block_written_ = false;
        state_ = kDfuDnloadSync;
        return {};
      }
      return StallError(setup);

    case kDfuDnloadSync:
      if (req != kGetStatus) return StallError(setup);
      if (block_written_) {
        state_ = kDfuDnloadIdle;
        return Report(0);
      } else {
        const BackendReply r = backend_->DownloadBlock(block_);
        block_written_ = true;
        if (!r.ok()) {
          Fail(r.status, r.message);
          return Report(0);
        }
        if (!options_.report_busy) {
          state_ = kDfuDnloadIdle;
          return Report(0);
        }
        const uint32_t poll = Poll(r.poll_ms);
        state_ = kDfuDnBusy;
        deadline_ms_ = Now() + poll;
        return Report(poll);
      }

    case kDfuDnBusy:
      return StallError(setup);  // the host did not wait bwPollTimeout

    case kDfuDnloadIdle:
      if (req == kGetStatus) return Report(0);
      if (req == kAbort) {
        backend_->AbortDownload();
        state_ = kDfuIdle;
        return {};
      }
      if (req == kDnload && setup.length == 0) {
        std::string why;
        if (!backend_->DownloadComplete(&why)) {
          backend_->AbortDownload();
          Fail(kErrNotDone, why);
          return {true, {}};
        }
        manifest_done_ = false;
        state_ = kDfuManifestSync;
        return {};
      }
      if (req == kDnload) {
        if (setup.length > options_.transfer_size) return StallError(setup);
        if (setup.value != next_block_) {
          backend_->AbortDownload();
          Fail(kErrAddress, "block-sequence: got block " + std::to_string(setup.value) +
                                ", expected " + std::to_string(next_block_));
          return {true, {}};
        }
        block_.assign(out_data.begin(), out_data.end());
        next_block_ = static_cast<uint16_t>(next_block_ + 1);
        block_written_ = false;
        state_ = kDfuDnloadSync;
        return {};
      }
      return StallError(setup);

    case kDfuManifestSync:
      if (req != kGetStatus) return StallError(setup);
      if (manifest_done_) {
        state_ = kDfuIdle;
        return Report(0);
      } else {
        const BackendReply r = backend_->Manifest();
        manifest_done_ = true;
        if (!r.ok()) {
          Fail(r.status, r.message);
          return Report(0);
        }
        const uint32_t poll = Poll(r.poll_ms);
        state_ = kDfuManifest;
        deadline_ms_ = Now() + poll;
        return Report(poll);
      }

    case kDfuManifest:
    case kDfuManifestWaitReset:
    case kDfuUploadIdle:
      return StallError(setup);

    case kDfuError:
      if (req == kGetStatus) return Report(0);
      if (req == kClrStatus) {
        backend_->AbortDownload();
        status_ = kOk;
        error_.clear();
        state_ = kDfuIdle;
        return {};
      }
      return StallError(setup);
  }
  return StallError(setup);
}

DfuDevice::ResetAction DfuDevice::OnBusReset() {
  ApplyTimedTransitions(Now());
  if (state_ == kAppDetach) {
    state_ = kDfuIdle;
    status_ = kOk;
    error_.clear();
    return ResetAction::kEnterDfuMode;
  }
  if (state_ == kAppIdle) return ResetAction::kNone;
  backend_->AbortDownload();
  state_ = kAppIdle;
  status_ = kOk;
  error_.clear();
  return ResetAction::kReboot;
}

}  // namespace d3d::dfu
