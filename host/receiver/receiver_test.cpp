#include "host/receiver/receiver.h"

#include <gtest/gtest.h>

#include <chrono>
#include <thread>

#include "protocol/protocol.h"

namespace d3d {
namespace {

using proto::BurstMsg;

BurstMsg Burst(uint64_t seq, uint16_t version = proto::kProtocolVersion) {
  BurstMsg b;
  b.serial = "P1";
  b.protocol_version = version;
  b.burst_seq = seq;
  b.width = 8;
  b.height = 6;
  b.pattern_set = "phase4-marker";
  for (int f = 0; f < 4; ++f) {
    proto::FrameMsg fr;
    fr.pattern_index = static_cast<uint16_t>(f);
    fr.timestamp_ns = 1000 + f * 10;
    fr.pixels.assign(48, static_cast<uint8_t>(seq + f));
    b.frames.push_back(fr);
  }
  return b;
}

DropReason Check(const BurstMsg& b) {
  d3d_proto_PhaseBurst s;
  std::vector<d3d_proto_ImageFrame> storage;
  proto::ToDds(b, &s, &storage);
  std::string detail;
  return CheckBurst(s, &detail);
}

TEST(CheckBurst, AcceptsValidRejectsMalformed) {
  EXPECT_EQ(Check(Burst(0)), DropReason::kCount);
  EXPECT_EQ(Check(Burst(0, 201)), DropReason::kProtocolVersion);
  BurstMsg b = Burst(0);
  b.frames[1].pixels.pop_back();
  EXPECT_EQ(Check(b), DropReason::kFrameSize);
  b = Burst(0);
  b.frames.resize(2);
  EXPECT_EQ(Check(b), DropReason::kFrameCount);
  b = Burst(0);
  b.width = 0;
  EXPECT_EQ(Check(b), DropReason::kGeometry);
  b = Burst(0);
  std::swap(b.frames[1].timestamp_ns, b.frames[2].timestamp_ns);
  EXPECT_EQ(Check(b), DropReason::kFrameOrder);
  b = Burst(0);
  b.bit_depth = 12;  // 16-bit storage: 8 × 6 × 2 bytes expected
  EXPECT_EQ(Check(b), DropReason::kFrameSize);
}

TEST(CheckInfo, CalibrationMustParseAndMatch) {
  ProbeCalibration c;
  c.camera = {8, 6, 20, 20, 3.5, 2.5, 0, 0, 0, 0, 0};
  c.projector = {16, 12, 20, 20, 7.5, 5.5, 0, 0, 0, 0, 0};
  c.cam_from_proj.translation() = Eigen::Vector3d(10, 0, 0);
  c.depth_min_mm = 40;
  c.depth_max_mm = 60;
  proto::InfoMsg m{"P1", proto::kProtocolVersion, "1", "s", "p", "sim", 8, 6, 8, c.ToJson()};
  ProbeCalibration out;
  std::string d;
  EXPECT_EQ(CheckInfo(m, &out, &d), DropReason::kCount) << d;
  EXPECT_EQ(out.camera.width, 8);
  m.width = 640;
  EXPECT_EQ(CheckInfo(m, &out, &d), DropReason::kCalibration);
  m.width = 8;
  m.calibration_json = "{not json";
  EXPECT_EQ(CheckInfo(m, &out, &d), DropReason::kCalibration);
}

// In-process DDS: the receiver counts gaps, duplicates and malformed samples and passes the rest in
// order, without blocking the writer.
TEST(BurstReceiver, ChecksSequenceAndDropsMalformed) {
  proto::DdsParticipant pp;
  ASSERT_TRUE(pp.Create({61, proto::SelectCycloneConfig(nullptr, 0, 0, nullptr)}).ok());
  std::vector<std::string> logged;
  std::mutex log_mu;
  ReceiverOptions o;
  o.log = [&](const std::string& m) {
    std::lock_guard<std::mutex> lock(log_mu);
    logged.push_back(m);
  };
  BurstReceiver rx(o);
  ASSERT_TRUE(rx.Start(&pp).ok());
  Status st;
  const dds_entity_t topic = pp.Topic(&d3d_proto_PhaseBurst_desc, proto::kTopicPhaseBurst, &st);
  std::unique_ptr<dds_qos_t, proto::QosDeleter> q(proto::MakeQos(proto::QosProfile::kBurstWriter));
  const dds_entity_t w = dds_create_writer(pp.participant(), topic, q.get(), nullptr);
  ASSERT_GT(w, 0);
  std::vector<BurstMsg> sent = {
      Burst(0), Burst(1), Burst(3), Burst(2) /*late*/, Burst(4, 300) /*version*/, Burst(4)};
  sent.push_back(Burst(5));
  sent.back().frames[3].pixels.resize(10);  // torn frame
  sent.push_back(Burst(5));
  for (const BurstMsg& b : sent) {
    d3d_proto_PhaseBurst s;
    std::vector<d3d_proto_ImageFrame> storage;
    proto::ToDds(b, &s, &storage);
    ASSERT_EQ(dds_write(w, &s), DDS_RETCODE_OK);
  }
  std::vector<uint64_t> got;
  ReceivedSample r;
  while (got.size() < 5 && rx.Pop(&r, 5'000'000'000)) {
    if (const auto* b = std::get_if<BurstMsg>(&r.msg)) {
      got.push_back(b->burst_seq);
      EXPECT_EQ(*b, Burst(b->burst_seq));
    }
    rx.Recycle(std::move(r));
  }
  EXPECT_EQ(got, (std::vector<uint64_t>{0, 1, 3, 4, 5}));
  const ReceiverCounters c = rx.counters();
  EXPECT_EQ(c.bursts_accepted, 5u);
  EXPECT_EQ(c.sequence_gaps, 1u);
  EXPECT_EQ(c.bursts_missing, 1u);
  EXPECT_EQ(c.dropped[static_cast<size_t>(DropReason::kDuplicate)], 1u);
  EXPECT_EQ(c.dropped[static_cast<size_t>(DropReason::kProtocolVersion)], 1u);
  EXPECT_EQ(c.dropped[static_cast<size_t>(DropReason::kFrameSize)], 1u);
  std::lock_guard<std::mutex> lock(log_mu);
  ASSERT_EQ(logged.size(), 3u);
  EXPECT_NE(logged[0].find("duplicate"), std::string::npos) << logged[0];
}

}  // namespace
}  // namespace d3d
