#include "firmware/update/sim_wire.h"

#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace d3d::dfu {

Status ReadFull(int fd, std::span<uint8_t> buf) {
  size_t done = 0;
  while (done < buf.size()) {
    const ssize_t n = ::recv(fd, buf.data() + done, buf.size() - done, 0);
    if (n == 0) return Unavailable("peer closed the link");
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EAGAIN || errno == EWOULDBLOCK)
        return Unavailable("timed out waiting for the peer");
      if (errno == ECONNRESET) return Unavailable("peer reset the link");
      return IoError(std::string("recv: ") + std::strerror(errno));
    }
    done += static_cast<size_t>(n);
  }
  return Status::Ok();
}

Status WriteFull(int fd, std::span<const uint8_t> buf) {
  size_t done = 0;
  while (done < buf.size()) {
    const ssize_t n = ::send(fd, buf.data() + done, buf.size() - done, MSG_NOSIGNAL);
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EPIPE || errno == ECONNRESET) return Unavailable("peer closed the link");
      return IoError(std::string("send: ") + std::strerror(errno));
    }
    done += static_cast<size_t>(n);
  }
  return Status::Ok();
}

std::vector<uint8_t> EncodeRequest(uint8_t kind, const SetupPacket& setup,
                                   std::span<const uint8_t> out_data) {
  std::vector<uint8_t> f;
  f.reserve(9 + out_data.size());
  f.push_back(kind);
  const auto s = setup.Encode();
  f.insert(f.end(), s.begin(), s.end());
  f.insert(f.end(), out_data.begin(), out_data.end());
  return f;
}

std::vector<uint8_t> EncodeResponse(bool stall, std::span<const uint8_t> in_data) {
  std::vector<uint8_t> f;
  f.reserve(3 + in_data.size());
  f.push_back(stall ? kResultStall : kResultAck);
  f.push_back(static_cast<uint8_t>(in_data.size()));
  f.push_back(static_cast<uint8_t>(in_data.size() >> 8));
  f.insert(f.end(), in_data.begin(), in_data.end());
  return f;
}

}  // namespace d3d::dfu
