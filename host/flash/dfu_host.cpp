#include "host/flash/dfu_host.h"

#include <chrono>
#include <thread>

namespace d3d::flash {

using namespace d3d::dfu;

namespace {
double Seconds(std::chrono::steady_clock::time_point a, std::chrono::steady_clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}
}  // namespace

const char* FlashOutcomeName(FlashOutcome o) {
  switch (o) {
    case FlashOutcome::kUpdated:
      return "UPDATED";
    case FlashOutcome::kRefused:
      return "REFUSED";
    case FlashOutcome::kRolledBack:
      return "ROLLED BACK";
    case FlashOutcome::kDryRun:
      return "DRY RUN";
    case FlashOutcome::kLinkLost:
      return "LINK LOST";
    case FlashOutcome::kError:
      return "ERROR";
  }
  return "?";
}

ControlResult DfuHost::In(uint8_t type, uint8_t request, uint16_t value, uint16_t length,
                          std::vector<uint8_t>* out) {
  out->assign(length, 0);
  const uint16_t index =
      type == kRequestTypeStandardIn
          ? (request == kGetDescriptor && (value >> 8) == kDescString && (value & 0xFF) != 0
                 ? kLangEnUs
                 : 0)
          : interface_;
  ControlResult r = t_->Control({type, request, value, index, length}, *out);
  ++transfers_;
  out->resize(r.ok() ? r.length : 0);
  return r;
}

ControlResult DfuHost::Out(uint8_t type, uint8_t request, uint16_t value,
                           std::span<const uint8_t> data) {
  scratch_.assign(data.begin(), data.end());
  ControlResult r =
      t_->Control({type, request, value, interface_, static_cast<uint16_t>(data.size())}, scratch_);
  ++transfers_;
  return r;
}

Status DfuHost::Check(const ControlResult& r, const char* what) {
  if (!r.status.ok()) return r.status;
  if (r.stalled) return Unsupported(std::string(what) + ": stalled by the device");
  return Status::Ok();
}

Status DfuHost::ReadDescriptors(DfuDeviceInfo* out) {
  DfuDeviceInfo info;
  std::vector<uint8_t> d;
  D3D_RETURN_IF_ERROR(Check(In(kRequestTypeStandardIn, kGetDescriptor, kDescDevice << 8, 18, &d),
                            "GET_DESCRIPTOR(device)"));
  if (d.size() < 18 || d[1] != kDescDevice) return ParseError("device descriptor malformed");
  info.vendor_id = static_cast<uint16_t>(d[8] | (d[9] << 8));
  info.product_id = static_cast<uint16_t>(d[10] | (d[11] << 8));
  const uint8_t i_product = d[15], i_serial = d[16];
  D3D_RETURN_IF_ERROR(
      Check(In(kRequestTypeStandardIn, kGetDescriptor, kDescConfiguration << 8, 9, &d),
            "GET_DESCRIPTOR(config)"));
  if (d.size() < 9 || d[1] != kDescConfiguration)
    return ParseError("configuration descriptor malformed");
  const uint16_t total = static_cast<uint16_t>(d[2] | (d[3] << 8));
  D3D_RETURN_IF_ERROR(
      Check(In(kRequestTypeStandardIn, kGetDescriptor, kDescConfiguration << 8, total, &d),
            "GET_DESCRIPTOR(config)"));
  bool in_dfu_interface = false, found = false, have_functional = false;
  for (size_t p = 0; p + 2 <= d.size() && d[p] >= 2 && p + d[p] <= d.size(); p += d[p]) {
    const uint8_t len = d[p], type = d[p + 1];
    if (type == kDescInterface && len >= 9) {
      in_dfu_interface = d[p + 5] == kInterfaceClassApp && d[p + 6] == kInterfaceSubclassDfu;
      if (in_dfu_interface && !found) {
        found = true;
        info.interface_number = d[p + 2];
        info.dfu_mode = d[p + 7] == kProtocolDfuMode;
      }
    } else if (type == kFunctionalDescriptorType && len >= 7 && in_dfu_interface &&
               !have_functional) {
      have_functional = true;
      info.functional.attributes = d[p + 2];
      info.functional.detach_timeout_ms = static_cast<uint16_t>(d[p + 3] | (d[p + 4] << 8));
      info.functional.transfer_size = static_cast<uint16_t>(d[p + 5] | (d[p + 6] << 8));
      info.functional.dfu_version_bcd =
          len >= 9 ? static_cast<uint16_t>(d[p + 7] | (d[p + 8] << 8)) : 0x0100;
    }
  }
  if (!found) return NotFound("the device has no DFU interface");
  if (!have_functional || info.functional.transfer_size == 0)
    return ParseError("no usable DFU functional descriptor");
  interface_ = info.interface_number;
  manifestation_tolerant_ = (info.functional.attributes & kAttrManifestationTolerant) != 0;
  (void)GetString(i_serial, &info.serial);
  (void)GetString(i_product, &info.product);
  *out = info;
  return Status::Ok();
}

Status DfuHost::GetString(uint8_t index, std::string* out) {
  out->clear();
  if (index == 0) return Status::Ok();
  std::vector<uint8_t> d;
  D3D_RETURN_IF_ERROR(Check(In(kRequestTypeStandardIn, kGetDescriptor,
                               static_cast<uint16_t>(kDescString << 8 | index), 255, &d),
                            "GET_DESCRIPTOR(string)"));
  if (!DecodeStringDescriptor(d, out)) return ParseError("string descriptor malformed");
  return Status::Ok();
}

Status DfuHost::GetStatus(StatusReport* out) {
  std::vector<uint8_t> d;
  D3D_RETURN_IF_ERROR(Check(In(kRequestTypeClassIn, kGetStatus, 0, 6, &d), "DFU_GETSTATUS"));
  if (d.size() != 6)
    return ParseError("DFU_GETSTATUS returned " + std::to_string(d.size()) + " bytes, not 6");
  *out = StatusReport::Decode(std::span<const uint8_t, 6>(d.data(), 6));
  return Status::Ok();
}

Status DfuHost::GetState(uint8_t* out) {
  std::vector<uint8_t> d;
  D3D_RETURN_IF_ERROR(Check(In(kRequestTypeClassIn, kGetState, 0, 1, &d), "DFU_GETSTATE"));
  if (d.size() != 1) return ParseError("DFU_GETSTATE returned no byte");
  *out = d[0];
  return Status::Ok();
}

Status DfuHost::Detach(uint16_t timeout_ms) {
  return Check(Out(kRequestTypeClassOut, kDetach, timeout_ms, {}), "DFU_DETACH");
}
Status DfuHost::Dnload(uint16_t block, std::span<const uint8_t> data) {
  return Check(Out(kRequestTypeClassOut, kDnload, block, data), "DFU_DNLOAD");
}
Status DfuHost::ClrStatus() {
  return Check(Out(kRequestTypeClassOut, kClrStatus, 0, {}), "DFU_CLRSTATUS");
}
Status DfuHost::Abort() { return Check(Out(kRequestTypeClassOut, kAbort, 0, {}), "DFU_ABORT"); }

Status DfuHost::GetFirmwareInfo(FirmwareInfo* out) {
  std::vector<uint8_t> d;
  D3D_RETURN_IF_ERROR(
      Check(In(kRequestTypeVendorIn, kVendorGetFirmwareInfo, 0, kFirmwareInfoBytes, &d),
            "GET_FIRMWARE_INFO"));
  if (!FirmwareInfo::Decode(d, out)) return ParseError("firmware info malformed");
  return Status::Ok();
}

Status DfuHost::SetSimStreaming(bool on) {
  return Check(Out(kRequestTypeVendorOut, kVendorSimSetStreaming, on ? 1 : 0, {}),
               "SIM_SET_STREAMING");
}

Status DfuHost::PollWhileBusy(StatusReport* out) {
  for (;;) {
    D3D_RETURN_IF_ERROR(GetStatus(out));
    if (out->state != kDfuDnBusy && out->state != kDfuManifest) return Status::Ok();
    // The host waits bwPollTimeout before its next request (§6.1.2); then dfuDNBUSY becomes
    // dfuDNLOAD-SYNC and dfuMANIFEST becomes dfuMANIFEST-SYNC (manifestation tolerant).
    if (out->poll_timeout_ms > 0)
      std::this_thread::sleep_for(std::chrono::milliseconds(out->poll_timeout_ms));
    poll_wait_ms_ += out->poll_timeout_ms;
    if (out->state == kDfuManifest && !manifestation_tolerant_) {
      out->state = kDfuManifestWaitReset;  // such a device answers nothing but a reset now
      return Status::Ok();
    }
  }
}

std::string DfuHost::DescribeError(const StatusReport& r) {
  std::string text;
  if (r.string_index != 0) (void)GetString(r.string_index, &text);
  if (text.empty()) text = StatusMeaning(r.status);
  return text;
}

FlashReport FlashImage(DfuTransport* t, std::span<const uint8_t> image, const FlashOptions& o) {
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  FlashReport rep;
  DfuHost host(t);
  auto finish = [&](FlashOutcome outcome, std::string reason) {
    rep.outcome = outcome;
    if (!reason.empty()) rep.reason = std::move(reason);
    rep.control_transfers = host.control_transfers();
    rep.poll_wait_ms = host.poll_wait_ms();
    rep.total_s = Seconds(t0, Clock::now());
    return rep;
  };
  auto link_lost = [&](const Status& s) {
    return finish(
        s.code() == StatusCode::kUnavailable ? FlashOutcome::kLinkLost : FlashOutcome::kError,
        s.ToString());
  };
  // Back to run-time mode and read what the probe runs now.
  auto back_to_runtime = [&]() -> Status {
    D3D_RETURN_IF_ERROR(t->BusReset());
    D3D_RETURN_IF_ERROR(t->Reopen(o.reconnect_timeout_ms));
    D3D_RETURN_IF_ERROR(host.ReadDescriptors(&rep.device));
    D3D_RETURN_IF_ERROR(host.GetFirmwareInfo(&rep.after));
    rep.have_after = true;
    return Status::Ok();
  };
  auto refuse = [&](const StatusReport& st) {
    rep.dfu_status = st.status;
    rep.reason = host.DescribeError(st);
    (void)host.ClrStatus();
    const Status s = back_to_runtime();
    if (!s.ok()) return link_lost(s);
    return finish(FlashOutcome::kRefused, "");
  };

  if (Status s = host.ReadDescriptors(&rep.device); !s.ok()) return link_lost(s);
  if (Status s = host.GetFirmwareInfo(&rep.before); !s.ok()) return link_lost(s);
  if (o.on_connected) o.on_connected(rep.device, rep.before);
  if (o.dry_run) return finish(FlashOutcome::kDryRun, "");

  // Into DFU mode.
  StatusReport st;
  if (!rep.device.dfu_mode) {
    const Status s = host.Detach(rep.device.functional.detach_timeout_ms);
    if (s.code() ==
        StatusCode::kUnsupported) {  // stalled: the probe refuses to leave run-time mode
      if (Status g = host.GetStatus(&st); !g.ok()) return link_lost(g);
      rep.dfu_status = st.status;
      rep.reason = host.DescribeError(st);
      if (host.GetFirmwareInfo(&rep.after).ok()) rep.have_after = true;
      return finish(FlashOutcome::kRefused, "");
    }
    if (!s.ok()) return link_lost(s);
    if (!(rep.device.functional.attributes & kAttrWillDetach)) {
      if (Status r = t->BusReset(); !r.ok()) return link_lost(r);
    }
    if (Status r = t->Reopen(o.reconnect_timeout_ms); !r.ok()) return link_lost(r);
    DfuDeviceInfo dfu_info;
    if (Status r = host.ReadDescriptors(&dfu_info); !r.ok()) return link_lost(r);
    if (!dfu_info.dfu_mode)
      return finish(FlashOutcome::kError, "the probe did not enter DFU mode after DFU_DETACH");
    rep.device.functional = dfu_info.functional;
  }
  if (Status s = host.GetStatus(&st); !s.ok()) return link_lost(s);
  if (st.state == kDfuError) {
    if (Status s = host.ClrStatus(); !s.ok()) return link_lost(s);
  } else if (st.state != kDfuIdle) {
    if (Status s = host.Abort(); !s.ok()) return link_lost(s);
  }

  // Download.
  const auto td = Clock::now();
  const size_t block = rep.device.functional.transfer_size;
  const int64_t before_dl = host.control_transfers();
  uint16_t n = 0;
  for (size_t off = 0; off < image.size(); off += block, ++n) {
    if (o.stop_after_blocks >= 0 && rep.blocks >= o.stop_after_blocks) {
      return finish(FlashOutcome::kLinkLost,
                    "transfer stopped after block " + std::to_string(rep.blocks));
    }
    const auto chunk = image.subspan(off, std::min(block, image.size() - off));
    const Status s = host.Dnload(n, chunk);
    if (s.code() == StatusCode::kUnsupported) {
      if (Status g = host.GetStatus(&st); !g.ok()) return link_lost(g);
      return refuse(st);
    }
    if (!s.ok()) return link_lost(s);
    if (Status p = host.PollWhileBusy(&st); !p.ok()) return link_lost(p);
    if (st.state == kDfuError) return refuse(st);
    if (st.state != kDfuDnloadIdle) {
      return finish(FlashOutcome::kError,
                    std::string("unexpected state ") + StateName(st.state) + " after a block");
    }
    ++rep.blocks;
    rep.bytes += chunk.size();
    if (o.progress) o.progress(rep.bytes, image.size());
  }
  rep.download_transfers = host.control_transfers() - before_dl;
  rep.download_s = Seconds(td, Clock::now());

  // Manifestation: end of image, the probe verifies and marks the slot.
  const auto tm = Clock::now();
  {
    const Status s = host.Dnload(n, {});
    if (s.code() == StatusCode::kUnsupported) {
      if (Status g = host.GetStatus(&st); !g.ok()) return link_lost(g);
      return refuse(st);
    }
    if (!s.ok()) return link_lost(s);
  }
  if (Status p = host.PollWhileBusy(&st); !p.ok()) return link_lost(p);
  if (st.state == kDfuManifestSync) {
    if (Status p = host.PollWhileBusy(&st); !p.ok()) return link_lost(p);
  }
  if (st.state == kDfuError) return refuse(st);
  if (st.state != kDfuIdle && st.state != kDfuManifestWaitReset) {
    return finish(FlashOutcome::kError,
                  std::string("unexpected state ") + StateName(st.state) + " after manifestation");
  }
  rep.manifest_s = Seconds(tm, Clock::now());

  // Reboot into the new slot: trial boot, health check, confirm or roll back.
  const auto tr = Clock::now();
  if (Status s = back_to_runtime(); !s.ok()) return link_lost(s);
  rep.reboot_s = Seconds(tr, Clock::now());
  const FirmwareInfo& a = rep.after;
  if (a.boot_state == BootState::kRolledBack) {
    return finish(FlashOutcome::kRolledBack,
                  "the new firmware did not confirm its health check; the probe rolled back to " +
                      a.VersionString());
  }
  if (a.boot_state == BootState::kConfirmed && a.running_slot != rep.before.running_slot) {
    return finish(FlashOutcome::kUpdated, "");
  }
  return finish(FlashOutcome::kError, std::string("after the reboot the probe runs ") +
                                          a.VersionString() + " (" + BootStateName(a.boot_state) +
                                          ")");
}

}  // namespace d3d::flash
