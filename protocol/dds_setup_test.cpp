#include "protocol/dds_setup.h"

#include <gtest/gtest.h>
#include <spawn.h>
#include <sys/wait.h>

#include <chrono>
#include <thread>

#include "protocol/d3d_protocol.h"
#include "protocol/messages.h"
#include "protocol/protocol.h"

extern char** environ;

namespace d3d::proto {
namespace {

TEST(CycloneConfig, ShippedByDefaultEnvWins) {
  std::string warning;
  EXPECT_EQ(SelectCycloneConfig("file:///x.xml", 0, 0, &warning), "");
  const std::string xml = SelectCycloneConfig(nullptr, 8 << 20, 8 << 20, &warning);
  EXPECT_NE(xml.find("<SocketReceiveBufferSize min=\"4MB\"/>"), std::string::npos);
  EXPECT_NE(xml.find("<MaxMessageSize>65500B</MaxMessageSize>"), std::string::npos);
  EXPECT_TRUE(warning.empty());
}

TEST(CycloneConfig, RelaxesMinimumWhenKernelLimitIsLower) {
  std::string warning;
  const std::string xml = SelectCycloneConfig(nullptr, 212992, 212992, &warning);
  EXPECT_NE(xml.find("<SocketReceiveBufferSize max=\"4MB\"/>"), std::string::npos) << xml;
  EXPECT_NE(xml.find("<SocketSendBufferSize max=\"2MB\"/>"), std::string::npos) << xml;
  EXPECT_NE(warning.find("rmem_max"), std::string::npos);
  // Cyclone accepts the relaxed configuration.
  DdsParticipant p;
  ASSERT_TRUE(p.Create({53, xml}).ok());
}

// Runs a command, returns its pid (waited for by the caller).
pid_t Spawn(const std::vector<std::string>& args) {
  std::vector<char*> argv;
  for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  pid_t pid = -1;
  EXPECT_EQ(posix_spawn(&pid, argv[0], nullptr, nullptr, argv.data(), environ), 0) << args[0];
  return pid;
}

// An older probe (protocol 1.0, frozen IDL, separate process) writes; the current types read.
TEST(ProtocolVersioning, NewerReaderReadsOlderWriter) {
  constexpr int kDomain = 52, kBursts = 5;
  DdsParticipant p;
  ASSERT_TRUE(p.Create({kDomain, SelectCycloneConfig(nullptr, 0, 0, nullptr)}).ok());
  Status st;
  const dds_entity_t tb = p.Topic(&d3d_proto_PhaseBurst_desc, kTopicPhaseBurst, &st);
  ASSERT_TRUE(st.ok()) << st.ToString();
  const dds_entity_t ts = p.Topic(&d3d_proto_ProbeStatus_desc, kTopicProbeStatus, &st);
  ASSERT_TRUE(st.ok()) << st.ToString();
  std::unique_ptr<dds_qos_t, QosDeleter> q(MakeQos(QosProfile::kBurstRecordReader));
  const dds_entity_t rb = dds_create_reader(p.participant(), tb, q.get(), nullptr);
  const dds_entity_t rs = dds_create_reader(p.participant(), ts, q.get(), nullptr);
  ASSERT_GT(rb, 0);
  ASSERT_GT(rs, 0);
  const pid_t pid = Spawn(
      {D3D_V1_0_WRITER, D3D_CYCLONE_XML_PATH, std::to_string(kDomain), std::to_string(kBursts)});

  std::vector<BurstMsg> bursts;
  std::vector<StatusMsg> statuses;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  while ((bursts.size() < kBursts || statuses.empty()) &&
         std::chrono::steady_clock::now() < deadline) {
    void* samples[4] = {};
    dds_sample_info_t infos[4];
    int n = dds_take(rb, samples, infos, 4, 4);
    for (int i = 0; i < n; ++i) {
      if (!infos[i].valid_data) continue;
      bursts.emplace_back();
      FromDds(*static_cast<d3d_proto_PhaseBurst*>(samples[i]), &bursts.back());
    }
    if (n > 0) dds_return_loan(rb, samples, n);
    n = dds_take(rs, samples, infos, 4, 4);
    for (int i = 0; i < n; ++i) {
      if (!infos[i].valid_data) continue;
      statuses.emplace_back();
      FromDds(*static_cast<d3d_proto_ProbeStatus*>(samples[i]), &statuses.back());
    }
    if (n > 0) dds_return_loan(rs, samples, n);
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  int wstatus = 0;
  ASSERT_EQ(waitpid(pid, &wstatus, 0), pid);
  EXPECT_TRUE(WIFEXITED(wstatus) && WEXITSTATUS(wstatus) == 0) << "old writer failed";

  ASSERT_EQ(bursts.size(), static_cast<size_t>(kBursts));
  for (int b = 0; b < kBursts; ++b) {
    const BurstMsg& m = bursts[b];
    EXPECT_EQ(m.serial, "OLD-1");
    EXPECT_EQ(m.protocol_version, 100);
    EXPECT_TRUE(ProtocolCompatible(m.protocol_version));
    EXPECT_EQ(m.burst_seq, static_cast<uint64_t>(b));
    ASSERT_EQ(m.frames.size(), 4u);
    for (int f = 0; f < 4; ++f) {
      EXPECT_EQ(m.frames[f].pattern, "phase4-marker/" + std::to_string(f));
      EXPECT_EQ(m.frames[f].camera_frame_seq, 0u) << "appended in 1.1: default for a 1.0 sample";
      ASSERT_EQ(m.frames[f].pixels.size(), 48u);
      for (int i = 0; i < 48; ++i) EXPECT_EQ(m.frames[f].pixels[i], (b * 31 + f * 7 + i) % 256);
    }
  }
  ASSERT_EQ(statuses.size(), 1u);
  EXPECT_EQ(statuses[0].state, ProbeStateKind::kStreaming);
  EXPECT_EQ(statuses[0].bursts_published, static_cast<uint64_t>(kBursts));
  EXPECT_EQ(statuses[0].last_error, "none");
  EXPECT_EQ(statuses[0].publish_failures, 0u);
  EXPECT_EQ(statuses[0].last_command_id, 0u);
}

}  // namespace
}  // namespace d3d::proto
