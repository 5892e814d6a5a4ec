// d3d-probe: the probe's acquisition process. Captures phase bursts (real camera through libcamera,
// or the virtual probe), synchronises camera frames with projector patterns and publishes bursts,
// ProbeInfo and ProbeStatus over DDS; obeys ProbeCommand. Thin wiring of firmware/probe.
//
// Sim backend: renders a cycle of --sim-cycle bursts at start-up (rendering is ~3.5 bursts/s per
// core at 640×480, far below 30 Hz), then publishes them in a loop at --rate with live timestamps;
// the bytes published are exactly the rendered images.
#include <zlib.h>

#include <chrono>
#include <csignal>
#include <cstdio>
#include <fstream>

#include "common/options/option_registry.h"
#include "firmware/probe/probe_app.h"
#include "firmware/probe/probe_update.h"
#include "sim/trajectory/scan_styles.h"
#include "tools/dds/tool_dds.h"

using namespace d3d;

namespace {
volatile std::sig_atomic_t g_stop = 0;
ProbeApp* g_app = nullptr;
void OnSignal(int) {
  g_stop = 1;
  if (g_app != nullptr) g_app->RequestStop();
}

// The command line: the capture, the DDS publishing and the firmware update agent.
struct ProbeToolOptions {
  std::string sim, camera, size = "640x480", serial = "SIM-0001", manifest;
  CaptureOptions capture;
  ProbeAppOptions app;
  int domain = 0, wait_subscribers = 0;
  double wait_timeout_s = 60;
  bool idle = false;
  int64_t frames = 0;
  // Firmware update agent (issue 8): served over the sim link when --update-socket is given.
  ProbeUpdateOptions update;
  std::string hw = "0x0001";
  uint64_t slot_mib = 20;
  uint32_t erase_kib = 64;
};

void DeclareOptions(OptionRegistry* r, ProbeToolOptions* o) {
  r->Add("--sim", &o->sim,
         "virtual probe scene: typodont or a mesh file (PLY/STL/OBJ, mm); implies --camera sim");
  r->Add("--camera", &o->camera,
         "capture backend: auto (first real camera), libcamera, sim (default: sim with --sim, else "
         "auto)");
  r->Add("--trajectory", &o->capture.trajectory,
         "sim scan path: a style (" + ScanStyleList("|") + "), quadrant or FILE.tum");
  r->Add("--rate", &o->app.rate_hz, "bursts per second");
  r->Add("--frames", &o->frames,
         "publish this many bursts, wait for readers' acks, exit (0 = until SIGINT)");
  r->Add("--seed", &o->capture.seed, "sim: scan path and sensor noise seed");
  r->Add("--serial", &o->serial, "probe serial number (≤ 32 characters)");
  r->Add("--domain", &o->domain, "DDS domain id");
  r->Add("--size", &o->size, "sim camera: 640x480 or 1280x1024");
  r->Add("--sim-cycle", &o->capture.sim_cycle,
         "sim: distinct bursts rendered at start-up, then repeated");
  r->Add("--fault-rate", &o->capture.sim_fault_rate,
         "sim: share of frames lost, torn or out of order (tests the frame sync)");
  r->Add("--render-threads", &o->capture.render_threads, "sim: render threads (0 = all cores)");
  r->Flag("--idle", &o->idle, "start idle; stream on ProbeCommand START_STREAMING");
  r->Add("--wait-subscribers", &o->wait_subscribers,
         "before streaming, wait for this many PhaseBurst readers");
  r->Add("--wait-timeout", &o->wait_timeout_s, "seconds to wait for them");
  r->Add("--manifest", &o->manifest,
         "write 'burst_seq crc32(frame 0) ... crc32(frame N-1)' per published burst (tests)");
  r->Add("--update-socket", &o->update.socket_path,
         "serve firmware updates on this Unix socket (sim link)");
  r->Add("--flash", &o->update.setup.flash_dir,
         "directory of the probe's flash (flash.bin, A/B slots)");
  r->Add("--pubkey", &o->update.setup.pubkey_path,
         "the firmware signing public key the probe trusts");
  r->Add("--provision", &o->update.setup.provision_path,
         "factory image written to slot A when the flash is blank");
  r->Add("--hw", &o->hw, "this probe's hardware compatibility id");
  r->Add("--slot-mib", &o->slot_mib, "capacity of each A/B slot, MiB");
  r->Add("--erase-kib", &o->erase_kib, "flash erase block, KiB");
}

// Derives the capture, app and update settings from the parsed options; 0, or 2 (printed) on a
// value the registry cannot check.
int ResolveOptions(ProbeToolOptions* o) {
  if (o->camera.empty()) o->camera = o->sim.empty() ? "auto" : "sim";
  if (!o->sim.empty()) o->capture.sim_model = o->sim;
  if (o->size == "1280x1024") {
    o->capture.width = 1280;
    o->capture.height = 1024;
  } else if (o->size != "640x480") {
    std::fprintf(stderr, "d3d-probe: --size must be 640x480 or 1280x1024\n");
    return 2;
  }
  o->capture.rate_hz = o->app.rate_hz;
  o->capture.max_bursts = static_cast<int>(std::min<int64_t>(o->frames, 1 << 20));
  o->app.serial = o->serial;
  o->app.firmware_version = D3D_FIRMWARE_VERSION;
  o->app.max_bursts = o->frames;
  o->app.start_streaming = !o->idle;
  if (o->update.socket_path.empty()) return 0;
  if (o->update.setup.flash_dir.empty() || o->update.setup.pubkey_path.empty()) {
    std::fprintf(stderr, "d3d-probe: --update-socket needs --flash DIR and --pubkey FILE\n");
    return 2;
  }
  try {
    o->update.agent.slots.hw_id = static_cast<uint32_t>(std::stoul(o->hw, nullptr, 0));
  } catch (const std::exception&) {
    std::fprintf(stderr, "d3d-probe: --hw must be a number, got '%s'\n", o->hw.c_str());
    return 2;
  }
  o->update.agent.slots.slot_bytes = o->slot_mib << 20;
  o->update.agent.serial = o->serial;
  o->update.setup.erase_bytes = o->erase_kib * 1024;
  return 0;
}

// Opens the capture backend `camera` (the sim pre-renders its cycle here); 0, or the exit code.
int OpenCamera(const std::string& camera, const CaptureOptions& capture,
               std::unique_ptr<CaptureBackend>* backend) {
  CaptureBackendRegistry registry;
  RegisterBuiltinCaptureBackends(&registry);
  const auto t0 = std::chrono::steady_clock::now();
  if (camera == "sim")
    std::fprintf(stderr,
                 "d3d-probe: sim: building the scene and pre-rendering up to %d bursts...\n",
                 capture.sim_cycle);
  const Status opened = registry.CreateAndOpen(camera, capture, backend);
  if (!opened.ok()) {
    std::fprintf(stderr, "d3d-probe: cannot open camera '%s': %s\n", camera.c_str(),
                 opened.ToString().c_str());
    return opened.code() == StatusCode::kInvalidArgument ? 2 : 3;
  }
  const CaptureInfo& info = (*backend)->info();
  std::fprintf(stderr, "d3d-probe: camera '%s' (%s, %dx%d) ready in %.1f s\n", info.backend.c_str(),
               info.sensor_model.c_str(), info.width, info.height,
               std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  return 0;
}

// --manifest: opens the file and has the app write each published burst's frame CRCs to it (the
// file stays open until the run ends); false (printed) when it cannot be written.
bool OpenManifest(const std::string& path, ProbeAppOptions* app, std::FILE** file) {
  *file = std::fopen(path.c_str(), "w");
  if (*file == nullptr) {
    std::fprintf(stderr, "d3d-probe: cannot write %s\n", path.c_str());
    return false;
  }
  app->on_published = [manifest = *file](uint64_t seq, const std::vector<CapturedFrame>& frames) {
    std::fprintf(manifest, "%llu", static_cast<unsigned long long>(seq));
    for (const auto& f : frames)
      std::fprintf(manifest, " %08lx",
                   crc32(0L, f.pixels->data(), static_cast<uInt>(f.pixels->size())));
    std::fprintf(manifest, "\n");
  };
  return true;
}

void PrintPublished(const ProbeApp& app, double secs) {
  const uint64_t published = app.counters().bursts_published.load();
  std::printf(
      "d3d-probe: published %llu bursts in %.2f s (%.2f/s); dropped by frame sync %llu, publish "
      "failures %llu, overruns %llu\n",
      static_cast<unsigned long long>(published), secs,
      secs > 0 ? static_cast<double>(published) / secs : 0.0,
      static_cast<unsigned long long>(app.sync_counters().dropped_total()),
      static_cast<unsigned long long>(app.counters().publish_failures.load()),
      static_cast<unsigned long long>(app.counters().capture_overruns.load()));
}

// Opens the camera and DDS, streams until --frames or a signal (serving updates if asked); the exit
// code: 0 done, 1 the run failed, 2 usage or files, 3 camera, DDS or start-up failures.
int RunProbe(ProbeToolOptions* o) {
  std::unique_ptr<CaptureBackend> backend;
  if (const int code = OpenCamera(o->camera, o->capture, &backend); code != 0) return code;
  proto::DdsParticipant participant;
  if (const Status s = tools::CreateToolParticipant(o->domain, &participant, "d3d-probe");
      !s.ok()) {
    std::fprintf(stderr, "d3d-probe: DDS: %s\n", s.ToString().c_str());
    return 3;
  }
  std::FILE* manifest_file = nullptr;
  if (!o->manifest.empty() && !OpenManifest(o->manifest, &o->app, &manifest_file)) return 2;
  o->app.wait_readers = o->wait_subscribers;
  o->app.wait_readers_timeout_ns = static_cast<int64_t>(o->wait_timeout_s * 1e9);
  ProbeApp app(o->app, std::move(backend), std::make_unique<LoggingProjectorDriver>(stderr),
               &participant);
  g_app = &app;
  if (g_stop) app.RequestStop();
  if (const Status s = app.Start(); !s.ok()) {
    std::fprintf(stderr, "d3d-probe: start: %s\n", s.ToString().c_str());
    return 3;
  }
  // The update agent powers on once the camera, projector and DDS are up (its health check).
  std::unique_ptr<ProbeUpdateService> updates;
  if (!o->update.socket_path.empty()) {
    updates = std::make_unique<ProbeUpdateService>(&app, o->update);
    if (const Status s = updates->Start(); !s.ok()) {
      std::fprintf(stderr, "d3d-probe: firmware update agent: %s\n", s.ToString().c_str());
      return 3;
    }
    std::fprintf(stderr, "d3d-probe: firmware: %s; updates on %s\n", updates->boot_log().c_str(),
                 o->update.socket_path.c_str());
  }
  const auto t1 = std::chrono::steady_clock::now();
  const Status s = app.Run();
  if (updates) updates->Stop();
  const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  g_app = nullptr;
  if (manifest_file) std::fclose(manifest_file);
  PrintPublished(app, secs);
  if (!s.ok()) {
    std::fprintf(stderr, "d3d-probe: %s\n", s.ToString().c_str());
    return 1;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options(
      "d3d-probe: the probe's acquisition process (capture, frame sync, DDS publishing)\n"
      "Firmware update agent (d3d-flash --device sim:SOCKET): --update-socket, --flash, --pubkey, "
      "--provision, --hw, --slot-mib, "
      "--erase-kib");
  ProbeToolOptions o;
  DeclareOptions(&options, &o);
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;
  if (const int code = ResolveOptions(&o); code != 0) return code;
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  try {
    return RunProbe(&o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-probe: %s\n", e.what());
    return 2;
  }
}
