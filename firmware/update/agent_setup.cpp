#include "firmware/update/agent_setup.h"

#include <filesystem>
#include <fstream>
#include <iterator>
#include <vector>

namespace d3d::fw {

void AgentSetupOptions::Check() const {
  D3D_CHECK_MSG(!flash_dir.empty(), "flash_dir is required");
  D3D_CHECK_MSG(!pubkey_path.empty(), "pubkey_path is required");
  D3D_CHECK_MSG(erase_bytes > 0 && page_bytes > 0 && erase_bytes % page_bytes == 0,
                "the erase block (" << erase_bytes << " B) must be a multiple of the page ("
                                    << page_bytes << " B)");
}

Status OpenUpdateAgent(const AgentSetupOptions& setup, const UpdateAgentOptions& options,
                       ProbeHooks* hooks, AgentSetup* out) {
  setup.Check();
  D3D_RETURN_IF_ERROR(LoadPublicKey(setup.pubkey_path, &out->trusted_key));
  FlashGeometry g;
  g.erase_block_bytes = setup.erase_bytes;
  g.page_bytes = setup.page_bytes;
  g = SlotFlashGeometry(g, options.slots.slot_bytes);
  std::error_code ec;
  std::filesystem::create_directories(setup.flash_dir, ec);
  if (ec)
    return IoError("cannot create the flash directory '" + setup.flash_dir + "': " + ec.message());
  D3D_RETURN_IF_ERROR(Flash::OpenFile(setup.flash_dir + "/flash.bin", g, &out->flash));
  out->agent = std::make_unique<UpdateAgent>(out->flash.get(), out->trusted_key, options, hooks);
  bool provisioned = false;
  D3D_RETURN_IF_ERROR(out->agent->slots().IsProvisioned(&provisioned));
  if (provisioned || setup.provision_path.empty()) return Status::Ok();
  std::ifstream f(setup.provision_path, std::ios::binary);
  if (!f) return NotFound("cannot read the factory image '" + setup.provision_path + "'");
  const std::vector<uint8_t> image((std::istreambuf_iterator<char>(f)),
                                   std::istreambuf_iterator<char>());
  return out->agent->slots().Provision(image);
}

}  // namespace d3d::fw
