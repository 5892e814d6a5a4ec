// DfuTransport over the sim link: a Unix stream socket to d3d-update-agent carrying USB control
// transfers and bus resets (frame format in firmware/update/dfu_protocol.h).
#pragma once

#include <memory>
#include <string>

#include "host/flash/dfu_transport.h"

namespace d3d::flash {

class SimTransport : public DfuTransport {
 public:
  // Connects to the agent's socket, retrying up to timeout_ms. kUnavailable when nothing listens.
  static Status Open(const std::string& socket_path, int timeout_ms,
                     std::unique_ptr<SimTransport>* out);
  ~SimTransport() override;

  ControlResult Control(const dfu::SetupPacket& setup, std::span<uint8_t> data) override;
  Status BusReset() override;
  Status Reopen(int timeout_ms) override;
  std::string Describe() const override { return "sim:" + path_; }

 private:
  explicit SimTransport(std::string path) : path_(std::move(path)) {}
  Status Connect(int timeout_ms);
  void Close();
  std::string path_;
  int fd_ = -1;
  std::vector<uint8_t> frame_;  // reused request buffer
};

}  // namespace d3d::flash
