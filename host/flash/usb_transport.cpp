#include "host/flash/usb_transport.h"

#include <libusb-1.0/libusb.h>

#include <chrono>
#include <cstdio>
#include <thread>

namespace d3d::flash {

namespace {

constexpr unsigned kUsbControlTimeoutMs = 10000;

std::string UsbError(int rc) { return libusb_error_name(rc); }

// The DFU interface of a device's active (or first) configuration; false when it has none.
bool FindDfuInterface(libusb_device* dev, uint8_t* number, bool* dfu_mode) {
  libusb_config_descriptor* cfg = nullptr;
  if (libusb_get_active_config_descriptor(dev, &cfg) != 0 &&
      libusb_get_config_descriptor(dev, 0, &cfg) != 0) {
    return false;
  }
  bool found = false;
  for (int i = 0; i < cfg->bNumInterfaces && !found; ++i) {
    for (int a = 0; a < cfg->interface[i].num_altsetting; ++a) {
      const libusb_interface_descriptor& d = cfg->interface[i].altsetting[a];
      if (d.bInterfaceClass == dfu::kInterfaceClassApp &&
          d.bInterfaceSubClass == dfu::kInterfaceSubclassDfu) {
        *number = d.bInterfaceNumber;
        *dfu_mode = d.bInterfaceProtocol == dfu::kProtocolDfuMode;
        found = true;
        break;
      }
    }
  }
  libusb_free_config_descriptor(cfg);
  return found;
}

std::string ReadStringDescriptor(libusb_device_handle* h, uint8_t index) {
  if (index == 0) return {};
  unsigned char buf[256];
  const int n = libusb_get_string_descriptor_ascii(h, index, buf, sizeof(buf));
  return n > 0 ? std::string(reinterpret_cast<char*>(buf), static_cast<size_t>(n)) : std::string();
}

Status Init(libusb_context** ctx) {
  const int rc = libusb_init(ctx);
  if (rc != 0)
    return Unavailable("libusb cannot be initialised (" + UsbError(rc) +
                       "): no USB access on this machine");
  return Status::Ok();
}

}  // namespace

bool UsbDeviceId::Parse(const std::string& text, UsbDeviceId* out) {
  unsigned vid = 0, pid = 0;
  int consumed = 0;
  if (std::sscanf(text.c_str(), "%x:%x%n", &vid, &pid, &consumed) != 2 || vid > 0xFFFF ||
      pid > 0xFFFF)
    return false;
  UsbDeviceId id;
  id.vendor_id = static_cast<uint16_t>(vid);
  id.product_id = static_cast<uint16_t>(pid);
  const std::string rest = text.substr(static_cast<size_t>(consumed));
  if (!rest.empty()) {
    if (rest[0] != ':' || rest.size() == 1) return false;
    id.serial = rest.substr(1);
  }
  *out = id;
  return true;
}

Status UsbTransport::List(std::vector<UsbDfuDevice>* out) {
  out->clear();
  libusb_context* ctx = nullptr;
  D3D_RETURN_IF_ERROR(Init(&ctx));
  libusb_device** list = nullptr;
  const ssize_t n = libusb_get_device_list(ctx, &list);
  for (ssize_t i = 0; i < n; ++i) {
    libusb_device_descriptor dd{};
    if (libusb_get_device_descriptor(list[i], &dd) != 0) continue;
    UsbDfuDevice d;
    if (!FindDfuInterface(list[i], &d.interface_number, &d.dfu_mode)) continue;
    d.id.vendor_id = dd.idVendor;
    d.id.product_id = dd.idProduct;
    d.bus = libusb_get_bus_number(list[i]);
    d.address = libusb_get_device_address(list[i]);
    libusb_device_handle* h = nullptr;
    if (libusb_open(list[i], &h) == 0) {
      d.id.serial = ReadStringDescriptor(h, dd.iSerialNumber);
      d.product = ReadStringDescriptor(h, dd.iProduct);
      libusb_close(h);
    }
    out->push_back(d);
  }
  if (n > 0) libusb_free_device_list(list, 1);
  libusb_exit(ctx);
  return Status::Ok();
}

Status UsbTransport::Open(const UsbDeviceId& id, std::unique_ptr<UsbTransport>* out) {
  std::unique_ptr<UsbTransport> t(new UsbTransport());
  t->id_ = id;
  D3D_RETURN_IF_ERROR(Init(&t->ctx_));
  D3D_RETURN_IF_ERROR(t->OpenMatching());
  *out = std::move(t);
  return Status::Ok();
}

UsbTransport::~UsbTransport() {
  CloseHandle();
  if (ctx_) libusb_exit(ctx_);
}

void UsbTransport::CloseHandle() {
  if (handle_) {
    libusb_release_interface(handle_, interface_);
    libusb_close(handle_);
  }
  handle_ = nullptr;
}

Status UsbTransport::OpenMatching() {
  CloseHandle();
  libusb_device** list = nullptr;
  const ssize_t n = libusb_get_device_list(ctx_, &list);
  Status result = NotFound("no USB device " + Describe() + " is attached (libusb sees " +
                           std::to_string(n < 0 ? 0 : n) + " devices)");
  for (ssize_t i = 0; i < n && !handle_; ++i) {
    libusb_device_descriptor dd{};
    if (libusb_get_device_descriptor(list[i], &dd) != 0) continue;
    if (dd.idVendor != id_.vendor_id || dd.idProduct != id_.product_id) continue;
    uint8_t number = 0;
    bool dfu_mode = false;
    if (!FindDfuInterface(list[i], &number, &dfu_mode)) continue;
    libusb_device_handle* h = nullptr;
    if (const int rc = libusb_open(list[i], &h); rc != 0) {
      result = Unavailable("cannot open " + Describe() + ": " + UsbError(rc) +
                           " (permissions? see the udev rule in firmware/update/README.md)");
      continue;
    }
    if (!id_.serial.empty() && ReadStringDescriptor(h, dd.iSerialNumber) != id_.serial) {
      libusb_close(h);
      continue;
    }
    libusb_set_auto_detach_kernel_driver(h, 1);
    if (const int rc = libusb_claim_interface(h, number); rc != 0) {
      result = Unavailable("cannot claim the DFU interface of " + Describe() + ": " + UsbError(rc));
      libusb_close(h);
      continue;
    }
    handle_ = h;
    interface_ = number;
    result = Status::Ok();
  }
  if (n > 0) libusb_free_device_list(list, 1);
  return result;
}

ControlResult UsbTransport::Control(const dfu::SetupPacket& s, std::span<uint8_t> data) {
  ControlResult r;
  if (!handle_) {
    r.status = Unavailable("usb: device not open");
    return r;
  }
  const int rc = libusb_control_transfer(handle_, s.request_type, s.request, s.value, s.index,
                                         data.data(), s.length, kUsbControlTimeoutMs);
  if (rc == LIBUSB_ERROR_PIPE) {
    r.stalled = true;
  } else if (rc < 0) {
    r.status = Unavailable("usb: control transfer failed: " + UsbError(rc));
  } else {
    r.length = static_cast<size_t>(rc);
  }
  return r;
}

Status UsbTransport::BusReset() {
  if (!handle_) return Unavailable("usb: device not open");
  const int rc = libusb_reset_device(handle_);
  CloseHandle();  // after a reset the device may re-enumerate with new descriptors
  if (rc != 0 && rc != LIBUSB_ERROR_NOT_FOUND)
    return Unavailable("usb: reset failed: " + UsbError(rc));
  return Status::Ok();
}

Status UsbTransport::Reopen(int timeout_ms) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
  for (;;) {
    const Status s = OpenMatching();
    if (s.ok() || std::chrono::steady_clock::now() >= deadline) return s;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
}

std::string UsbTransport::Describe() const {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "usb:%04x:%04x", id_.vendor_id, id_.product_id);
  std::string s = buf;
  if (!id_.serial.empty()) s.append(":").append(id_.serial);
  return s;
}

}  // namespace d3d::flash
