// d3d-update-agent: the simulated probe's firmware update agent. Holds a file-backed A/B flash,
// boots it like the probe's bootloader, and serves USB DFU 1.1 over a Unix socket (the sim link)
// to d3d-flash. Tests start it, kill it (power loss) and restart it on the same flash.
#include <unistd.h>

#include <csignal>
#include <cstdio>

#include "common/options/option_registry.h"
#include "firmware/update/agent_setup.h"
#include "firmware/update/sim_link_server.h"
#include "firmware/update/update_agent.h"

using namespace d3d;
using namespace d3d::fw;

namespace {

// SIGTERM / SIGINT keep their default action (terminate at once): the flash is a file, so stopping
// at any point is just another power cut, which the probe is built to survive.
std::atomic<bool> g_stop{false};

class SimProbeHooks : public ProbeHooks {
 public:
  std::atomic<bool> streaming{false};
  std::string unhealthy_version, silent_version;
  bool quiet = false;

  bool IsStreaming() const override { return streaming.load(); }
  void OnDfuMode(bool entering) override {
    if (!quiet)
      std::fprintf(stderr, "d3d-update-agent: %s DFU mode\n", entering ? "entering" : "leaving");
  }
  void OnRunningFirmware(const dfu::FirmwareInfo& f) override {
    if (!quiet) {
      std::fprintf(stderr, "d3d-update-agent: running %s (slot %c, %s), security floor %u\n",
                   f.VersionString().c_str(), f.running_slot == 0 ? 'A' : 'B',
                   dfu::BootStateName(f.boot_state), f.security_floor);
    }
  }
  HealthResult HealthCheck(const ImageHeader& h) override {
    const std::string v = h.version.ToString();
    if (v == unhealthy_version) return HealthResult::kUnhealthy;
    if (v == silent_version) return HealthResult::kNoAnswer;
    return HealthResult::kHealthy;
  }
  bool SimSetStreaming(bool on) override {
    streaming.store(on);
    if (!quiet)
      std::fprintf(stderr, "d3d-update-agent: streaming %s\n", on ? "started" : "stopped");
    return true;
  }
};

}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options(
      "d3d-update-agent: the simulated probe's firmware update agent (USB DFU 1.1 over a Unix "
      "socket)");
  std::string socket_path, flash_dir, pubkey_path, provision, hw = "0x0001", serial = "SIM0001";
  SimProbeHooks hooks;
  uint64_t slot_mib = 20;
  uint32_t erase_kib = 64, page_bytes = 256;
  unsigned transfer_size = 4096;  // a uint16_t (wTransferSize): the range is checked
  int poll_ms = 0, trial_boots = 2;
  int64_t power_cut_after = -1;
  bool streaming = false, sim_controls = false;
  options.Add("--socket", &socket_path, "Unix socket to serve the sim link on").Required();
  options.Add("--flash", &flash_dir, "directory of the simulated flash (flash.bin, created erased)")
      .Required();
  options.Add("--pubkey", &pubkey_path, "the public key the probe trusts (d3d-fwpack --keygen)")
      .Required();
  options.Add("--hw", &hw, "this probe's hardware compatibility id");
  options.Add("--serial", &serial, "USB serial number");
  options.Add("--provision", &provision, "factory image written to slot A when the flash is blank");
  options.Add("--slot-mib", &slot_mib, "capacity of each A/B slot, MiB");
  options.Add("--erase-kib", &erase_kib, "flash erase block, KiB");
  options.Add("--page", &page_bytes, "flash program page, bytes");
  options.Add("--transfer-size", &transfer_size, "DFU wTransferSize, bytes").Range(0, 65535);
  options.Add("--poll-ms", &poll_ms,
              "bwPollTimeout reported while busy (-1: the flash timing model)");
  options.Add("--trial-boots", &trial_boots, "boots a new firmware gets to confirm itself");
  options.Flag("--streaming", &streaming, "the probe streams from the start (updates are refused)");
  options.Flag("--sim-controls", &sim_controls,
               "accept the vendor request that starts/stops streaming");
  options.Add("--unhealthy-version", &hooks.unhealthy_version,
              "a firmware version whose health check fails");
  options.Add("--silent-version", &hooks.silent_version,
              "a firmware version that never confirms (hangs)");
  options.Add("--power-cut-after-ops", &power_cut_after,
              "cut the power at flash operation N (erases + page programs since start); the agent "
              "exits 86");
  options.Flag("--quiet", &hooks.quiet, "no log lines");
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;

  try {
    UpdateAgentOptions opt;
    opt.slots.hw_id = static_cast<uint32_t>(std::stoul(hw, nullptr, 0));
    opt.slots.slot_bytes = slot_mib << 20;
    opt.slots.trial_boots = static_cast<uint8_t>(trial_boots);
    opt.dfu.transfer_size = static_cast<uint16_t>(transfer_size);
    opt.dfu.fixed_poll_ms = poll_ms;
    opt.serial = serial;
    opt.sim_controls = sim_controls;
    AgentSetupOptions setup_options;
    setup_options.flash_dir = flash_dir;
    setup_options.pubkey_path = pubkey_path;
    setup_options.provision_path = provision;
    setup_options.erase_bytes = erase_kib * 1024;
    setup_options.page_bytes = page_bytes;
    hooks.streaming.store(streaming);
    AgentSetup setup;
    if (Status s = OpenUpdateAgent(setup_options, opt, &hooks, &setup); !s.ok()) {
      std::fprintf(stderr, "d3d-update-agent: %s\n", s.ToString().c_str());
      return 2;
    }
    Flash* flash = setup.flash.get();
    UpdateAgent& agent = *setup.agent;
    // The power cut counts operations from this start on (provisioning is the factory's).
    if (power_cut_after >= 0) flash->CutPowerAfterOps(flash->ops() + power_cut_after);
    if (Status s = agent.PowerOn(); !s.ok()) {
      if (agent.flash_dead()) {
        std::fprintf(stderr, "d3d-update-agent: power cut during boot\n");
        _exit(86);
      }
      std::fprintf(stderr, "d3d-update-agent: %s\n", s.ToString().c_str());
      return 3;
    }
    if (!hooks.quiet)
      std::fprintf(stderr, "d3d-update-agent: power-on: %s\n", agent.boot_log().c_str());
    SimLinkServerOptions so;
    so.socket_path = socket_path;
    so.on_power_cut = [] {
      std::fprintf(stderr, "d3d-update-agent: power cut\n");
      _exit(86);
    };
    so.on_reset = [&](const Status& s) {
      if (!s.ok())
        std::fprintf(stderr, "d3d-update-agent: reboot: %s\n", s.ToString().c_str());
      else if (!hooks.quiet && !agent.boot_log().empty()) {
        std::fprintf(stderr, "d3d-update-agent: reboot: %s\n", agent.boot_log().c_str());
      }
    };
    if (!hooks.quiet)
      std::fprintf(stderr, "d3d-update-agent: listening on %s\n", socket_path.c_str());
    const Status s = ServeSimLink(&agent, so, &g_stop);
    if (!s.ok()) {
      std::fprintf(stderr, "d3d-update-agent: %s\n", s.ToString().c_str());
      return 2;
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-update-agent: %s\n", e.what());
    return 2;
  }
  return 0;
}
