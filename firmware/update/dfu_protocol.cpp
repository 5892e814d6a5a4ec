#include "firmware/update/dfu_protocol.h"

#include <cstring>

#include "firmware/update/little_endian.h"

namespace d3d::dfu {

const char* StateName(uint8_t state) {
  switch (state) {
    case kAppIdle:
      return "appIDLE";
    case kAppDetach:
      return "appDETACH";
    case kDfuIdle:
      return "dfuIDLE";
    case kDfuDnloadSync:
      return "dfuDNLOAD-SYNC";
    case kDfuDnBusy:
      return "dfuDNBUSY";
    case kDfuDnloadIdle:
      return "dfuDNLOAD-IDLE";
    case kDfuManifestSync:
      return "dfuMANIFEST-SYNC";
    case kDfuManifest:
      return "dfuMANIFEST";
    case kDfuManifestWaitReset:
      return "dfuMANIFEST-WAIT-RESET";
    case kDfuUploadIdle:
      return "dfuUPLOAD-IDLE";
    case kDfuError:
      return "dfuERROR";
  }
  return "state?";
}

const char* StatusName(uint8_t status) {
  switch (status) {
    case kOk:
      return "OK";
    case kErrTarget:
      return "errTARGET";
    case kErrFile:
      return "errFILE";
    case kErrWrite:
      return "errWRITE";
    case kErrErase:
      return "errERASE";
    case kErrCheckErased:
      return "errCHECK_ERASED";
    case kErrProg:
      return "errPROG";
    case kErrVerify:
      return "errVERIFY";
    case kErrAddress:
      return "errADDRESS";
    case kErrNotDone:
      return "errNOTDONE";
    case kErrFirmware:
      return "errFIRMWARE";
    case kErrVendor:
      return "errVENDOR";
    case kErrUsbr:
      return "errUSBR";
    case kErrPor:
      return "errPOR";
    case kErrUnknown:
      return "errUNKNOWN";
    case kErrStalledPkt:
      return "errSTALLEDPKT";
  }
  return "err?";
}

const char* StatusMeaning(uint8_t status) {
  switch (status) {
    case kOk:
      return "no error";
    case kErrTarget:
      return "file is not targeted for use by this device";
    case kErrFile:
      return "file is for this device but fails a verification test";
    case kErrWrite:
      return "device is unable to write memory";
    case kErrErase:
      return "memory erase function failed";
    case kErrCheckErased:
      return "memory erase check failed";
    case kErrProg:
      return "program memory function failed";
    case kErrVerify:
      return "programmed memory failed verification";
    case kErrAddress:
      return "address out of range";
    case kErrNotDone:
      return "device does not have all of the data yet";
    case kErrFirmware:
      return "device firmware is corrupt";
    case kErrVendor:
      return "vendor-specific error (see iString)";
    case kErrUsbr:
      return "unexpected USB reset";
    case kErrPor:
      return "unexpected power-on reset";
    case kErrUnknown:
      return "unknown error";
    case kErrStalledPkt:
      return "device stalled an unexpected request";
  }
  return "unknown status";
}

const char* BootStateName(BootState s) {
  switch (s) {
    case BootState::kUnknown:
      return "unknown";
    case BootState::kConfirmed:
      return "confirmed";
    case BootState::kTrial:
      return "trial";
    case BootState::kRolledBack:
      return "rolled back";
    case BootState::kFallback:
      return "fallback";
  }
  return "unknown";
}

std::array<uint8_t, 8> SetupPacket::Encode() const {
  return {request_type,
          request,
          static_cast<uint8_t>(value),
          static_cast<uint8_t>(value >> 8),
          static_cast<uint8_t>(index),
          static_cast<uint8_t>(index >> 8),
          static_cast<uint8_t>(length),
          static_cast<uint8_t>(length >> 8)};
}

SetupPacket SetupPacket::Decode(std::span<const uint8_t, 8> b) {
  SetupPacket s;
  s.request_type = b[0];
  s.request = b[1];
  s.value = static_cast<uint16_t>(b[2] | (b[3] << 8));
  s.index = static_cast<uint16_t>(b[4] | (b[5] << 8));
  s.length = static_cast<uint16_t>(b[6] | (b[7] << 8));
  return s;
}

std::array<uint8_t, 6> StatusReport::Encode() const {
  return {status,
          static_cast<uint8_t>(poll_timeout_ms),
          static_cast<uint8_t>(poll_timeout_ms >> 8),
          static_cast<uint8_t>(poll_timeout_ms >> 16),
          state,
          string_index};
}

StatusReport StatusReport::Decode(std::span<const uint8_t, 6> b) {
  StatusReport r;
  r.status = b[0];
  r.poll_timeout_ms = static_cast<uint32_t>(b[1]) | (static_cast<uint32_t>(b[2]) << 8) |
                      (static_cast<uint32_t>(b[3]) << 16);
  r.state = b[4];
  r.string_index = b[5];
  return r;
}

std::string FirmwareInfo::VersionString() const {
  std::string s = std::to_string(major);
  s.append(".").append(std::to_string(minor)).append(".").append(std::to_string(patch));
  return s;
}

// Layout: 0 u8 layout version (1), 1 running slot, 2 boot state, 3 flags (bit0 streaming, bit1 DFU
// mode), 4..9 major/minor/patch u16, 10..11 reserved, 12 hw id u32, 16 security counter u32,
// 20 security floor u32, 24 slot capacity in 4 KiB units u32, 28..31 reserved.
std::vector<uint8_t> FirmwareInfo::Encode() const {
  std::vector<uint8_t> v(kFirmwareInfoBytes, 0);
  v[0] = 1;
  v[1] = running_slot;
  v[2] = static_cast<uint8_t>(boot_state);
  v[3] = static_cast<uint8_t>((streaming ? 1 : 0) | (dfu_mode ? 2 : 0));
  fw::PutLe16(&v[4], major);
  fw::PutLe16(&v[6], minor);
  fw::PutLe16(&v[8], patch);
  fw::PutLe32(&v[12], hw_id);
  fw::PutLe32(&v[16], security_counter);
  fw::PutLe32(&v[20], security_floor);
  fw::PutLe32(&v[24], static_cast<uint32_t>(slot_capacity_bytes / 4096));
  return v;
}

bool FirmwareInfo::Decode(std::span<const uint8_t> v, FirmwareInfo* out) {
  if (v.size() < kFirmwareInfoBytes || v[0] != 1 || v[2] > 4) return false;
  FirmwareInfo f;
  f.running_slot = v[1];
  f.boot_state = static_cast<BootState>(v[2]);
  f.streaming = (v[3] & 1) != 0;
  f.dfu_mode = (v[3] & 2) != 0;
  f.major = fw::GetLe16(&v[4]);
  f.minor = fw::GetLe16(&v[6]);
  f.patch = fw::GetLe16(&v[8]);
  f.hw_id = fw::GetLe32(&v[12]);
  f.security_counter = fw::GetLe32(&v[16]);
  f.security_floor = fw::GetLe32(&v[20]);
  f.slot_capacity_bytes = static_cast<uint64_t>(fw::GetLe32(&v[24])) * 4096;
  *out = f;
  return true;
}

std::vector<uint8_t> EncodeStringDescriptor(const std::string& ascii) {
  const size_t n = std::min<size_t>(ascii.size(), 126);
  std::vector<uint8_t> d(2 + 2 * n);
  d[0] = static_cast<uint8_t>(d.size());
  d[1] = kDescString;
  for (size_t i = 0; i < n; ++i) {
    d[2 + 2 * i] = static_cast<uint8_t>(ascii[i]);
    d[3 + 2 * i] = 0;
  }
  return d;
}

bool DecodeStringDescriptor(std::span<const uint8_t> d, std::string* out) {
  if (d.size() < 2 || d[1] != kDescString || d[0] < 2 || d[0] > d.size() || d[0] % 2 != 0)
    return false;
  out->clear();
  for (size_t i = 2; i + 1 < d[0]; i += 2) {
    const uint16_t u = static_cast<uint16_t>(d[i] | (d[i + 1] << 8));
    out->push_back(u < 0x80 ? static_cast<char>(u) : '?');
  }
  return true;
}

}  // namespace d3d::dfu
