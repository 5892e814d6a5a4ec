// The probe's state machine: idle → streaming → error → recovering (→ idle).
//
//   idle ──start──▶ streaming ──stop──▶ idle
//   idle | streaming ──fault──▶ error ──recover──▶ recovering ──ok──▶ idle
//                                                  recovering ──fault──▶ error
// Every other transition (including to the same state) is illegal: Transition() returns
// INVALID_ARGUMENT naming both states and leaves the state unchanged.
//
// Threads: all members are thread-safe. Observers run on the thread that made the transition, after
// the state changed, without the lock held; they must not call Transition() themselves.
//
// Hook for the firmware-update agent (issue 8): it holds a `const ProbeStateQuery&` and asks
// IsStreaming() before installing, or observes transitions.
#pragma once

#include <functional>
#include <mutex>
#include <string>
#include <vector>

#include "common/core/status.h"

namespace d3d {

enum class ProbeState { kIdle, kStreaming, kError, kRecovering };
const char* ProbeStateName(ProbeState s);

// Read-only view of the probe state for other components of the firmware.
class ProbeStateQuery {
 public:
  virtual ~ProbeStateQuery() = default;
  virtual ProbeState state() const = 0;
  bool IsStreaming() const { return state() == ProbeState::kStreaming; }
};

class ProbeStateMachine final : public ProbeStateQuery {
 public:
  using Observer = std::function<void(ProbeState from, ProbeState to, const std::string& reason)>;

  static bool IsLegal(ProbeState from, ProbeState to);
  ProbeState state() const override;
  // `reason` is kept as last_error() when entering kError.
  [[nodiscard]] Status Transition(ProbeState to, const std::string& reason);
  std::string last_error() const;
  void AddObserver(Observer observer);

 private:
  mutable std::mutex mu_;
  ProbeState state_ = ProbeState::kIdle;
  std::string last_error_;
  std::vector<Observer> observers_;
};

}  // namespace d3d
