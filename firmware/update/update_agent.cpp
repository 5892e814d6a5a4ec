#include "firmware/update/update_agent.h"

#include <cmath>

namespace d3d::fw {

using dfu::BackendReply;
using dfu::ControlResponse;
using dfu::SetupPacket;

namespace {
void Put16(std::vector<uint8_t>& v, uint16_t x) {
  v.push_back(static_cast<uint8_t>(x));
  v.push_back(static_cast<uint8_t>(x >> 8));
}
const char* SlotLetter(int s) { return s == 0 ? "A" : "B"; }
}  // namespace

UpdateAgent::UpdateAgent(Flash* flash, const PublicKey& trusted_key, UpdateAgentOptions options,
                         ProbeHooks* hooks)
    : flash_(flash),
      options_(std::move(options)),
      hooks_(hooks),
      slots_(flash, trusted_key, options_.slots),
      dfu_(this, options_.dfu) {
  D3D_CHECK_MSG(hooks_ != nullptr, "the update agent needs the probe's hooks");
}

Status UpdateAgent::PowerOn() {
  // Bounded: each pass either settles or uses up a trial boot / marks the trial slot failed.
  boot_log_.clear();
  for (int pass = 0; pass < options_.slots.trial_boots + 3; ++pass) {
    BootOutcome b;
    D3D_RETURN_IF_ERROR(slots_.Boot(&b));
    if (!boot_log_.empty()) boot_log_.append("; ");
    boot_log_.append(b.message);
    if (!b.booted) return NotFound("no bootable firmware: " + b.message);
    if (!slots_.on_trial()) {
      hooks_->OnRunningFirmware(Info());
      return Status::Ok();
    }
    const HealthResult h = hooks_->HealthCheck(b.header);
    if (h == HealthResult::kHealthy) {
      D3D_RETURN_IF_ERROR(slots_.Confirm());
      boot_log_.append("; health check passed: confirmed");
      hooks_->OnRunningFirmware(Info());
      return Status::Ok();
    }
    if (h == HealthResult::kUnhealthy) {
      boot_log_.append("; health check failed: reboot");
      D3D_RETURN_IF_ERROR(slots_.ReportHealthFailure());
    } else {
      boot_log_.append("; no health-check answer: watchdog reset");
    }
  }
  return Status(StatusCode::kInternal, "boot did not settle");
}

dfu::FirmwareInfo UpdateAgent::Info() const {
  dfu::FirmwareInfo f;
  const BootOutcome& b = slots_.running();
  f.major = b.header.version.major;
  f.minor = b.header.version.minor;
  f.patch = b.header.version.patch;
  f.running_slot = b.slot;
  switch (b.event) {
    case BootEvent::kUpdated:
      f.boot_state = dfu::BootState::kTrial;
      break;
    case BootEvent::kRolledBack:
      f.boot_state = dfu::BootState::kRolledBack;
      break;
    case BootEvent::kFallback:
      f.boot_state = dfu::BootState::kFallback;
      break;
    case BootEvent::kConfirmed:
    case BootEvent::kNone:
      f.boot_state = b.booted ? dfu::BootState::kConfirmed : dfu::BootState::kUnknown;
      break;
  }
  f.streaming = hooks_->IsStreaming();
  f.dfu_mode = dfu_.dfu_mode();
  f.hw_id = options_.slots.hw_id;
  f.security_counter = b.header.security_counter;
  f.security_floor = slots_.record() ? slots_.record()->security_floor : 0;
  f.slot_capacity_bytes = options_.slots.slot_bytes;
  return f;
}

std::vector<uint8_t> UpdateAgent::DeviceDescriptor() const {
  std::vector<uint8_t> d = {18, dfu::kDescDevice};
  Put16(d, 0x0200);                  // bcdUSB 2.0
  d.insert(d.end(), {0, 0, 0, 64});  // class/subclass/protocol per interface, EP0 max packet 64
  Put16(d, options_.vendor_id);
  Put16(d, options_.product_id);
  const auto& v = slots_.running().header.version;
  Put16(d, static_cast<uint16_t>(((v.major & 0xFF) << 8) | (v.minor & 0xFF)));  // bcdDevice
  d.insert(d.end(), {dfu::kStrManufacturer, dfu::kStrProduct, dfu::kStrSerial, 1});
  return d;
}

std::vector<uint8_t> UpdateAgent::ConfigurationDescriptor() const {
  std::vector<uint8_t> d = {9, dfu::kDescConfiguration};
  Put16(d, 27);
  d.insert(d.end(), {1, 1, 0, 0x80, 250});  // 1 interface, value 1, bus powered, 500 mA
  d.insert(d.end(),
           {9, dfu::kDescInterface, 0, 0, 0, dfu::kInterfaceClassApp, dfu::kInterfaceSubclassDfu,
            dfu_.dfu_mode() ? dfu::kProtocolDfuMode : dfu::kProtocolRuntime, dfu::kStrInterface});
  const dfu::FunctionalDescriptor f = dfu_.functional_descriptor();
  d.insert(d.end(), {9, dfu::kFunctionalDescriptorType, f.attributes});
  Put16(d, f.detach_timeout_ms);
  Put16(d, f.transfer_size);
  Put16(d, f.dfu_version_bcd);
  return d;
}

std::string UpdateAgent::StringDescriptorText(uint8_t index) const {
  const BootOutcome& b = slots_.running();
  switch (index) {
    case dfu::kStrManufacturer:
      return "d3dscan";
    case dfu::kStrProduct:
      return "d3dscan intraoral probe";
    case dfu::kStrSerial:
      return options_.serial;
    case dfu::kStrInterface: {
      std::string s = dfu_.dfu_mode() ? "d3dscan DFU, writing slot " : "d3dscan firmware ";
      if (dfu_.dfu_mode()) return s.append(SlotLetter(1 - b.slot));
      return s.append(b.header.version.ToString()).append(" slot ").append(SlotLetter(b.slot));
    }
    case dfu::kStrLastError:
      return dfu_.last_error();
    default:
      return {};
  }
}

ControlResponse UpdateAgent::HandleControl(const SetupPacket& setup,
                                           std::span<const uint8_t> out_data) {
  ControlResponse r;
  const uint8_t type = setup.request_type;
  if (type == dfu::kRequestTypeStandardIn && setup.request == dfu::kGetDescriptor) {
    const uint8_t dtype = static_cast<uint8_t>(setup.value >> 8),
                  index = static_cast<uint8_t>(setup.value);
    if (dtype == dfu::kDescDevice) {
      r.data = DeviceDescriptor();
    } else if (dtype == dfu::kDescConfiguration && index == 0) {
      r.data = ConfigurationDescriptor();
    } else if (dtype == dfu::kDescString && index == 0) {
      r.data = {4, dfu::kDescString, 0x09, 0x04};  // LANGID en-US
    } else if (dtype == dfu::kDescString) {
      const std::string text = StringDescriptorText(index);
      if (text.empty()) return {true, {}};
      r.data = dfu::EncodeStringDescriptor(text);
    } else {
      return {true, {}};
    }
  } else if ((type == 0x00 && setup.request == 0x09) || (type == 0x01 && setup.request == 0x0B)) {
    // SET_CONFIGURATION 1 / SET_INTERFACE alt 0: nothing to switch, acknowledged.
    if (setup.value > 1) return {true, {}};
    return {};
  } else if ((type == 0x80 || type == 0x81) && setup.request == 0x00) {
    r.data = {0, 0};  // GET_STATUS: bus powered, no remote wake-up
  } else if (type == 0x80 && setup.request == 0x08) {
    r.data = {1};  // GET_CONFIGURATION
  } else if ((type == dfu::kRequestTypeClassIn || type == dfu::kRequestTypeClassOut) &&
             setup.index == 0) {
    r = dfu_.Handle(setup, out_data);
  } else if (type == dfu::kRequestTypeVendorIn && setup.request == dfu::kVendorGetFirmwareInfo) {
    r.data = Info().Encode();
  } else if (type == dfu::kRequestTypeVendorOut && setup.request == dfu::kVendorSimSetStreaming) {
    if (!options_.sim_controls || dfu_.dfu_mode() || !hooks_->SimSetStreaming(setup.value != 0))
      return {true, {}};
    return {};
  } else {
    return {true, {}};
  }
  if (r.data.size() > setup.length) r.data.resize(setup.length);
  return r;
}

Status UpdateAgent::BusReset() {
  boot_log_.clear();
  switch (dfu_.OnBusReset()) {
    case dfu::DfuDevice::ResetAction::kNone:
      return Status::Ok();
    case dfu::DfuDevice::ResetAction::kEnterDfuMode:
      hooks_->OnDfuMode(true);
      return Status::Ok();
    case dfu::DfuDevice::ResetAction::kReboot:
      hooks_->OnDfuMode(false);
      return PowerOn();
  }
  return Status::Ok();
}

BackendReply UpdateAgent::FromUpdate(const UpdateResult& r) { return {r.dfu_status, r.message, 0}; }

BackendReply UpdateAgent::Detach() {
  if (hooks_->IsStreaming()) {
    return {dfu::kErrVendor, "streaming: the probe is streaming a scan; stop the scan, then update",
            0};
  }
  if (slots_.on_trial()) {
    return {dfu::kErrVendor, "busy: the running firmware has not confirmed its trial boot yet", 0};
  }
  return {};
}

BackendReply UpdateAgent::BeginDownload() { return FromUpdate(slots_.BeginUpdate()); }

BackendReply UpdateAgent::DownloadBlock(std::span<const uint8_t> data) {
  const double ms = slots_.ModelledWriteMs(data.size());
  BackendReply r = FromUpdate(slots_.WriteChunk(data));
  r.poll_ms = static_cast<uint32_t>(std::ceil(ms));
  return r;
}

bool UpdateAgent::DownloadComplete(std::string* why_not) {
  if (slots_.UpdateComplete()) return true;
  const uint64_t got = slots_.received_bytes(), want = slots_.expected_bytes();
  if (want == 0) {
    *why_not = std::string(RejectToken(Reject::kTooShort)) + ": " + std::to_string(got) +
               " bytes, a header needs 128";
  } else {
    *why_not = std::string(RejectToken(Reject::kTruncated)) + ": " + std::to_string(got) + " of " +
               std::to_string(want) + " bytes";
  }
  return false;
}

BackendReply UpdateAgent::Manifest() {
  const double ms = static_cast<double>(slots_.received_bytes()) / (options_.verify_mb_per_s * 1e3);
  BackendReply r = FromUpdate(slots_.FinishUpdate());
  r.poll_ms = static_cast<uint32_t>(std::ceil(ms));
  return r;
}

void UpdateAgent::AbortDownload() { slots_.AbortUpdate(); }

}  // namespace d3d::fw
