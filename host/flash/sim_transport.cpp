#include "host/flash/sim_transport.h"

#include <sys/socket.h>
#include <sys/time.h>
#include <sys/un.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <thread>

#include "firmware/update/sim_wire.h"

namespace d3d::flash {

namespace {
constexpr int kControlTimeoutMs =
    10000;  // a control transfer's timeout (manifestation verifies 16 MiB)
}

Status SimTransport::Open(const std::string& socket_path, int timeout_ms,
                          std::unique_ptr<SimTransport>* out) {
  std::unique_ptr<SimTransport> t(new SimTransport(socket_path));
  D3D_RETURN_IF_ERROR(t->Connect(timeout_ms));
  *out = std::move(t);
  return Status::Ok();
}

SimTransport::~SimTransport() { Close(); }

void SimTransport::Close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

Status SimTransport::Connect(int timeout_ms) {
  Close();
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  if (path_.size() >= sizeof(addr.sun_path))
    return InvalidArgument("sim: socket path too long: " + path_);
  std::memcpy(addr.sun_path, path_.c_str(), path_.size() + 1);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
  for (;;) {
    const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0) return IoError("sim: socket() failed");
    if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) == 0) {
      timeval tv{kControlTimeoutMs / 1000, 0};
      ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
      fd_ = fd;
      return Status::Ok();
    }
    ::close(fd);
    if (std::chrono::steady_clock::now() >= deadline) {
      return Unavailable("sim: no simulated probe listens on " + path_ +
                         " (is d3d-update-agent running?)");
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

ControlResult SimTransport::Control(const dfu::SetupPacket& setup, std::span<uint8_t> data) {
  ControlResult r;
  if (fd_ < 0) {
    r.status = Unavailable("sim: not connected");
    return r;
  }
  const std::span<const uint8_t> out = setup.is_in()
                                           ? std::span<const uint8_t>()
                                           : std::span<const uint8_t>(data.data(), setup.length);
  frame_ = dfu::EncodeRequest(dfu::kKindControl, setup, out);
  if (r.status = dfu::WriteFull(fd_, frame_); !r.status.ok()) {
    r.status = Unavailable("sim: probe link lost (" + r.status.message() + ")");
    return r;
  }
  std::array<uint8_t, 3> head;
  if (r.status = dfu::ReadFull(fd_, head); !r.status.ok()) {
    r.status = Unavailable("sim: probe link lost (" + r.status.message() + ")");
    return r;
  }
  const size_t len = static_cast<size_t>(head[1] | (head[2] << 8));
  if (len > setup.length || (!setup.is_in() && len > 0)) {
    r.status = IoError("sim: the probe answered " + std::to_string(len) + " bytes to a " +
                       std::to_string(setup.length) + "-byte request");
    return r;
  }
  if (len > 0 && !(r.status = dfu::ReadFull(fd_, data.first(len))).ok()) {
    r.status = Unavailable("sim: probe link lost (" + r.status.message() + ")");
    return r;
  }
  r.stalled = head[0] == dfu::kResultStall;
  r.length = len;
  return r;
}

Status SimTransport::BusReset() {
  if (fd_ < 0) return Unavailable("sim: not connected");
  const Status s = dfu::WriteFull(fd_, dfu::EncodeRequest(dfu::kKindBusReset, {}, {}));
  std::array<uint8_t, 3> head;
  if (s.ok()) (void)dfu::ReadFull(fd_, head);
  Close();  // the device re-enumerates
  return s.ok() ? Status::Ok() : Unavailable("sim: probe link lost during reset");
}

Status SimTransport::Reopen(int timeout_ms) { return Connect(timeout_ms); }

}  // namespace d3d::flash
