#include "firmware/update/sim_link_server.h"

#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "firmware/update/sim_wire.h"

namespace d3d::fw {

namespace {

struct Fd {
  int fd = -1;
  ~Fd() {
    if (fd >= 0) ::close(fd);
  }
};

// Serves one connected host until it disconnects or resets the bus. Returns false when the flash
// lost power (the probe is dead).
bool ServeClient(int fd, UpdateAgent* agent, const SimLinkServerOptions& o) {
  std::vector<uint8_t> data;
  data.reserve(65535);
  for (;;) {
    std::array<uint8_t, 9> head;
    if (!dfu::ReadFull(fd, head).ok()) return true;
    const dfu::SetupPacket setup =
        dfu::SetupPacket::Decode(std::span<const uint8_t, 8>(head.data() + 1, 8));
    if (head[0] == dfu::kKindBusReset) {
      (void)dfu::WriteFull(fd, dfu::EncodeResponse(false, {}));
      ::shutdown(fd, SHUT_RDWR);
      const Status s = agent->BusReset();
      if (agent->flash_dead()) return false;
      if (o.on_reset) o.on_reset(s);
      return true;
    }
    if (head[0] != dfu::kKindControl) return true;  // protocol error: drop the host
    data.assign(setup.is_in() ? 0 : setup.length, 0);
    if (!data.empty() && !dfu::ReadFull(fd, data).ok()) return true;
    const dfu::ControlResponse r = agent->HandleControl(setup, data);
    if (agent->flash_dead()) return false;  // power cut: no answer, like a dead device
    if (!dfu::WriteFull(fd, dfu::EncodeResponse(r.stall, r.data)).ok()) return true;
  }
}

}  // namespace

Status ServeSimLink(UpdateAgent* agent, const SimLinkServerOptions& o,
                    const std::atomic<bool>* stop) {
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  if (o.socket_path.empty() || o.socket_path.size() >= sizeof(addr.sun_path)) {
    return InvalidArgument("sim link: socket path empty or longer than " +
                           std::to_string(sizeof(addr.sun_path) - 1));
  }
  std::memcpy(addr.sun_path, o.socket_path.c_str(), o.socket_path.size() + 1);
  Fd listener;
  listener.fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (listener.fd < 0) return IoError(std::string("sim link: socket: ") + std::strerror(errno));
  ::unlink(o.socket_path.c_str());
  if (::bind(listener.fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0 ||
      ::listen(listener.fd, 4) != 0) {
    return IoError("sim link: cannot listen on " + o.socket_path + ": " + std::strerror(errno));
  }
  while (!stop->load()) {
    pollfd p{listener.fd, POLLIN, 0};
    const int n = ::poll(&p, 1, 100);
    if (n <= 0) continue;
    Fd client;
    client.fd = ::accept4(listener.fd, nullptr, nullptr, SOCK_CLOEXEC);
    if (client.fd < 0) continue;
    if (!ServeClient(client.fd, agent, o)) {
      if (o.on_power_cut) o.on_power_cut();
      ::unlink(o.socket_path.c_str());
      return Unavailable("flash lost power");
    }
  }
  ::unlink(o.socket_path.c_str());
  return Status::Ok();
}

}  // namespace d3d::fw
