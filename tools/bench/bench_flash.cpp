// d3d-bench-flash: times flashing a 16 MiB signed image over the sim link (d3d-update-agent as a
// separate process, file-backed flash, full verification by the probe) and prints the estimate for
// a real USB full-speed / high-speed link from the block size and the DFU round trips
// (model: firmware/update/README.md, "How long a real probe takes").
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "common/options/option_registry.h"
#include "firmware/update/agent_process.h"
#include "firmware/update/flash_model.h"
#include "firmware/update/test_images.h"
#include "host/flash/dfu_host.h"
#include "host/flash/sim_transport.h"

using namespace d3d;
namespace fs = std::filesystem;

namespace {

struct LinkModel {
  const char* name;
  double
      packet_us;  // bus time of one 64-byte EP0 data transaction (token, data, handshake, overhead)
  double transfer_ms;  // completion latency of one control transfer (a frame / a microframe)
};

// Link time of one DFU block: the DNLOAD data stage plus `transfers` control-transfer latencies.
double BlockLinkMs(const LinkModel& m, int block_bytes, int transfers) {
  const int packets = (block_bytes + 63) / 64;
  return packets * m.packet_us / 1000.0 + transfers * m.transfer_ms;
}

void WriteFile(const fs::path& p, const std::vector<uint8_t>& d) {
  std::ofstream f(p, std::ios::binary);
  f.write(reinterpret_cast<const char*>(d.data()), static_cast<std::streamsize>(d.size()));
}

}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options("d3d-bench-flash: 16 MiB over the sim link, and the real-USB estimate");
  int runs = 3, transfer_size = 4096;
  uint64_t image_mib = 16;
  options.Add("--runs", &runs, "timed runs (median reported)");
  options.Add("--transfer-size", &transfer_size, "DFU wTransferSize of the simulated probe");
  options.Add("--image-mib", &image_mib, "image size, MiB");
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;

  const fs::path dir =
      fs::temp_directory_path() / ("d3d_bench_flash_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const auto key = fw::testing::MakeTestKey(1);
  (void)fw::SavePublicKey((dir / "signing.pub").string(), key.pk);
  WriteFile(dir / "v1.0.img", fw::testing::MakeImage(&key, {1, 0, 0}, 1, 1, 64 * 1024, 1));
  const uint64_t image_bytes = image_mib << 20;
  const auto big =
      fw::testing::MakeImage(&key, {1, 1, 0}, 1, 1, image_bytes - fw::kImageOverheadBytes, 2);
  const std::string agent_bin = fw::ExecutableDir() + "/d3d-update-agent";

  std::vector<flash::FlashReport> reports;
  for (int run = 0; run < runs; ++run) {
    fs::remove_all(dir / "flash");
    const std::string sock = (dir / "probe.sock").string();
    fw::AgentProcess agent;
    const Status s =
        agent.Start(agent_bin,
                    {"--socket", sock, "--flash", (dir / "flash").string(), "--pubkey",
                     (dir / "signing.pub").string(), "--provision", (dir / "v1.0.img").string(),
                     "--transfer-size", std::to_string(transfer_size), "--slot-mib",
                     std::to_string(image_mib + 4), "--quiet"},
                    sock);
    if (!s.ok()) {
      std::fprintf(stderr, "d3d-bench-flash: %s\n", s.ToString().c_str());
      return 1;
    }
    std::unique_ptr<flash::SimTransport> t;
    if (Status o = flash::SimTransport::Open(sock, 2000, &t); !o.ok()) {
      std::fprintf(stderr, "d3d-bench-flash: %s\n", o.ToString().c_str());
      return 1;
    }
    const flash::FlashReport r = flash::FlashImage(t.get(), big, {});
    agent.Stop();
    if (r.outcome != flash::FlashOutcome::kUpdated) {
      std::fprintf(stderr, "d3d-bench-flash: run %d: %s: %s\n", run,
                   flash::FlashOutcomeName(r.outcome), r.reason.c_str());
      return 1;
    }
    std::printf(
        "run %d: total %.3f s = download %.3f s + manifestation (verify) %.3f s + reboot (verified "
        "boot) %.3f s\n",
        run, r.total_s, r.download_s, r.manifest_s, r.reboot_s);
    reports.push_back(r);
  }
  fs::remove_all(dir);
  std::sort(reports.begin(), reports.end(),
            [](const auto& a, const auto& b) { return a.total_s < b.total_s; });
  const flash::FlashReport& m = reports[reports.size() / 2];
  const double per_block =
      static_cast<double>(m.download_transfers) / static_cast<double>(m.blocks);
  std::printf("\nsim link, %llu MiB image, wTransferSize %d (median of %d):\n",
              static_cast<unsigned long long>(image_mib), transfer_size, runs);
  std::printf(
      "  total %.2f s (limit 10 s): download %.2f s (%.1f MiB/s), probe verification %.2f s, "
      "reboot %.2f s\n",
      m.total_s, m.download_s, static_cast<double>(m.bytes) / (1 << 20) / m.download_s,
      m.manifest_s, m.reboot_s);
  std::printf(
      "  %lld blocks, %lld control transfers in all, %.2f per block (DNLOAD + GETSTATUS dfuDNBUSY "
      "+ GETSTATUS dfuDNLOAD-IDLE)\n",
      static_cast<long long>(m.blocks), static_cast<long long>(m.control_transfers), per_block);
  std::printf("  mean control round trip %.1f us (including the probe writing its flash file)\n",
              m.download_s / static_cast<double>(m.download_transfers) * 1e6);

  // Real USB estimate.
  const LinkModel fs_link{"full-speed (12 Mbit/s)", 60.0, 1.0};
  const LinkModel hs_link{"high-speed (480 Mbit/s)", 1.5, 0.125};
  fw::FlashGeometry nor;  // W25Q128JV-class NOR timings
  const double pages = static_cast<double>(image_bytes) / nor.page_bytes;
  const double erases = static_cast<double>(image_bytes) / nor.erase_block_bytes;
  const double nor_s = (pages * nor.page_program_ms + erases * nor.block_erase_ms) / 1000.0;
  const double verify_s =
      static_cast<double>(image_bytes) / 100e6;  // 100 MB/s SHA-256 + SHA-512 on the probe
  std::printf(
      "\nreal USB estimate for %llu MiB (EP0 max packet 64 B; %.0f control transfers per block; "
      "verification %.2f s):\n",
      static_cast<unsigned long long>(image_mib), std::round(per_block), verify_s);
  std::printf("  %-26s %8s %12s %14s %16s\n", "link", "block", "link only", "+ NOR flash",
              "+ eMMC 20 MB/s");
  for (const LinkModel& l : {fs_link, hs_link}) {
    for (int b : {1024, 4096, 32768}) {
      const double blocks = std::ceil(static_cast<double>(image_bytes) / b);
      const double link_s =
          blocks * BlockLinkMs(l, b, static_cast<int>(std::round(per_block))) / 1000.0 + verify_s;
      std::printf("  %-26s %6d B %10.1f s %12.1f s %14.1f s\n", l.name, b, link_s, link_s + nor_s,
                  link_s + static_cast<double>(image_bytes) / 20e6);
    }
  }
  std::printf(
      "  (NOR: %.0f page programs x %.1f ms + %.0f block erases x %.0f ms = %.1f s of device busy "
      "time, waited via bwPollTimeout)\n",
      pages, nor.page_program_ms, erases, nor.block_erase_ms, nor_s);
  return 0;
}
