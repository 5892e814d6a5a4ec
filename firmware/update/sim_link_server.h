// The simulated probe's side of the sim link: a Unix stream socket on which one host at a time
// sends USB control transfers and bus resets (frame format in dfu_protocol.h), served by an
// UpdateAgent. After acknowledging a bus reset the server closes the connection (the device
// re-enumerates), performs the reset (which may reboot the probe) and accepts the next host.
#pragma once

#include <atomic>
#include <functional>
#include <string>

#include "common/core/status.h"
#include "firmware/update/update_agent.h"

namespace d3d::fw {

struct SimLinkServerOptions {
  std::string socket_path;
  // Called when a flash operation hit the injected power cut: the simulated probe must stop now
  // (the agent executable calls _exit). Default: return from ServeSimLink with kUnavailable.
  std::function<void()> on_power_cut;
  // Called after every bus reset with its result (for logs).
  std::function<void(const Status&)> on_reset;
};

// Serves until *stop becomes true (checked every 100 ms). kIoError when the socket cannot be bound.
Status ServeSimLink(UpdateAgent* agent, const SimLinkServerOptions& options,
                    const std::atomic<bool>* stop);

}  // namespace d3d::fw
