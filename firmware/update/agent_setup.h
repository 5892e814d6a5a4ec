// Setting up an update agent in a probe process (d3d-update-agent, d3d-probe): the file-backed
// flash with its A/B slot geometry, factory provisioning of a blank flash, and the trusted key.
// Tools call this once at start-up; it reads files (the flash, the key, the factory image).
#pragma once

#include <memory>
#include <string>

#include "common/core/status.h"
#include "firmware/update/flash_model.h"
#include "firmware/update/update_agent.h"

namespace d3d::fw {

struct AgentSetupOptions {
  std::string flash_dir;    // holds flash.bin (created erased when absent)
  std::string pubkey_path;  // the public key the probe trusts (d3d-fwpack --keygen)
  std::string
      provision_path;  // factory image written to slot A when the flash is blank ("" = none)
  uint32_t erase_bytes = 64 * 1024;  // flash erase block
  uint32_t page_bytes = 256;         // flash program page
  void Check() const;                // throws std::invalid_argument
};

// What a probe process keeps alive while it serves updates. Owned by the process's main thread;
// after Open() only the transport thread touches `agent` (see update_agent.h).
struct AgentSetup {
  PublicKey trusted_key{};
  std::unique_ptr<Flash> flash;
  std::unique_ptr<UpdateAgent> agent;
};

// Opens (or creates) DIR/flash.bin sized for `options.slots.slot_bytes` slots, constructs the agent
// and provisions a blank flash from `setup.provision_path`. Does not power on (call
// agent->PowerOn()). NOT_FOUND / IO_ERROR / PARSE_ERROR for the key, flash or image files;
// the slot manager's status when provisioning fails.
[[nodiscard]] Status OpenUpdateAgent(const AgentSetupOptions& setup,
                                     const UpdateAgentOptions& options, ProbeHooks* hooks,
                                     AgentSetup* out);

}  // namespace d3d::fw
