// d3d-flash: flashes a signed firmware image onto a probe over USB DFU 1.1 (libusb) or over the
// simulated link (a Unix socket to d3d-update-agent), showing progress, the version before and
// after, and a clear end state.
//
// Exit codes: 0 updated (or dry run), 2 usage / file / no probe, 3 refused by the probe,
// 4 rolled back, 5 link lost, 1 other errors.
#include <cstdio>
#include <fstream>

#include "common/core/progress.h"
#include "common/options/option_registry.h"
#include "firmware/update/image_format.h"
#include "host/flash/dfu_host.h"
#include "host/flash/sim_transport.h"
#include "host/flash/usb_transport.h"

using namespace d3d;
using namespace d3d::flash;

namespace {

std::string Mib(uint64_t b) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.2f MiB", static_cast<double>(b) / (1 << 20));
  return buf;
}

std::string Describe(const dfu::FirmwareInfo& f) {
  std::string s = f.VersionString();
  s.append(" (slot ")
      .append(f.running_slot == 0 ? "A" : "B")
      .append(", ")
      .append(dfu::BootStateName(f.boot_state));
  if (f.streaming) s.append(", streaming");
  return s.append(")");
}

int ListDevices(const std::string& device) {
  std::vector<UsbDfuDevice> found;
  const Status s = UsbTransport::List(&found);
  if (!s.ok()) {
    std::printf("usb: none (%s)\n", s.message().c_str());
  } else if (found.empty()) {
    std::printf("usb: no DFU-capable probes found\n");
  }
  for (const UsbDfuDevice& d : found) {
    std::printf("usb:%04x:%04x%s%s  bus %u addr %u  %s  %s\n", d.id.vendor_id, d.id.product_id,
                d.id.serial.empty() ? "" : ":", d.id.serial.c_str(), d.bus, d.address,
                d.dfu_mode ? "DFU mode" : "run-time", d.product.c_str());
  }
  if (device.rfind("sim:", 0) == 0) {
    std::unique_ptr<SimTransport> t;
    if (Status o = SimTransport::Open(device.substr(4), 500, &t); !o.ok()) {
      std::printf("%s: %s\n", device.c_str(), o.message().c_str());
      return 0;
    }
    DfuHost host(t.get());
    DfuDeviceInfo info;
    dfu::FirmwareInfo fw;
    if (host.ReadDescriptors(&info).ok() && host.GetFirmwareInfo(&fw).ok()) {
      std::printf("%s  serial %s  %s  hw 0x%04x  runs %s\n", device.c_str(), info.serial.c_str(),
                  info.product.c_str(), fw.hw_id, Describe(fw).c_str());
    }
  }
  return 0;
}

struct FlashToolOptions {
  std::string image_path, device;
  bool list = false, dry_run = false, no_progress = false;
};

void DeclareOptions(OptionRegistry* r, FlashToolOptions* o) {
  r->Flag("--list", &o->list,
          "list the probes that can be flashed (USB; and --device sim:SOCKET if given)");
  r->Add("image", &o->image_path, "signed firmware image (d3d-fwpack)");
  r->Add("--device", &o->device,
         "usb:VID:PID[:SERIAL] or sim:SOCKET (default: the only USB probe)");
  r->Flag("--dry-run", &o->dry_run, "read the image and the probe, send nothing");
  r->Flag("--no-progress", &o->no_progress, "no progress bar");
}

// Reads the image and its header, printing what it is; false (printed) when it is not an image.
bool ReadImage(const std::string& path, std::vector<uint8_t>* image, fw::ImageHeader* h) {
  {
    std::ifstream f(path, std::ios::binary);
    if (!f) {
      std::fprintf(stderr, "d3d-flash: cannot read %s\n", path.c_str());
      return false;
    }
    image->assign(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
  }
  if (const fw::Verdict v = fw::ParseHeader(*image, h); !v.ok()) {
    std::fprintf(stderr, "d3d-flash: %s is not a d3dscan firmware image (%s)\n", path.c_str(),
                 v.message.c_str());
    return false;
  }
  std::printf("image   %s: firmware %s, hardware 0x%04x, counter %u, %s, key id %s\n", path.c_str(),
              h->version.ToString().c_str(), h->hw_id, h->security_counter,
              Mib(image->size()).c_str(), fw::Hex(h->key_id).c_str());
  return true;
}

// Opens the link to the probe named by *device (empty: the only USB probe, whose name is then
// written back); false (printed) when there is none or it cannot be opened.
bool OpenTransport(std::string* device, std::unique_ptr<DfuTransport>* transport) {
  if (device->empty()) {
    std::vector<UsbDfuDevice> found;
    const Status s = UsbTransport::List(&found);
    if (!s.ok() || found.size() != 1) {
      std::fprintf(stderr,
                   "d3d-flash: %s; name one with --device usb:VID:PID[:SERIAL] or sim:SOCKET\n",
                   !s.ok()         ? s.message().c_str()
                   : found.empty() ? "no probe found on USB"
                                   : "several probes found");
      return false;
    }
    char buf[16];
    std::snprintf(buf, sizeof(buf), "%04x:%04x", found[0].id.vendor_id, found[0].id.product_id);
    *device = std::string("usb:") + buf;
    if (!found[0].id.serial.empty()) device->append(":").append(found[0].id.serial);
  }
  if (device->rfind("sim:", 0) == 0) {
    std::unique_ptr<SimTransport> t;
    if (Status s = SimTransport::Open(device->substr(4), 2000, &t); !s.ok()) {
      std::fprintf(stderr, "d3d-flash: %s\n", s.message().c_str());
      return false;
    }
    *transport = std::move(t);
    return true;
  }
  if (device->rfind("usb:", 0) != 0) {
    std::fprintf(stderr, "d3d-flash: --device must start with usb: or sim:, got %s\n",
                 device->c_str());
    return false;
  }
  UsbDeviceId id;
  if (!UsbDeviceId::Parse(device->substr(4), &id)) {
    std::fprintf(stderr, "d3d-flash: --device usb:VID:PID[:SERIAL] with hex VID/PID, got %s\n",
                 device->c_str());
    return false;
  }
  std::unique_ptr<UsbTransport> t;
  if (Status s = UsbTransport::Open(id, &t); !s.ok()) {
    std::fprintf(stderr, "d3d-flash: %s\n", s.message().c_str());
    return false;
  }
  *transport = std::move(t);
  return true;
}

// Flashes `image` (or only reads the probe with --dry-run), with a progress bar in KiB and the
// probe's identity printed once connected.
FlashReport Flash(DfuTransport* transport, const std::vector<uint8_t>& image,
                  const FlashToolOptions& opt) {
  FlashOptions o;
  o.dry_run = opt.dry_run;
  const int64_t total_kib = static_cast<int64_t>((image.size() + 1023) / 1024);
  ProgressBar bar("flash (KiB)", total_kib, !opt.no_progress && !opt.dry_run);
  int64_t shown = -1;
  o.progress = [&](uint64_t done, uint64_t) {
    const int64_t kib = static_cast<int64_t>(done / 1024);
    if (kib - shown >= std::max<int64_t>(1, total_kib / 200) || done == image.size()) {
      bar.Update(kib);
      shown = kib;
    }
  };
  o.on_connected = [&](const DfuDeviceInfo& d, const dfu::FirmwareInfo& f) {
    std::printf("probe   %s: \"%s\" serial %s, hardware 0x%04x, wTransferSize %u\n",
                transport->Describe().c_str(), d.product.c_str(), d.serial.c_str(), f.hw_id,
                d.functional.transfer_size);
    std::printf("        runs %s, security floor %u, slot capacity %s\n", Describe(f).c_str(),
                f.security_floor, Mib(f.slot_capacity_bytes).c_str());
    std::fflush(stdout);
  };
  const FlashReport r = FlashImage(transport, image, o);
  bar.Finish();
  return r;
}

// What a dry run would send, and why the probe would refuse the image if it would.
void PrintDryRun(const FlashReport& r, const fw::ImageHeader& h, size_t image_bytes) {
  const uint64_t blocks =
      (image_bytes + r.device.functional.transfer_size - 1) / r.device.functional.transfer_size;
  std::printf(
      "dry run would send %llu blocks of %u bytes (%llu control transfers); the probe checks size, "
      "SHA-256,\n"
      "        signature, hardware id and counter before it marks the slot bootable.",
      static_cast<unsigned long long>(blocks), r.device.functional.transfer_size,
      static_cast<unsigned long long>(3 * blocks + 2));
  if (h.hw_id != r.before.hw_id) std::printf(" Hardware ids differ: the probe will refuse it.");
  if (h.security_counter < r.before.security_floor)
    std::printf(" Counter below the floor: the probe will refuse it.");
  if (h.ImageSize() > r.before.slot_capacity_bytes)
    std::printf(" Larger than the slot: the probe will refuse it.");
  std::printf("\nresult: DRY RUN (nothing sent; probe runs %s)\n",
              r.before.VersionString().c_str());
}

// The transfer's figures and the end state; the exit code (0 updated, 3 refused, 4 rolled back,
// 5 link lost, 1 other errors).
int ReportOutcome(const FlashReport& r) {
  if (r.blocks > 0) {
    std::printf("sent    %llu bytes in %lld blocks, %lld control transfers, %.2f s (%.1f MiB/s)",
                static_cast<unsigned long long>(r.bytes), static_cast<long long>(r.blocks),
                static_cast<long long>(r.control_transfers), r.download_s,
                r.download_s > 0 ? static_cast<double>(r.bytes) / (1 << 20) / r.download_s : 0.0);
    if (r.outcome != FlashOutcome::kRefused || r.manifest_s > 0)
      std::printf("; verified by the probe in %.2f s", r.manifest_s);
    std::printf("\n");
  }
  const char* status_name = dfu::StatusName(r.dfu_status);
  switch (r.outcome) {
    case FlashOutcome::kUpdated:
      std::printf("version before %s -> after %s\n", Describe(r.before).c_str(),
                  Describe(r.after).c_str());
      std::printf("result: UPDATED %s -> %s (%.1f s in all)\n", r.before.VersionString().c_str(),
                  r.after.VersionString().c_str(), r.total_s);
      return 0;
    case FlashOutcome::kRefused:
      std::printf("result: REFUSED by the probe (%s): %s; the probe still runs %s\n", status_name,
                  r.reason.c_str(),
                  r.have_after ? Describe(r.after).c_str() : Describe(r.before).c_str());
      return 3;
    case FlashOutcome::kRolledBack:
      std::printf("version before %s -> after %s\n", Describe(r.before).c_str(),
                  Describe(r.after).c_str());
      std::printf("result: ROLLED BACK: %s\n", r.reason.c_str());
      return 4;
    case FlashOutcome::kLinkLost:
      std::printf(
          "result: LINK LOST: %s. The probe keeps booting its last good version; reconnect and "
          "flash again.\n",
          r.reason.c_str());
      return 5;
    default:
      std::printf("result: ERROR: %s\n", r.reason.c_str());
      return 1;
  }
}

}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options(
      "d3d-flash: flash a signed firmware image onto a d3dscan probe (USB DFU 1.1, or the "
      "simulated link)");
  FlashToolOptions o;
  DeclareOptions(&options, &o);
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;

  if (o.list) return ListDevices(o.device);
  if (o.image_path.empty()) {
    std::fprintf(stderr, "d3d-flash: an IMAGE is needed (or --list); see --help\n");
    return 2;
  }
  std::vector<uint8_t> image;
  fw::ImageHeader h;
  if (!ReadImage(o.image_path, &image, &h)) return 2;
  std::unique_ptr<DfuTransport> transport;
  if (!OpenTransport(&o.device, &transport)) return 2;
  const FlashReport r = Flash(transport.get(), image, o);
  if (r.outcome == FlashOutcome::kDryRun) {
    PrintDryRun(r, h, image.size());
    return 0;
  }
  return ReportOutcome(r);
}
