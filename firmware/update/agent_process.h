// Starts and stops d3d-update-agent as a separate process (integration tests, benchmarks): the
// simulated probe, whose flash survives being killed like real flash survives a power cut.
#pragma once

#include <sys/types.h>

#include <string>
#include <vector>

#include "common/core/status.h"

namespace d3d::fw {

class AgentProcess {
 public:
  AgentProcess() = default;
  ~AgentProcess();  // kills a process still running
  AgentProcess(const AgentProcess&) = delete;
  AgentProcess& operator=(const AgentProcess&) = delete;

  // Runs `binary args...` (stderr to `log_path` if given, appended) and waits up to timeout_ms
  // until something accepts connections on `socket_path`. kUnavailable if it exits or times out.
  Status Start(const std::string& binary, const std::vector<std::string>& args,
               const std::string& socket_path, const std::string& log_path = "",
               int timeout_ms = 10000);
  // SIGKILL (a power cut) and reap. Returns the wait status.
  int Kill();
  // SIGTERM, then wait; returns the exit code (or 128 + signal).
  int Stop();
  // Waits for the process to exit by itself (e.g. an injected power cut: exit code 86), up to
  // timeout_ms; -1 if it is still running (then it is left running).
  int WaitExit(int timeout_ms);
  bool running() const { return pid_ > 0; }
  pid_t pid() const { return pid_; }

 private:
  pid_t pid_ = -1;
};

// The directory holding the running executable (to find sibling tools in build/bin).
std::string ExecutableDir();

}  // namespace d3d::fw
