// d3d-probe: the probe's acquisition process. Captures phase bursts (real camera through libcamera,
// or the virtual probe), synchronises camera frames with projector patterns and publishes bursts,
// ProbeInfo and ProbeStatus over DDS; obeys ProbeCommand. Thin wiring of firmware/probe.
//
// Sim backend: renders a cycle of --sim-cycle bursts at start-up (rendering is ~3.5 bursts/s per
// core at 640×480, far below 30 Hz), then publishes them in a loop at --rate with live timestamps;
// the bytes published are exactly the rendered images.
#include <zlib.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <fstream>

#include "firmware/probe/probe_app.h"
#include "firmware/probe/probe_update.h"
#include "firmware/sim/trajectory/scan_styles.h"
#include "tools/dds/tool_dds.h"

using namespace d3d;

namespace {
volatile std::sig_atomic_t g_stop = 0;
ProbeApp* g_app = nullptr;
void OnSignal(int) {
  g_stop = 1;
  if (g_app != nullptr) g_app->RequestStop();
}
}  // namespace

int main(int argc, char** argv) {
  CLI::App cli{"d3d-probe: the probe's acquisition process (capture, frame sync, DDS publishing)"};
  std::string sim, camera, size = "640x480", serial = "SIM-0001", manifest;
  CaptureOptions capture;
  ProbeAppOptions app_options;
  int domain = 0, wait_subscribers = 0;
  double wait_timeout_s = 60;
  bool idle = false;
  int64_t frames = 0;
  cli.add_option("--sim", sim, "virtual probe scene: typodont or a mesh file (PLY/STL/OBJ, mm); implies --camera sim");
  cli.add_option("--camera", camera, "capture backend: auto (first real camera), libcamera, sim (default: sim with --sim, else auto)");
  cli.add_option("--trajectory", capture.trajectory, "sim scan path: a style (" + ScanStyleList("|") + "), quadrant or FILE.tum")->capture_default_str();
  cli.add_option("--rate", app_options.rate_hz, "bursts per second")->capture_default_str();
  cli.add_option("--frames", frames, "publish this many bursts, wait for readers' acks, exit (0 = until SIGINT)")->capture_default_str();
  cli.add_option("--seed", capture.seed, "sim: scan path and sensor noise seed")->capture_default_str();
  cli.add_option("--serial", serial, "probe serial number (≤ 32 characters)")->capture_default_str();
  cli.add_option("--domain", domain, "DDS domain id")->capture_default_str();
  cli.add_option("--size", size, "sim camera: 640x480 or 1280x1024")->capture_default_str();
  cli.add_option("--sim-cycle", capture.sim_cycle, "sim: distinct bursts rendered at start-up, then repeated")->capture_default_str();
  cli.add_option("--fault-rate", capture.sim_fault_rate, "sim: share of frames lost, torn or out of order (tests the frame sync)")->capture_default_str();
  cli.add_option("--render-threads", capture.render_threads, "sim: render threads (0 = all cores)")->capture_default_str();
  cli.add_flag("--idle", idle, "start idle; stream on ProbeCommand START_STREAMING");
  cli.add_option("--wait-subscribers", wait_subscribers, "before streaming, wait for this many PhaseBurst readers")->capture_default_str();
  cli.add_option("--wait-timeout", wait_timeout_s, "seconds to wait for them")->capture_default_str();
  cli.add_option("--manifest", manifest, "write 'burst_seq crc32(frame 0) ... crc32(frame N-1)' per published burst (tests)");
  // Firmware update agent (issue 8): served over the sim link when --update-socket is given.
  ProbeUpdateOptions update;
  std::string hw = "0x0001";
  uint64_t slot_mib = 20;
  uint32_t erase_kib = 64;
  auto* update_group = cli.add_option_group("firmware update", "the update agent (d3d-flash --device sim:SOCKET)");
  update_group->add_option("--update-socket", update.socket_path, "serve firmware updates on this Unix socket (sim link)");
  update_group->add_option("--flash", update.setup.flash_dir, "directory of the probe's flash (flash.bin, A/B slots)");
  update_group->add_option("--pubkey", update.setup.pubkey_path, "the firmware signing public key the probe trusts");
  update_group->add_option("--provision", update.setup.provision_path, "factory image written to slot A when the flash is blank");
  update_group->add_option("--hw", hw, "this probe's hardware compatibility id")->capture_default_str();
  update_group->add_option("--slot-mib", slot_mib, "capacity of each A/B slot, MiB")->capture_default_str();
  update_group->add_option("--erase-kib", erase_kib, "flash erase block, KiB")->capture_default_str();
  CLI11_PARSE(cli, argc, argv);

  if (camera.empty()) camera = sim.empty() ? "auto" : "sim";
  if (!sim.empty()) capture.sim_model = sim;
  if (size == "1280x1024") {
    capture.width = 1280;
    capture.height = 1024;
  } else if (size != "640x480") {
    std::fprintf(stderr, "d3d-probe: --size must be 640x480 or 1280x1024\n");
    return 2;
  }
  capture.rate_hz = app_options.rate_hz;
  capture.max_bursts = static_cast<int>(std::min<int64_t>(frames, 1 << 20));
  app_options.serial = serial;
  app_options.firmware_version = D3D_FIRMWARE_VERSION;
  app_options.max_bursts = frames;
  app_options.start_streaming = !idle;
  if (!update.socket_path.empty()) {
    if (update.setup.flash_dir.empty() || update.setup.pubkey_path.empty()) {
      std::fprintf(stderr, "d3d-probe: --update-socket needs --flash DIR and --pubkey FILE\n");
      return 2;
    }
    try {
      update.agent.slots.hw_id = static_cast<uint32_t>(std::stoul(hw, nullptr, 0));
    } catch (const std::exception&) {
      std::fprintf(stderr, "d3d-probe: --hw must be a number, got '%s'\n", hw.c_str());
      return 2;
    }
    update.agent.slots.slot_bytes = slot_mib << 20;
    update.agent.serial = serial;
    update.setup.erase_bytes = erase_kib * 1024;
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);

  try {
    CaptureBackendRegistry registry;
    RegisterBuiltinCaptureBackends(&registry);
    const auto t0 = std::chrono::steady_clock::now();
    if (camera == "sim") std::fprintf(stderr, "d3d-probe: sim: building the scene and pre-rendering up to %d bursts...\n", capture.sim_cycle);
    std::unique_ptr<CaptureBackend> backend;
    const Status opened = registry.CreateAndOpen(camera, capture, &backend);
    if (!opened.ok()) {
      std::fprintf(stderr, "d3d-probe: cannot open camera '%s': %s\n", camera.c_str(), opened.ToString().c_str());
      return opened.code() == StatusCode::kInvalidArgument ? 2 : 3;
    }
    std::fprintf(stderr, "d3d-probe: camera '%s' (%s, %dx%d) ready in %.1f s\n", backend->info().backend.c_str(),
                 backend->info().sensor_model.c_str(), backend->info().width, backend->info().height,
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());

    proto::DdsParticipant participant;
    if (const Status s = tools::CreateToolParticipant(domain, &participant, "d3d-probe"); !s.ok()) {
      std::fprintf(stderr, "d3d-probe: DDS: %s\n", s.ToString().c_str());
      return 3;
    }
    std::FILE* manifest_file = nullptr;
    if (!manifest.empty()) {
      manifest_file = std::fopen(manifest.c_str(), "w");
      if (manifest_file == nullptr) {
        std::fprintf(stderr, "d3d-probe: cannot write %s\n", manifest.c_str());
        return 2;
      }
      app_options.on_published = [manifest_file](uint64_t seq, const std::vector<CapturedFrame>& fr) {
        std::fprintf(manifest_file, "%llu", static_cast<unsigned long long>(seq));
        for (const auto& f : fr)
          std::fprintf(manifest_file, " %08lx", crc32(0L, f.pixels->data(), static_cast<uInt>(f.pixels->size())));
        std::fprintf(manifest_file, "\n");
      };
    }
    app_options.wait_readers = wait_subscribers;
    app_options.wait_readers_timeout_ns = static_cast<int64_t>(wait_timeout_s * 1e9);
    ProbeApp app(app_options, std::move(backend), std::make_unique<LoggingProjectorDriver>(stderr), &participant);
    g_app = &app;
    if (g_stop) app.RequestStop();
    if (const Status s = app.Start(); !s.ok()) {
      std::fprintf(stderr, "d3d-probe: start: %s\n", s.ToString().c_str());
      return 3;
    }
    // The update agent powers on once the camera, projector and DDS are up (its health check).
    std::unique_ptr<ProbeUpdateService> updates;
    if (!update.socket_path.empty()) {
      updates = std::make_unique<ProbeUpdateService>(&app, update);
      if (const Status s = updates->Start(); !s.ok()) {
        std::fprintf(stderr, "d3d-probe: firmware update agent: %s\n", s.ToString().c_str());
        return 3;
      }
      std::fprintf(stderr, "d3d-probe: firmware: %s; updates on %s\n", updates->boot_log().c_str(), update.socket_path.c_str());
    }
    const auto t1 = std::chrono::steady_clock::now();
    const Status s = app.Run();
    if (updates) updates->Stop();
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
    g_app = nullptr;
    if (manifest_file) std::fclose(manifest_file);
    std::printf("d3d-probe: published %llu bursts in %.2f s (%.2f/s); dropped by frame sync %llu, publish failures %llu, overruns %llu\n",
                static_cast<unsigned long long>(app.counters().bursts_published.load()), secs,
                secs > 0 ? static_cast<double>(app.counters().bursts_published.load()) / secs : 0.0,
                static_cast<unsigned long long>(app.sync_counters().dropped_total()),
                static_cast<unsigned long long>(app.counters().publish_failures.load()),
                static_cast<unsigned long long>(app.counters().capture_overruns.load()));
    if (!s.ok()) {
      std::fprintf(stderr, "d3d-probe: %s\n", s.ToString().c_str());
      return 1;
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-probe: %s\n", e.what());
    return 2;
  }
  return 0;
}
