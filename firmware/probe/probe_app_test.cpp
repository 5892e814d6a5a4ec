// ProbeApp end to end in one process over DDS (loopback, shipped config): the sim backend with
// injected faults, the host receiver, ProbeCommand handling with acks.
#include "firmware/probe/probe_app.h"

#include <gtest/gtest.h>

#include <thread>

#include "host/receiver/receiver.h"
#include "protocol/protocol.h"

namespace d3d {
namespace {

std::unique_ptr<CaptureBackend> SimBackend(double fault_rate) {
  CaptureBackendRegistry reg;
  RegisterBuiltinCaptureBackends(&reg);
  CaptureOptions o;
  o.sim_cycle = 2;
  o.sim_fault_rate = fault_rate;
  o.seed = 3;
  std::unique_ptr<CaptureBackend> b;
  EXPECT_TRUE(reg.CreateAndOpen("sim", o, &b).ok());
  return b;
}

TEST(CaptureRegistry, UnknownAndAuto) {
  CaptureBackendRegistry reg;
  RegisterBuiltinCaptureBackends(&reg);
  std::unique_ptr<CaptureBackend> b;
  EXPECT_EQ(reg.CreateAndOpen("nope", CaptureOptions{}, &b).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(reg.Names(), (std::vector<std::string>{"sim", "libcamera"}));
}

TEST(ProbeApp, FaultyBurstsAreDroppedNeverPublished) {
  proto::DdsParticipant pp;
  ASSERT_TRUE(pp.Create({62, proto::SelectCycloneConfig(nullptr, 0, 0, nullptr)}).ok());
  BurstReceiver rx(ReceiverOptions{});
  ASSERT_TRUE(rx.Start(&pp).ok());
  ProbeAppOptions o;
  o.max_bursts = 12;
  o.rate_hz = 30;
  auto backend = SimBackend(0.08);
  const CaptureInfo info = backend->info();
  ProbeApp app(o, std::move(backend), std::make_unique<LoggingProjectorDriver>(nullptr), &pp);
  ASSERT_TRUE(app.Start().ok());
  ASSERT_TRUE(app.Run().ok());
  EXPECT_EQ(app.counters().bursts_published, 12u);
  EXPECT_GT(app.sync_counters().dropped_total(), 0u) << "8 % faulty frames in 12+ bursts";
  int bursts = 0, infos = 0, statuses = 0;
  ReceivedSample r;
  while (rx.Pop(&r, 500'000'000)) {
    if (const auto* b = std::get_if<proto::BurstMsg>(&r.msg)) {
      EXPECT_EQ(b->burst_seq, static_cast<uint64_t>(bursts));
      ASSERT_EQ(b->frames.size(), 4u);
      for (int k = 0; k < 4; ++k) {
        EXPECT_EQ(b->frames[k].pattern_index, k);
        if (k > 0) {
          EXPECT_EQ(b->frames[k].timestamp_ns - b->frames[k - 1].timestamp_ns,
                    info.frame_interval_ns)
              << "an intact burst";
          EXPECT_EQ(b->frames[k].camera_frame_seq, b->frames[k - 1].camera_frame_seq + 1);
        }
      }
      ++bursts;
    } else if (std::holds_alternative<proto::InfoMsg>(r.msg)) {
      ++infos;
    } else {
      ++statuses;
    }
  }
  EXPECT_EQ(bursts, 12);
  EXPECT_EQ(infos, 1);
  EXPECT_GE(statuses, 1);
  EXPECT_EQ(rx.counters().dropped_total(), 0u);
  ProbeCalibration cal;
  ASSERT_TRUE(rx.LatestInfo(nullptr, &cal));
  EXPECT_EQ(cal.ToJson(), info.calibration.ToJson());
}

TEST(ProbeApp, CommandsAreObeyedAndAcknowledged) {
  proto::DdsParticipant pp;
  ASSERT_TRUE(pp.Create({63, proto::SelectCycloneConfig(nullptr, 0, 0, nullptr)}).ok());
  ProbeAppOptions o;
  o.start_streaming = false;
  auto* projector = new LoggingProjectorDriver(nullptr);
  ProbeApp app(o, SimBackend(0), std::unique_ptr<ProjectorDriver>(projector), &pp);
  ASSERT_TRUE(app.Start().ok());
  std::thread run([&] { EXPECT_TRUE(app.Run().ok()); });

  Status st;
  const dds_entity_t tc = pp.Topic(&d3d_proto_ProbeCommand_desc, proto::kTopicProbeCommand, &st);
  const dds_entity_t ta =
      pp.Topic(&d3d_proto_ProbeCommandAck_desc, proto::kTopicProbeCommandAck, &st);
  std::unique_ptr<dds_qos_t, proto::QosDeleter> qw(
      proto::MakeQos(proto::QosProfile::kCommandWriter));
  std::unique_ptr<dds_qos_t, proto::QosDeleter> qr(
      proto::MakeQos(proto::QosProfile::kCommandReader));
  const dds_entity_t w = dds_create_writer(pp.participant(), tc, qw.get(), nullptr);
  const dds_entity_t r = dds_create_reader(pp.participant(), ta, qr.get(), nullptr);
  ASSERT_GT(w, 0);
  ASSERT_GT(r, 0);
  auto send = [&](uint64_t id, d3d_proto_ProbeCommandKind kind,
                  double value) -> std::pair<bool, std::string> {
    d3d_proto_ProbeCommand c{};
    proto::CopyBounded(c.serial, o.serial);
    c.protocol_version = proto::kProtocolVersion;
    c.command_id = id;
    c.kind = kind;
    c.value = value;
    EXPECT_EQ(dds_write(w, &c), DDS_RETCODE_OK);
    for (int i = 0; i < 500; ++i) {
      void* samples[1] = {};
      dds_sample_info_t info;
      if (dds_take(r, samples, &info, 1, 1) == 1) {
        const auto* a = static_cast<const d3d_proto_ProbeCommandAck*>(samples[0]);
        std::pair<bool, std::string> out{a->accepted, proto::FromBounded(a->message)};
        const uint64_t got = a->command_id;
        dds_return_loan(r, samples, 1);
        EXPECT_EQ(got, id);
        return out;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    ADD_FAILURE() << "no ack for command " << id;
    return {false, "timeout"};
  };
  EXPECT_FALSE(app.state().IsStreaming());
  EXPECT_TRUE(send(1, d3d_proto_CMD_START_STREAMING, 0).first);
  EXPECT_TRUE(app.state().IsStreaming());
  const auto again = send(2, d3d_proto_CMD_START_STREAMING, 0);
  EXPECT_FALSE(again.first);
  EXPECT_NE(again.second.find("illegal"), std::string::npos) << again.second;
  EXPECT_TRUE(send(3, d3d_proto_CMD_SET_BRIGHTNESS, 0.5).first);
  EXPECT_FALSE(send(4, d3d_proto_CMD_SET_BRIGHTNESS, 1.5).first);
  EXPECT_TRUE(send(5, d3d_proto_CMD_SET_EXPOSURE, 800'000).first);
  EXPECT_FALSE(send(6, d3d_proto_CMD_SET_PATTERN_PERIOD, 20).first);
  EXPECT_TRUE(send(7, d3d_proto_CMD_STOP_STREAMING, 0).first);
  EXPECT_FALSE(app.state().IsStreaming());
  EXPECT_EQ(app.counters().last_command_id, 7u);
  app.RequestStop();
  run.join();
}

}  // namespace
}  // namespace d3d
