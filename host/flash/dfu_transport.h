// The link to one USB DFU device's default control pipe, as the host's DFU layer (dfu_host.h) needs
// it: control transfers, bus reset, finding the device again after it re-enumerates. Two
// implementations: UsbTransport (libusb, a real probe) and SimTransport (a Unix socket to the
// simulated probe's update agent, carrying the same SETUP packets and data).
#pragma once

#include <cstddef>
#include <span>
#include <string>

#include "common/core/status.h"
#include "firmware/update/dfu_protocol.h"

namespace d3d::flash {

struct ControlResult {
  Status status;         // not ok: the link failed (device gone, timeout)
  bool stalled = false;  // the device answered with a STALL handshake (request refused)
  size_t length = 0;     // bytes of the IN data stage received
  bool ok() const { return status.ok() && !stalled; }
};

class DfuTransport {
 public:
  virtual ~DfuTransport() = default;
  // One control transfer. OUT: sends data (setup.length bytes). IN: receives up to setup.length
  // bytes into data (data.size() ≥ setup.length).
  virtual ControlResult Control(const dfu::SetupPacket& setup, std::span<uint8_t> data) = 0;
  // USB bus reset. The device re-enumerates afterwards: call Reopen before the next transfer.
  virtual Status BusReset() = 0;
  // Finds and opens the same device again, waiting up to timeout_ms. kUnavailable when it does not
  // come back.
  virtual Status Reopen(int timeout_ms) = 0;
  // "sim:/tmp/probe.sock", "usb:1209:0010:SIM0001".
  virtual std::string Describe() const = 0;
};

}  // namespace d3d::flash
