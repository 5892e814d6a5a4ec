#include "tests/fuzz/firmware_fuzz.h"

#include <cstdlib>
#include <memory>
#include <span>
#include <vector>

#include "firmware/update/boot_control.h"
#include "firmware/update/dfu_protocol.h"
#include "firmware/update/image_format.h"
#include "firmware/update/test_images.h"
#include "firmware/update/update_agent.h"

namespace d3d {

namespace {

const fw::testing::TestKey& Key() {
  static const fw::testing::TestKey k = fw::testing::MakeTestKey(1);
  return k;
}

void Check(bool ok) {
  if (!ok) std::abort();
}

}  // namespace

void FuzzFirmwareImageOnce(const uint8_t* data, size_t size) {
  if (size == 0) return;
  const std::span<const uint8_t> in(data + 1, size - 1);
  switch (data[0] % 3) {
    case 0: {
      fw::ImagePolicy p;
      p.check_hw_id = true;
      p.hw_id = 1;
      p.min_security_counter = 1;
      p.max_image_bytes = 1 << 20;
      fw::ImageHeader h;
      const fw::Verdict v = fw::VerifyImageBytes(in, Key().pk, p, &h);
      if (v.ok()) {
        Check(h.ImageSize() == in.size());
        Check(std::equal(in.begin(), in.begin() + fw::kHeaderBytes, h.Serialize().begin()));
      } else {
        Check(!v.message.empty());
      }
      break;
    }
    case 1: {
      const auto r = fw::BootRecord::Parse(in);
      if (r) {
        const auto again = fw::BootRecord::Parse(r->Serialize());
        Check(again && *again == *r);
      }
      break;
    }
    default: {
      dfu::FirmwareInfo f;
      if (dfu::FirmwareInfo::Decode(in, &f)) {
        dfu::FirmwareInfo g;
        Check(dfu::FirmwareInfo::Decode(f.Encode(), &g) && g.VersionString() == f.VersionString());
      }
      std::string s;
      if (dfu::DecodeStringDescriptor(in, &s)) Check(s.size() * 2 + 2 <= in.size());
      if (in.size() >= 8) {
        const auto setup = dfu::SetupPacket::Decode(std::span<const uint8_t, 8>(in.data(), 8));
        Check(setup.Encode() ==
              (std::array<uint8_t, 8>{in[0], in[1], in[2], in[3], in[4], in[5], in[6], in[7]}));
      }
      break;
    }
  }
}

namespace {

struct FuzzHooks : fw::ProbeHooks {
  bool streaming = false;
  uint8_t health = 0;
  bool IsStreaming() const override { return streaming; }
  fw::HealthResult HealthCheck(const fw::ImageHeader&) override {
    return health % 3 == 0
               ? fw::HealthResult::kHealthy
               : (health % 3 == 1 ? fw::HealthResult::kUnhealthy : fw::HealthResult::kNoAnswer);
  }
  bool SimSetStreaming(bool on) override {
    streaming = on;
    return true;
  }
};

constexpr uint64_t kSlot = 16 * 1024;

fw::FlashGeometry Geometry() {
  fw::FlashGeometry g;
  g.erase_block_bytes = 1024;
  g.page_bytes = 256;
  return fw::SlotFlashGeometry(g, kSlot);
}

fw::UpdateAgentOptions Options() {
  fw::UpdateAgentOptions o;
  o.slots.hw_id = 1;
  o.slots.slot_bytes = kSlot;
  o.dfu.transfer_size = 512;
  o.sim_controls = true;
  return o;
}

// A provisioned flash (v1.0.0 in slot A), built once.
const std::vector<uint8_t>& ProvisionedFlash() {
  static const std::vector<uint8_t> bytes = [] {
    auto flash = fw::Flash::InMemory(Geometry());
    FuzzHooks hooks;
    fw::UpdateAgent agent(flash.get(), Key().pk, Options(), &hooks);
    if (!agent.slots().Provision(fw::testing::MakeImage(&Key(), {1, 0, 0}, 1, 1, 2000, 1)).ok())
      std::abort();
    std::vector<uint8_t> all(Geometry().size_bytes);
    if (!flash->Read(0, all).ok()) std::abort();
    return all;
  }();
  return bytes;
}

const std::vector<uint8_t>& ValidImage() {
  static const std::vector<uint8_t> img = fw::testing::MakeImage(&Key(), {2, 0, 0}, 2, 1, 3000, 2);
  return img;
}

}  // namespace

int FuzzDfuRequestsOnce(const uint8_t* data, size_t size) {
  auto flash = fw::Flash::InMemory(Geometry());
  if (!flash->Program(0, ProvisionedFlash()).ok()) std::abort();
  FuzzHooks hooks;
  hooks.health = size > 0 ? data[0] : 0;
  int64_t now = 0;
  fw::UpdateAgentOptions opt = Options();
  opt.dfu.clock_ms = [&now] { return now; };
  opt.dfu.fixed_poll_ms =
      size > 0 && (data[0] & 0x10) ? -1 : 0;  // modelled flash busy times, or none
  {
    fw::UpdateAgent agent(flash.get(), Key().pk, opt, &hooks);
    Check(agent.PowerOn().ok());
    size_t pos = 1, image_off = 0;
    uint16_t block = 0;
    std::vector<uint8_t> out;
    while (pos < size) {
      const uint8_t op = data[pos++];
      switch (op % 5) {
        case 0:
        case 1: {  // a control transfer; the request type is steered towards the interesting ones
          if (size - pos < 8) {
            pos = size;
            break;
          }
          dfu::SetupPacket s = dfu::SetupPacket::Decode(std::span<const uint8_t, 8>(data + pos, 8));
          pos += 8;
          static constexpr uint8_t kTypes[] = {
              dfu::kRequestTypeClassOut, dfu::kRequestTypeClassIn, dfu::kRequestTypeStandardIn,
              dfu::kRequestTypeVendorIn, dfu::kRequestTypeVendorOut};
          if (op % 5 == 0) {
            s.request_type = kTypes[s.request_type % 5];
            s.index = 0;
            if (s.request_type == dfu::kRequestTypeClassOut ||
                s.request_type == dfu::kRequestTypeClassIn)
              s.request %= 8;
            s.length %= 1024;
          }
          out.clear();
          if (!s.is_in()) {
            const size_t n = std::min<size_t>(s.length, size - pos);
            s.length = static_cast<uint16_t>(n);
            out.assign(data + pos, data + pos + n);
            pos += n;
          }
          const dfu::ControlResponse r = agent.HandleControl(s, out);
          Check(r.data.size() <= s.length || (!s.is_in() && r.data.empty()));
          if (s.request_type == dfu::kRequestTypeClassIn && s.request == dfu::kGetStatus &&
              !r.stall) {
            Check(r.data.size() == 6 || s.length < 6);
          }
          if (s.request_type == dfu::kRequestTypeClassOut && s.request == dfu::kDnload &&
              !r.stall && s.length > 0) {
            block = static_cast<uint16_t>(s.value + 1);
          }
          break;
        }
        case 2:
          Check(agent.BusReset().ok());
          break;
        case 3:
          now += pos < size ? data[pos++] : 1;
          break;
        default: {  // the next block of a valid signed image, as d3d-flash would send it
          const auto& img = ValidImage();
          const size_t n = std::min<size_t>(512, img.size() - std::min(image_off, img.size()));
          dfu::SetupPacket s{dfu::kRequestTypeClassOut, dfu::kDnload, block, 0,
                             static_cast<uint16_t>(n)};
          const auto r = agent.HandleControl(
              s, std::span<const uint8_t>(img).subspan(std::min(image_off, img.size()), n));
          if (!r.stall) {
            block = static_cast<uint16_t>(block + 1);
            image_off = n == 0 ? 0 : image_off + n;
          }
          break;
        }
      }
      Check(agent.dfu().state() <= dfu::kDfuError);
    }
  }
  // Power comes back: the probe must boot a good, signed image.
  FuzzHooks healthy;
  fw::UpdateAgent again(flash.get(), Key().pk, Options(), &healthy);
  Check(again.PowerOn().ok());
  Check(again.running().booted);
  Check(again.slots().VerifySlot(again.running().slot).ok());
  const fw::SemVer v = again.running().header.version;
  Check(v == (fw::SemVer{1, 0, 0}) || v == (fw::SemVer{2, 0, 0}));
  return v.major;
}

}  // namespace d3d

#ifdef D3D_FUZZ_FW_IMAGE_MAIN
extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  d3d::FuzzFirmwareImageOnce(data, size);
  return 0;
}
#endif
#ifdef D3D_FUZZ_DFU_MAIN
extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  d3d::FuzzDfuRequestsOnce(data, size);
  return 0;
}
#endif
