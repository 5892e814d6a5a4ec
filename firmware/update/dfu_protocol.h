// USB Device Firmware Upgrade 1.1 constants shared by the probe's DFU device (firmware/update) and
// the host's DFU layer (host/flash), plus the d3dscan vendor requests and the sim link's wire
// format. Source: USB Device Class Specification for Device Firmware Upgrade, Version 1.1 (USB-IF,
// 2004): §3 Table 3.2 (requests), §4.1.3 / §4.2.4 Table 4.2 (functional descriptor), §6.1.2
// (GETSTATUS layout, status codes), Appendix A (state transition diagram and tables A.2.x).
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace d3d::dfu {

// bmRequestType values used by DFU (class request to an interface) and by our vendor requests.
inline constexpr uint8_t kRequestTypeClassOut = 0x21;    // host→device, class, interface
inline constexpr uint8_t kRequestTypeClassIn = 0xA1;     // device→host, class, interface
inline constexpr uint8_t kRequestTypeVendorOut = 0x41;   // host→device, vendor, interface
inline constexpr uint8_t kRequestTypeVendorIn = 0xC1;    // device→host, vendor, interface
inline constexpr uint8_t kRequestTypeStandardIn = 0x80;  // device→host, standard, device
inline constexpr uint8_t kDirectionIn = 0x80;

// DFU class requests (Table 3.2).
enum Request : uint8_t {
  kDetach = 0,
  kDnload = 1,
  kUpload = 2,
  kGetStatus = 3,
  kClrStatus = 4,
  kGetState = 5,
  kAbort = 6,
};

// Device states (§6.1.2, Appendix A).
enum State : uint8_t {
  kAppIdle = 0,
  kAppDetach = 1,
  kDfuIdle = 2,
  kDfuDnloadSync = 3,
  kDfuDnBusy = 4,
  kDfuDnloadIdle = 5,
  kDfuManifestSync = 6,
  kDfuManifest = 7,
  kDfuManifestWaitReset = 8,
  kDfuUploadIdle = 9,
  kDfuError = 10,
};

// bStatus values (§6.1.2).
enum DfuStatus : uint8_t {
  kOk = 0x00,
  kErrTarget = 0x01,       // file is not targeted for use by this device
  kErrFile = 0x02,         // file is for this device but fails a vendor-specific verification test
  kErrWrite = 0x03,        // device is unable to write memory
  kErrErase = 0x04,        // memory erase function failed
  kErrCheckErased = 0x05,  // memory erase check failed
  kErrProg = 0x06,         // program memory function failed
  kErrVerify = 0x07,       // programmed memory failed verification
  kErrAddress = 0x08,      // cannot program memory due to an address out of range
  kErrNotDone = 0x09,      // DNLOAD with wLength = 0, but the device does not have all the data yet
  kErrFirmware = 0x0A,     // device's firmware is corrupt; cannot return to run-time operation
  kErrVendor = 0x0B,       // iString indicates a vendor-specific error
  kErrUsbr = 0x0C,         // unexpected USB reset
  kErrPor = 0x0D,          // unexpected power-on reset
  kErrUnknown = 0x0E,      // something went wrong, the device does not know what
  kErrStalledPkt = 0x0F,   // device stalled an unexpected request
};

const char* StateName(uint8_t state);       // "dfuDNLOAD-IDLE"
const char* StatusName(uint8_t status);     // "errVERIFY"
const char* StatusMeaning(uint8_t status);  // the spec's one-line description

// DFU functional descriptor (Table 4.2), bDescriptorType 0x21, 9 bytes.
inline constexpr uint8_t kFunctionalDescriptorType = 0x21;
inline constexpr uint8_t kAttrCanDnload = 1 << 0;
inline constexpr uint8_t kAttrCanUpload = 1 << 1;
inline constexpr uint8_t kAttrManifestationTolerant = 1 << 2;
inline constexpr uint8_t kAttrWillDetach = 1 << 3;
inline constexpr uint8_t kInterfaceClassApp = 0xFE;  // application specific
inline constexpr uint8_t kInterfaceSubclassDfu = 0x01;
inline constexpr uint8_t kProtocolRuntime = 0x01;
inline constexpr uint8_t kProtocolDfuMode = 0x02;

struct FunctionalDescriptor {
  uint8_t attributes = 0;
  uint16_t detach_timeout_ms = 0;
  uint16_t transfer_size = 0;  // wTransferSize: maximum bytes per DNLOAD control write
  uint16_t dfu_version_bcd = 0x0110;
};

// USB standard descriptor types and requests used here.
inline constexpr uint8_t kGetDescriptor = 0x06;
inline constexpr uint8_t kDescDevice = 0x01;
inline constexpr uint8_t kDescConfiguration = 0x02;
inline constexpr uint8_t kDescString = 0x03;
inline constexpr uint8_t kDescInterface = 0x04;
inline constexpr uint16_t kLangEnUs = 0x0409;

// An 8-byte USB SETUP packet (USB 2.0 §9.3), little-endian on the wire.
struct SetupPacket {
  uint8_t request_type = 0;
  uint8_t request = 0;
  uint16_t value = 0;
  uint16_t index = 0;
  uint16_t length = 0;
  bool is_in() const { return (request_type & kDirectionIn) != 0; }
  std::array<uint8_t, 8> Encode() const;
  static SetupPacket Decode(std::span<const uint8_t, 8> bytes);
};

// DFU_GETSTATUS payload: bStatus, bwPollTimeout (24-bit ms, little-endian), bState, iString.
struct StatusReport {
  uint8_t status = kOk;
  uint32_t poll_timeout_ms = 0;  // < 2^24
  uint8_t state = kAppIdle;
  uint8_t string_index = 0;
  std::array<uint8_t, 6> Encode() const;
  static StatusReport Decode(std::span<const uint8_t, 6> bytes);
};

// d3dscan vendor requests (bmRequestType 0xC1 / 0x41, wIndex = DFU interface), valid in run-time
// and DFU mode.
enum VendorRequest : uint8_t {
  kVendorGetFirmwareInfo = 0x40,  // IN, FirmwareInfoWire (kFirmwareInfoBytes)
  kVendorSimSetStreaming = 0x41,  // OUT, wValue 1/0: the simulated probe starts/stops streaming
                                  // (only when the agent runs with simulation controls)
};

// Boot state of the running firmware as reported by kVendorGetFirmwareInfo.
enum class BootState : uint8_t {
  kUnknown = 0,
  kConfirmed = 1,   // running a confirmed slot
  kTrial = 2,       // running a new slot that has not confirmed its health check yet
  kRolledBack = 3,  // the last new slot failed its trial; running the previous one
  kFallback = 4,    // the active slot failed verification at boot; running the other one
};
const char* BootStateName(BootState s);

struct FirmwareInfo {
  uint16_t major = 0, minor = 0, patch = 0;
  uint8_t running_slot = 0;  // 0 = A, 1 = B
  BootState boot_state = BootState::kUnknown;
  bool streaming = false;
  bool dfu_mode = false;
  uint32_t hw_id = 0;
  uint32_t security_counter = 0;  // of the running image
  uint32_t security_floor = 0;    // the probe refuses images with a lower counter
  uint64_t slot_capacity_bytes = 0;
  std::string VersionString() const;
  std::vector<uint8_t> Encode() const;
  static bool Decode(std::span<const uint8_t> bytes, FirmwareInfo* out);
};
inline constexpr size_t kFirmwareInfoBytes = 32;

// String descriptor indices the probe serves.
inline constexpr uint8_t kStrManufacturer = 1;
inline constexpr uint8_t kStrProduct = 2;
inline constexpr uint8_t kStrSerial = 3;
inline constexpr uint8_t kStrInterface = 4;
inline constexpr uint8_t kStrLastError = 10;  // iString of a failed GETSTATUS: the exact reason

// Encodes an ASCII string as a USB string descriptor (UTF-16LE, ≤ 126 characters, longer ones cut).
std::vector<uint8_t> EncodeStringDescriptor(const std::string& ascii);
// Decodes a USB string descriptor into ASCII ('?' for code units above 0x7F). False when malformed.
bool DecodeStringDescriptor(std::span<const uint8_t> desc, std::string* out);

// --- Sim link wire format (a Unix stream socket carrying USB control transfers) ---------------
// Request:  u8 kind, then for kKindControl the 8-byte SETUP packet followed by wLength data bytes
//           when the request is OUT. kKindBusReset carries 8 zero bytes.
// Response: u8 result (kAck / kStall), u16 length (little-endian), then length bytes (IN data).
// After acknowledging kKindBusReset the device closes the connection (it re-enumerates); the host
// reconnects.
inline constexpr uint8_t kKindControl = 1;
inline constexpr uint8_t kKindBusReset = 2;
inline constexpr uint8_t kResultAck = 0;
inline constexpr uint8_t kResultStall = 1;

}  // namespace d3d::dfu
