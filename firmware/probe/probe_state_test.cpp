#include "firmware/probe/probe_state.h"

#include <gtest/gtest.h>

namespace d3d {
namespace {

constexpr ProbeState kAll[] = {ProbeState::kIdle, ProbeState::kStreaming, ProbeState::kError,
                               ProbeState::kRecovering};

TEST(ProbeStateMachine, LegalCycle) {
  ProbeStateMachine m;
  std::vector<std::string> seen;
  m.AddObserver([&](ProbeState from, ProbeState to, const std::string&) {
    seen.push_back(std::string(ProbeStateName(from)) + ">" + ProbeStateName(to));
  });
  EXPECT_EQ(m.state(), ProbeState::kIdle);
  ASSERT_TRUE(m.Transition(ProbeState::kStreaming, "start").ok());
  EXPECT_TRUE(m.IsStreaming());
  ASSERT_TRUE(m.Transition(ProbeState::kError, "camera timeout").ok());
  EXPECT_EQ(m.last_error(), "camera timeout");
  ASSERT_TRUE(m.Transition(ProbeState::kRecovering, "reset").ok());
  ASSERT_TRUE(m.Transition(ProbeState::kIdle, "recovered").ok());
  ASSERT_TRUE(m.Transition(ProbeState::kStreaming, "start").ok());
  ASSERT_TRUE(m.Transition(ProbeState::kIdle, "stop").ok());
  EXPECT_EQ(seen,
            (std::vector<std::string>{"idle>streaming", "streaming>error", "error>recovering",
                                      "recovering>idle", "idle>streaming", "streaming>idle"}));
}

TEST(ProbeStateMachine, ExactlyTheDocumentedTransitionsAreLegal) {
  int legal = 0;
  for (ProbeState from : kAll)
    for (ProbeState to : kAll) legal += ProbeStateMachine::IsLegal(from, to);
  EXPECT_EQ(legal, 7);
  EXPECT_FALSE(ProbeStateMachine::IsLegal(ProbeState::kError, ProbeState::kStreaming));
  EXPECT_FALSE(ProbeStateMachine::IsLegal(ProbeState::kIdle, ProbeState::kRecovering));
  EXPECT_FALSE(ProbeStateMachine::IsLegal(ProbeState::kStreaming, ProbeState::kStreaming));
}

TEST(ProbeStateMachine, IllegalTransitionIsAnErrorAndChangesNothing) {
  ProbeStateMachine m;
  int calls = 0;
  m.AddObserver([&](ProbeState, ProbeState, const std::string&) { ++calls; });
  ASSERT_TRUE(m.Transition(ProbeState::kError, "projector fault").ok());
  const Status s = m.Transition(ProbeState::kStreaming, "start");
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("error -> streaming"), std::string::npos) << s.message();
  EXPECT_EQ(m.state(), ProbeState::kError);
  EXPECT_EQ(calls, 1);
  EXPECT_EQ(m.Transition(ProbeState::kIdle, "").code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(m.Transition(ProbeState::kError, "again").code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace d3d
