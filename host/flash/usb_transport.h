// DfuTransport over libusb-1.0: the DFU class requests as USB control transfers to a real probe
// (libusb_control_transfer; a STALL is LIBUSB_ERROR_PIPE), bus reset with libusb_reset_device,
// and re-enumeration by VID:PID[:serial].
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "host/flash/dfu_transport.h"

struct libusb_context;
struct libusb_device_handle;

namespace d3d::flash {

struct UsbDeviceId {
  uint16_t vendor_id = 0;
  uint16_t product_id = 0;
  std::string serial;  // empty: any
  // Parses "VID:PID[:SERIAL]" (hex VID/PID). False when malformed.
  static bool Parse(const std::string& text, UsbDeviceId* out);
};

struct UsbDfuDevice {
  UsbDfuDevice() = default;
  UsbDeviceId id;
  uint8_t bus = 0, address = 0;
  uint8_t interface_number = 0;
  bool dfu_mode = false;  // interface protocol 2 (DFU mode) rather than 1 (run-time)
  std::string product;
};

class UsbTransport : public DfuTransport {
 public:
  // Every USB device exposing a DFU interface (class 0xFE, subclass 1). kUnavailable when libusb
  // cannot be initialised (no USB on this machine).
  static Status List(std::vector<UsbDfuDevice>* out);
  // Opens the device and claims its DFU interface. kNotFound when no such device is attached.
  static Status Open(const UsbDeviceId& id, std::unique_ptr<UsbTransport>* out);
  ~UsbTransport() override;

  ControlResult Control(const dfu::SetupPacket& setup, std::span<uint8_t> data) override;
  Status BusReset() override;
  Status Reopen(int timeout_ms) override;
  std::string Describe() const override;

 private:
  UsbTransport() = default;
  Status OpenMatching();
  void CloseHandle();
  libusb_context* ctx_ = nullptr;
  libusb_device_handle* handle_ = nullptr;
  UsbDeviceId id_;
  int interface_ = 0;
};

}  // namespace d3d::flash
