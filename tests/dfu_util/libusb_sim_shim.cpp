// A stand-in for the part of libusb-1.0 that dfu-util (Debian's) calls, loaded with LD_PRELOAD,
// that presents the simulated probe behind D3D_SIM_SOCKET as one USB device: descriptors are read
// with GET_DESCRIPTOR control transfers over the sim link, every control transfer dfu-util makes is
// carried over it unchanged, libusb_reset_device is a bus reset. This lets dfu-util, the reference
// DFU client, talk to d3d-update-agent without USB hardware. Test-only.
#include <libusb-1.0/libusb.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <sys/un.h>
#include <unistd.h>

#include <cstdarg>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "firmware/update/dfu_protocol.h"
#include "firmware/update/sim_wire.h"

struct libusb_context {
  int unused = 0;
};
struct libusb_device {
  int refs = 1;
};
struct libusb_device_handle {
  libusb_device* dev = nullptr;
};

namespace {

using namespace d3d;

int g_fd = -1;
libusb_device g_device;

bool Connect() {
  if (g_fd >= 0) return true;
  const char* path = std::getenv("D3D_SIM_SOCKET");
  if (!path) return false;
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  std::strncpy(addr.sun_path, path, sizeof(addr.sun_path) - 1);
  for (int attempt = 0; attempt < 400; ++attempt) {  // up to 2 s while the probe reboots
    const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0) return false;
    if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) == 0) {
      timeval tv{10, 0};
      ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
      g_fd = fd;
      return true;
    }
    ::close(fd);
    ::usleep(5000);
  }
  return false;
}

void Disconnect() {
  if (g_fd >= 0) ::close(g_fd);
  g_fd = -1;
}

// One control transfer over the sim link: bytes received (IN) or sent (OUT), or a libusb error.
int Transfer(uint8_t type, uint8_t request, uint16_t value, uint16_t index, unsigned char* data,
             uint16_t length) {
  if (!Connect()) return LIBUSB_ERROR_NO_DEVICE;
  const dfu::SetupPacket s{type, request, value, index, length};
  const std::span<const uint8_t> out =
      s.is_in() ? std::span<const uint8_t>() : std::span<const uint8_t>(data, length);
  if (!dfu::WriteFull(g_fd, dfu::EncodeRequest(dfu::kKindControl, s, out)).ok()) {
    Disconnect();
    return LIBUSB_ERROR_NO_DEVICE;
  }
  uint8_t head[3];
  if (!dfu::ReadFull(g_fd, head).ok()) {
    Disconnect();
    return LIBUSB_ERROR_NO_DEVICE;
  }
  const size_t len = static_cast<size_t>(head[1] | (head[2] << 8));
  if (len > length || (len > 0 && !dfu::ReadFull(g_fd, std::span<uint8_t>(data, len)).ok())) {
    Disconnect();
    return LIBUSB_ERROR_IO;
  }
  if (head[0] == dfu::kResultStall) return LIBUSB_ERROR_PIPE;
  return s.is_in() ? static_cast<int>(len) : length;
}

int GetDescriptor(uint8_t type, uint8_t index, std::vector<uint8_t>* out, uint16_t length) {
  out->assign(length, 0);
  const int n = Transfer(0x80, dfu::kGetDescriptor, static_cast<uint16_t>(type << 8 | index), 0,
                         out->data(), length);
  if (n < 0) return n;
  out->resize(static_cast<size_t>(n));
  return n;
}

}  // namespace

extern "C" {

int LIBUSB_CALL libusb_init(libusb_context** ctx) {
  if (ctx) *ctx = new libusb_context;
  return 0;
}
void LIBUSB_CALL libusb_exit(libusb_context* ctx) {
  delete ctx;
  Disconnect();
}
int LIBUSB_CALL libusb_set_option(libusb_context*, enum libusb_option, ...) { return 0; }

const struct libusb_version* LIBUSB_CALL libusb_get_version(void) {
  static const libusb_version v = {1, 0, 26, 0, "", "d3dscan sim-link shim"};
  return &v;
}

const char* LIBUSB_CALL libusb_error_name(int code) {
  switch (code) {
    case LIBUSB_SUCCESS:
      return "LIBUSB_SUCCESS";
    case LIBUSB_ERROR_IO:
      return "LIBUSB_ERROR_IO";
    case LIBUSB_ERROR_NO_DEVICE:
      return "LIBUSB_ERROR_NO_DEVICE";
    case LIBUSB_ERROR_NOT_FOUND:
      return "LIBUSB_ERROR_NOT_FOUND";
    case LIBUSB_ERROR_PIPE:
      return "LIBUSB_ERROR_PIPE";
    case LIBUSB_ERROR_TIMEOUT:
      return "LIBUSB_ERROR_TIMEOUT";
    default:
      return "LIBUSB_ERROR_OTHER";
  }
}

ssize_t LIBUSB_CALL libusb_get_device_list(libusb_context*, libusb_device*** list) {
  // A fresh enumeration: reconnect (the probe may have re-enumerated after a reset).
  Disconnect();
  const bool present = Connect();
  auto** l = static_cast<libusb_device**>(std::calloc(2, sizeof(libusb_device*)));
  if (present) l[0] = &g_device;
  *list = l;
  return present ? 1 : 0;
}
void LIBUSB_CALL libusb_free_device_list(libusb_device** list, int) { std::free(list); }
libusb_device* LIBUSB_CALL libusb_ref_device(libusb_device* dev) { return dev; }
void LIBUSB_CALL libusb_unref_device(libusb_device*) {}
uint8_t LIBUSB_CALL libusb_get_bus_number(libusb_device*) { return 1; }
uint8_t LIBUSB_CALL libusb_get_device_address(libusb_device*) { return 2; }
int LIBUSB_CALL libusb_get_port_numbers(libusb_device*, uint8_t* ports, int len) {
  if (len < 1) return LIBUSB_ERROR_OVERFLOW;
  ports[0] = 1;
  return 1;
}

int LIBUSB_CALL libusb_get_device_descriptor(libusb_device*, struct libusb_device_descriptor* d) {
  std::vector<uint8_t> b;
  const int n = GetDescriptor(dfu::kDescDevice, 0, &b, 18);
  if (n < 18) return n < 0 ? n : LIBUSB_ERROR_IO;
  std::memcpy(d, b.data(), 18);  // the struct mirrors the wire layout (host is little-endian)
  return 0;
}

int LIBUSB_CALL libusb_get_config_descriptor(libusb_device*, uint8_t index,
                                             struct libusb_config_descriptor** config) {
  if (index != 0) return LIBUSB_ERROR_NOT_FOUND;
  std::vector<uint8_t> b;
  if (GetDescriptor(dfu::kDescConfiguration, 0, &b, 9) < 9) return LIBUSB_ERROR_IO;
  const uint16_t total = static_cast<uint16_t>(b[2] | (b[3] << 8));
  if (GetDescriptor(dfu::kDescConfiguration, 0, &b, total) < total) return LIBUSB_ERROR_IO;
  // One interface with one alternate setting; descriptors after it (DFU functional) go to `extra`.
  auto* cfg =
      static_cast<libusb_config_descriptor*>(std::calloc(1, sizeof(libusb_config_descriptor)));
  auto* intf = static_cast<libusb_interface*>(std::calloc(1, sizeof(libusb_interface)));
  auto* alt = static_cast<libusb_interface_descriptor*>(
      std::calloc(1, sizeof(libusb_interface_descriptor)));
  std::memcpy(cfg, b.data(), 9);
  cfg->interface = intf;
  intf->altsetting = alt;
  intf->num_altsetting = 1;
  size_t p = 9;
  for (; p + 2 <= b.size() && b[p] >= 2; p += b[p]) {
    if (b[p + 1] == dfu::kDescInterface) {
      std::memcpy(alt, &b[p], 9);
      p += b[p];
      break;
    }
  }
  const size_t extra = b.size() - std::min(p, b.size());
  auto* ex = static_cast<unsigned char*>(std::malloc(extra + 1));
  std::memcpy(ex, b.data() + std::min(p, b.size()), extra);
  alt->extra = ex;
  alt->extra_length = static_cast<int>(extra);
  *config = cfg;
  return 0;
}

int LIBUSB_CALL libusb_get_active_config_descriptor(libusb_device* dev,
                                                    struct libusb_config_descriptor** config) {
  return libusb_get_config_descriptor(dev, 0, config);
}

void LIBUSB_CALL libusb_free_config_descriptor(struct libusb_config_descriptor* cfg) {
  if (!cfg) return;
  auto* alt = const_cast<libusb_interface_descriptor*>(cfg->interface->altsetting);
  std::free(const_cast<unsigned char*>(alt->extra));
  std::free(alt);
  std::free(const_cast<libusb_interface*>(cfg->interface));
  std::free(cfg);
}

int LIBUSB_CALL libusb_open(libusb_device* dev, libusb_device_handle** h) {
  if (!Connect()) return LIBUSB_ERROR_NO_DEVICE;
  *h = new libusb_device_handle{dev};
  return 0;
}
void LIBUSB_CALL libusb_close(libusb_device_handle* h) { delete h; }
int LIBUSB_CALL libusb_claim_interface(libusb_device_handle*, int) { return 0; }
int LIBUSB_CALL libusb_release_interface(libusb_device_handle*, int) { return 0; }
int LIBUSB_CALL libusb_set_interface_alt_setting(libusb_device_handle*, int interface, int alt) {
  unsigned char none = 0;
  const int n =
      Transfer(0x01, 0x0B, static_cast<uint16_t>(alt), static_cast<uint16_t>(interface), &none, 0);
  return n < 0 ? n : 0;
}

int LIBUSB_CALL libusb_control_transfer(libusb_device_handle*, uint8_t type, uint8_t request,
                                        uint16_t value, uint16_t index, unsigned char* data,
                                        uint16_t length, unsigned int) {
  return Transfer(type, request, value, index, data, length);
}

int LIBUSB_CALL libusb_reset_device(libusb_device_handle*) {
  if (!Connect()) return LIBUSB_ERROR_NO_DEVICE;
  (void)dfu::WriteFull(g_fd, dfu::EncodeRequest(dfu::kKindBusReset, {}, {}));
  uint8_t head[3];
  (void)dfu::ReadFull(g_fd, head);
  Disconnect();
  return 0;
}

}  // extern "C"
