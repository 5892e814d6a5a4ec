#include "firmware/update/dfu_device.h"

#include <gtest/gtest.h>

namespace d3d::dfu {
namespace {

struct FakeBackend : DfuBackend {
  bool refuse_detach = false;
  uint8_t fail_block_status = kOk;
  size_t expected_bytes = 0;
  size_t received = 0;
  int manifests = 0, aborts = 0;
  uint8_t manifest_status = kOk;
  BackendReply Detach() override {
    if (refuse_detach) return {kErrVendor, "streaming: busy", 0};
    return {};
  }
  BackendReply BeginDownload() override {
    received = 0;
    return {};
  }
  BackendReply DownloadBlock(std::span<const uint8_t> d) override {
    if (fail_block_status != kOk) return {fail_block_status, "payload-hash: bad", 0};
    received += d.size();
    return {kOk, "", 25};
  }
  bool DownloadComplete(std::string* why) override {
    if (received == expected_bytes) return true;
    *why = "truncated: short";
    return false;
  }
  BackendReply Manifest() override {
    ++manifests;
    return {manifest_status, manifest_status == kOk ? "" : "bad-signature: no", 40};
  }
  void AbortDownload() override { ++aborts; }
};

class DfuDeviceTest : public ::testing::Test {
 protected:
  DfuDeviceTest() : dev(&backend, Options()) {}
  DfuDeviceOptions Options() {
    DfuDeviceOptions o;
    o.transfer_size = 64;
    o.clock_ms = [this] { return now; };
    return o;
  }
  ControlResponse Out(uint8_t req, uint16_t value, std::vector<uint8_t> data = {}) {
    SetupPacket s{kRequestTypeClassOut, req, value, 0, static_cast<uint16_t>(data.size())};
    return dev.Handle(s, data);
  }
  StatusReport GetStatus() {
    const ControlResponse r = dev.Handle({kRequestTypeClassIn, kGetStatus, 0, 0, 6}, {});
    EXPECT_FALSE(r.stall);
    EXPECT_EQ(r.data.size(), 6u);
    return StatusReport::Decode(std::span<const uint8_t, 6>(r.data.data(), 6));
  }
  void EnterDfuMode() {
    ASSERT_FALSE(Out(kDetach, 1000).stall);
    ASSERT_EQ(dev.state(), kAppDetach);
    ASSERT_EQ(dev.OnBusReset(), DfuDevice::ResetAction::kEnterDfuMode);
    ASSERT_EQ(dev.state(), kDfuIdle);
  }
  int64_t now = 1000;
  FakeBackend backend;
  DfuDevice dev;
};

TEST_F(DfuDeviceTest, DownloadManifestSequenceFollowsTheSpecDiagram) {
  EnterDfuMode();
  backend.expected_bytes = 100;
  ASSERT_FALSE(Out(kDnload, 0, std::vector<uint8_t>(64, 1)).stall);
  EXPECT_EQ(dev.state(), kDfuDnloadSync);
  StatusReport s = GetStatus();
  EXPECT_EQ(s.state, kDfuDnBusy);
  EXPECT_EQ(s.poll_timeout_ms, 25u);
  now += 25;
  s = GetStatus();
  EXPECT_EQ(s.state, kDfuDnloadIdle);
  ASSERT_FALSE(Out(kDnload, 1, std::vector<uint8_t>(36, 2)).stall);
  EXPECT_EQ(GetStatus().state, kDfuDnBusy);
  now += 25;
  EXPECT_EQ(GetStatus().state, kDfuDnloadIdle);
  ASSERT_FALSE(Out(kDnload, 2).stall);  // zero length: end of image
  EXPECT_EQ(dev.state(), kDfuManifestSync);
  s = GetStatus();
  EXPECT_EQ(s.state, kDfuManifest);
  EXPECT_EQ(s.poll_timeout_ms, 40u);
  EXPECT_EQ(backend.manifests, 1);
  now += 40;
  s = GetStatus();  // manifestation tolerant: back to dfuIDLE
  EXPECT_EQ(s.state, kDfuIdle);
  EXPECT_EQ(s.status, kOk);
  EXPECT_EQ(dev.OnBusReset(), DfuDevice::ResetAction::kReboot);
  EXPECT_EQ(dev.state(), kAppIdle);
}

TEST_F(DfuDeviceTest, RequestDuringBusyStallsIntoError) {
  EnterDfuMode();
  ASSERT_FALSE(Out(kDnload, 0, std::vector<uint8_t>(10, 1)).stall);
  EXPECT_EQ(GetStatus().state, kDfuDnBusy);
  now += 5;  // before bwPollTimeout
  const ControlResponse r = dev.Handle({kRequestTypeClassIn, kGetStatus, 0, 0, 6}, {});
  EXPECT_TRUE(r.stall);
  EXPECT_EQ(dev.state(), kDfuError);
  EXPECT_EQ(dev.status(), kErrStalledPkt);
  const StatusReport s = GetStatus();
  EXPECT_EQ(s.state, kDfuError);
  EXPECT_EQ(s.string_index, kStrLastError);
  ASSERT_FALSE(Out(kClrStatus, 0).stall);
  EXPECT_EQ(dev.state(), kDfuIdle);
  EXPECT_EQ(GetStatus().status, kOk);
}

TEST_F(DfuDeviceTest, BlockFailureIsReportedByGetStatusWithTheReason) {
  EnterDfuMode();
  backend.fail_block_status = kErrVerify;
  ASSERT_FALSE(Out(kDnload, 0, std::vector<uint8_t>(10, 1)).stall);
  const StatusReport s = GetStatus();
  EXPECT_EQ(s.state, kDfuError);
  EXPECT_EQ(s.status, kErrVerify);
  EXPECT_EQ(dev.last_error(), "payload-hash: bad");
  EXPECT_TRUE(Out(kAbort, 0).stall);    // only CLRSTATUS leaves dfuERROR
  EXPECT_EQ(dev.status(), kErrVerify);  // the original reason is kept
}

TEST_F(DfuDeviceTest, IncompleteImageGivesErrNotDone) {
  EnterDfuMode();
  backend.expected_bytes = 1000;
  ASSERT_FALSE(Out(kDnload, 0, std::vector<uint8_t>(10, 1)).stall);
  GetStatus();
  now += 25;
  GetStatus();
  EXPECT_TRUE(Out(kDnload, 1).stall);
  EXPECT_EQ(dev.state(), kDfuError);
  EXPECT_EQ(dev.status(), kErrNotDone);
}

TEST_F(DfuDeviceTest, ManifestFailureAndBlockSequenceAndOversizeRequests) {
  EnterDfuMode();
  backend.expected_bytes = 10;
  backend.manifest_status = kErrFile;
  ASSERT_FALSE(Out(kDnload, 0, std::vector<uint8_t>(10, 1)).stall);
  GetStatus();
  now += 25;
  GetStatus();
  ASSERT_FALSE(Out(kDnload, 1).stall);
  StatusReport s = GetStatus();
  EXPECT_EQ(s.state, kDfuError);
  EXPECT_EQ(s.status, kErrFile);
  ASSERT_FALSE(Out(kClrStatus, 0).stall);
  // Out-of-sequence block.
  ASSERT_FALSE(Out(kDnload, 7, std::vector<uint8_t>(10, 1)).stall);
  GetStatus();
  now += 25;
  GetStatus();
  EXPECT_TRUE(Out(kDnload, 9, std::vector<uint8_t>(10, 1)).stall);
  EXPECT_EQ(dev.status(), kErrAddress);
  ASSERT_FALSE(Out(kClrStatus, 0).stall);
  // More than wTransferSize.
  EXPECT_TRUE(Out(kDnload, 0, std::vector<uint8_t>(65, 1)).stall);
  EXPECT_EQ(dev.state(), kDfuError);
}

TEST_F(DfuDeviceTest, RunTimeModeRefusesDetachWithAReasonAndStaysInAppIdle) {
  backend.refuse_detach = true;
  EXPECT_TRUE(Out(kDetach, 1000).stall);
  EXPECT_EQ(dev.state(), kAppIdle);
  const StatusReport s = GetStatus();
  EXPECT_EQ(s.status, kErrVendor);
  EXPECT_EQ(s.state, kAppIdle);
  EXPECT_EQ(dev.last_error(), "streaming: busy");
  EXPECT_EQ(dev.OnBusReset(), DfuDevice::ResetAction::kNone);
  EXPECT_TRUE(Out(kDnload, 0, std::vector<uint8_t>(4, 0)).stall);  // no download in run-time mode
  EXPECT_EQ(dev.state(), kAppIdle);
}

TEST_F(DfuDeviceTest, DetachTimesOutWithoutReset) {
  ASSERT_FALSE(Out(kDetach, 100).stall);
  EXPECT_EQ(dev.state(), kAppDetach);
  now += 101;
  EXPECT_EQ(GetStatus().state, kAppIdle);
}

TEST_F(DfuDeviceTest, AbortAndResetDropAPartialDownload) {
  EnterDfuMode();
  ASSERT_FALSE(Out(kDnload, 0, std::vector<uint8_t>(10, 1)).stall);
  GetStatus();
  now += 25;
  GetStatus();
  ASSERT_FALSE(Out(kAbort, 0).stall);
  EXPECT_EQ(dev.state(), kDfuIdle);
  EXPECT_EQ(backend.aborts, 1);
  ASSERT_FALSE(Out(kDnload, 0, std::vector<uint8_t>(10, 1)).stall);
  EXPECT_EQ(dev.OnBusReset(), DfuDevice::ResetAction::kReboot);
  EXPECT_EQ(backend.aborts, 2);
  EXPECT_EQ(dev.state(), kAppIdle);
}

TEST_F(DfuDeviceTest, WrongDirectionAndUnknownRequestsStall) {
  EnterDfuMode();
  EXPECT_TRUE(dev.Handle({kRequestTypeClassOut, kGetStatus, 0, 0, 0}, {}).stall);
  EXPECT_EQ(dev.state(), kDfuError);
  ASSERT_FALSE(Out(kClrStatus, 0).stall);
  EXPECT_TRUE(
      dev.Handle({kRequestTypeClassIn, kUpload, 0, 0, 64}, {}).stall);  // upload not supported
  ASSERT_FALSE(Out(kClrStatus, 0).stall);
  EXPECT_TRUE(Out(9, 0).stall);
  EXPECT_EQ(dev.state(), kDfuError);
  const ControlResponse st = dev.Handle({kRequestTypeClassIn, kGetState, 0, 0, 1}, {});
  ASSERT_EQ(st.data.size(), 1u);
  EXPECT_EQ(st.data[0], kDfuError);
}

}  // namespace
}  // namespace d3d::dfu
