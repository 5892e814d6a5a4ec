#include "firmware/probe/probe_state.h"

namespace d3d {

const char* ProbeStateName(ProbeState s) {
  switch (s) {
    case ProbeState::kIdle:
      return "idle";
    case ProbeState::kStreaming:
      return "streaming";
    case ProbeState::kError:
      return "error";
    case ProbeState::kRecovering:
      return "recovering";
  }
  return "unknown";
}

bool ProbeStateMachine::IsLegal(ProbeState from, ProbeState to) {
  using S = ProbeState;
  switch (from) {
    case S::kIdle:
      return to == S::kStreaming || to == S::kError;
    case S::kStreaming:
      return to == S::kIdle || to == S::kError;
    case S::kError:
      return to == S::kRecovering;
    case S::kRecovering:
      return to == S::kIdle || to == S::kError;
  }
  return false;
}

ProbeState ProbeStateMachine::state() const {
  std::lock_guard<std::mutex> lock(mu_);
  return state_;
}

std::string ProbeStateMachine::last_error() const {
  std::lock_guard<std::mutex> lock(mu_);
  return last_error_;
}

void ProbeStateMachine::AddObserver(Observer observer) {
  std::lock_guard<std::mutex> lock(mu_);
  observers_.push_back(std::move(observer));
}

Status ProbeStateMachine::Transition(ProbeState to, const std::string& reason) {
  ProbeState from;
  std::vector<Observer> observers;
  {
    std::lock_guard<std::mutex> lock(mu_);
    from = state_;
    if (!IsLegal(from, to)) {
      std::string m("illegal probe state transition ");
      m.append(ProbeStateName(from)).append(" -> ").append(ProbeStateName(to));
      if (!reason.empty()) m.append(" (").append(reason).append(")");
      return InvalidArgument(m);
    }
    state_ = to;
    if (to == ProbeState::kError) last_error_ = reason;
    observers = observers_;
  }
  for (const auto& o : observers) o(from, to, reason);
  return Status::Ok();
}

}  // namespace d3d
