// The host's DFU layer against the probe's update agent in one process (a loopback transport),
// with every request checked against the DFU 1.1 state diagram (spec Appendix A) — written here
// independently of the device's implementation.
#include "host/flash/dfu_host.h"

#include <gtest/gtest.h>

#include <chrono>
#include <map>
#include <set>

#include "firmware/update/test_images.h"
#include "firmware/update/update_agent.h"
#include "host/flash/usb_transport.h"

namespace d3d::flash {
namespace {

using namespace d3d::dfu;
using fw::testing::MakeImage;
using fw::testing::MakeTestKey;

struct Hooks : fw::ProbeHooks {
  bool streaming = false;
  fw::HealthResult health = fw::HealthResult::kHealthy;
  bool IsStreaming() const override { return streaming; }
  fw::HealthResult HealthCheck(const fw::ImageHeader&) override { return health; }
};

// DFU 1.1 Appendix A: the class requests a host may send in each state, and the states each may
// lead to.
const std::map<uint8_t, std::set<uint8_t>>& AllowedRequests() {
  static const std::map<uint8_t, std::set<uint8_t>> m = {
      {kAppIdle, {kDetach, kGetStatus, kGetState}},
      {kAppDetach, {kGetStatus, kGetState}},
      {kDfuIdle, {kDnload, kUpload, kAbort, kGetStatus, kGetState}},
      {kDfuDnloadSync, {kGetStatus, kGetState}},
      {kDfuDnBusy, {}},
      {kDfuDnloadIdle, {kDnload, kAbort, kGetStatus, kGetState}},
      {kDfuManifestSync, {kGetStatus, kGetState}},
      {kDfuManifest, {}},
      {kDfuManifestWaitReset, {}},
      {kDfuUploadIdle, {kUpload, kAbort, kGetStatus, kGetState}},
      {kDfuError, {kGetStatus, kClrStatus, kGetState}},
  };
  return m;
}
const std::set<std::pair<uint8_t, uint8_t>>&
AllowedTransitions() {  // (from, to) caused by a request
  static const std::set<std::pair<uint8_t, uint8_t>> t = {
      {kAppIdle, kAppDetach},
      {kDfuIdle, kDfuDnloadSync},
      {kDfuDnloadSync, kDfuDnBusy},
      {kDfuDnloadSync, kDfuDnloadIdle},
      {kDfuDnloadSync, kDfuError},
      {kDfuDnloadIdle, kDfuDnloadSync},
      {kDfuDnloadIdle, kDfuManifestSync},
      {kDfuDnloadIdle, kDfuIdle},
      {kDfuDnloadIdle, kDfuError},
      {kDfuManifestSync, kDfuManifest},
      {kDfuManifestSync, kDfuIdle},
      {kDfuManifestSync, kDfuError},
      {kDfuError, kDfuIdle},
      {kDfuIdle, kDfuError},
  };
  return t;
}

class CheckingLoopback : public DfuTransport {
 public:
  explicit CheckingLoopback(fw::UpdateAgent* a) : agent_(a) {}
  ControlResult Control(const SetupPacket& s, std::span<uint8_t> data) override {
    const bool dfu_request =
        (s.request_type == kRequestTypeClassIn || s.request_type == kRequestTypeClassOut);
    const auto now = std::chrono::steady_clock::now();
    uint8_t before = agent_->dfu().state();
    // Timed transitions the device makes on its own once bwPollTimeout elapsed.
    if (before == kDfuDnBusy && now >= busy_until_) before = kDfuDnloadSync;
    if (before == kDfuManifest && now >= busy_until_) before = kDfuManifestSync;
    if (dfu_request) {
      sequence.push_back(std::string(StateName(before)) + ":" + std::to_string(s.request));
      if (!AllowedRequests().at(before).count(s.request)) {
        violations.push_back("request " + std::to_string(s.request) + " in " + StateName(before));
      }
    }
    const ControlResponse r =
        agent_->HandleControl(s, std::span<const uint8_t>(data.data(), s.is_in() ? 0 : s.length));
    const uint8_t after = agent_->dfu().state();
    if (dfu_request && after != before && !AllowedTransitions().count({before, after})) {
      violations.push_back(std::string("transition ") + StateName(before) + " -> " +
                           StateName(after));
    }
    if (dfu_request && s.request == kGetStatus && r.data.size() == 6) {
      const StatusReport rep = StatusReport::Decode(std::span<const uint8_t, 6>(r.data.data(), 6));
      busy_until_ = now + std::chrono::milliseconds(rep.poll_timeout_ms);
    }
    ControlResult out;
    out.stalled = r.stall;
    out.length = r.data.size();
    std::copy(r.data.begin(), r.data.end(), data.begin());
    return out;
  }
  Status BusReset() override {
    const uint8_t before = agent_->dfu().state();
    if (before != kAppDetach && before < kDfuIdle)
      violations.push_back("reset in run-time mode without DETACH");
    ++resets;
    return agent_->BusReset();
  }
  Status Reopen(int) override { return Status::Ok(); }
  std::string Describe() const override { return "loopback"; }

  std::vector<std::string> violations, sequence;
  int resets = 0;

 private:
  fw::UpdateAgent* agent_;
  std::chrono::steady_clock::time_point busy_until_{};
};

class DfuHostTest : public ::testing::Test {
 protected:
  void SetUp() override {
    fw::FlashGeometry g;
    g.erase_block_bytes = 4096;
    g.page_bytes = 256;
    fw::UpdateAgentOptions o;
    o.slots.hw_id = 1;
    o.slots.slot_bytes = 128 * 1024;
    o.dfu.transfer_size = 1024;
    o.dfu.fixed_poll_ms = 1;  // the host must honour it
    flash = fw::Flash::InMemory(fw::SlotFlashGeometry(g, o.slots.slot_bytes));
    agent = std::make_unique<fw::UpdateAgent>(flash.get(), key.pk, o, &hooks);
    ASSERT_TRUE(agent->slots().Provision(MakeImage(&key, {1, 0, 0}, 1, 1, 30000, 1)).ok());
    ASSERT_TRUE(agent->PowerOn().ok());
    link = std::make_unique<CheckingLoopback>(agent.get());
  }
  fw::testing::TestKey key = MakeTestKey(1);
  Hooks hooks;
  std::unique_ptr<fw::Flash> flash;
  std::unique_ptr<fw::UpdateAgent> agent;
  std::unique_ptr<CheckingLoopback> link;
};

TEST_F(DfuHostTest, HappyPathFollowsTheDfuStateDiagram) {
  const auto img = MakeImage(&key, {1, 1, 0}, 1, 1, 50000, 2);
  uint64_t last = 0;
  FlashOptions o;
  o.progress = [&](uint64_t done, uint64_t total) {
    EXPECT_GT(done, last);
    EXPECT_EQ(total, img.size());
    last = done;
  };
  const FlashReport r = FlashImage(link.get(), img, o);
  EXPECT_EQ(r.outcome, FlashOutcome::kUpdated) << r.reason;
  EXPECT_EQ(r.before.VersionString(), "1.0.0");
  ASSERT_TRUE(r.have_after);
  EXPECT_EQ(r.after.VersionString(), "1.1.0");
  EXPECT_EQ(r.after.boot_state, BootState::kConfirmed);
  EXPECT_EQ(r.after.running_slot, 1);
  EXPECT_EQ(last, img.size());
  EXPECT_EQ(r.blocks, static_cast<int64_t>((img.size() + 1023) / 1024));
  EXPECT_EQ(r.download_transfers,
            3 * r.blocks);  // DNLOAD, GETSTATUS (dfuDNBUSY), GETSTATUS (dfuDNLOAD-IDLE)
  EXPECT_GE(r.poll_wait_ms,
            static_cast<double>(r.blocks));  // waited bwPollTimeout = 1 ms per block
  EXPECT_TRUE(link->violations.empty()) << link->violations.front();
  EXPECT_EQ(link->resets, 2);  // after DETACH, after manifestation
  // The request sequence, compressed: DETACH, first block, ..., manifestation.
  ASSERT_GE(link->sequence.size(), 6u);
  EXPECT_EQ(link->sequence[0], "appIDLE:0");
  EXPECT_EQ(link->sequence[1], "dfuIDLE:3");
  EXPECT_EQ(link->sequence[2], "dfuIDLE:1");
  EXPECT_EQ(link->sequence[3], "dfuDNLOAD-SYNC:3");
  EXPECT_EQ(link->sequence[4], "dfuDNLOAD-SYNC:3");
  EXPECT_EQ(link->sequence[5], "dfuDNLOAD-IDLE:1");
  EXPECT_EQ(link->sequence[link->sequence.size() - 3], "dfuDNLOAD-IDLE:1");  // zero-length DNLOAD
  EXPECT_EQ(link->sequence[link->sequence.size() - 2], "dfuMANIFEST-SYNC:3");
  EXPECT_EQ(link->sequence.back(), "dfuMANIFEST-SYNC:3");
}

TEST_F(DfuHostTest, RefusalCarriesTheExactReasonAndTheOldVersionRuns) {
  const auto other = MakeTestKey(2);
  const FlashReport r = FlashImage(link.get(), MakeImage(&other, {1, 1, 0}, 1, 1, 50000, 2), {});
  EXPECT_EQ(r.outcome, FlashOutcome::kRefused);
  EXPECT_EQ(r.dfu_status, kErrFile);
  EXPECT_EQ(r.reason.rfind("unknown-key:", 0), 0u) << r.reason;
  ASSERT_TRUE(r.have_after);
  EXPECT_EQ(r.after.VersionString(), "1.0.0");
  EXPECT_FALSE(r.after.dfu_mode);
  EXPECT_TRUE(link->violations.empty()) << link->violations.front();
}

TEST_F(DfuHostTest, WrongHardwareIsRefusedAtTheFirstBlock) {
  const FlashReport r = FlashImage(link.get(), MakeImage(&key, {1, 1, 0}, 1, 7, 50000, 2), {});
  EXPECT_EQ(r.outcome, FlashOutcome::kRefused);
  EXPECT_EQ(r.dfu_status, kErrTarget);
  EXPECT_EQ(r.blocks, 0);
  EXPECT_EQ(r.reason.rfind("wrong-hardware:", 0), 0u) << r.reason;
  EXPECT_TRUE(link->violations.empty()) << link->violations.front();
}

TEST_F(DfuHostTest, StreamingProbeRefusesToDetach) {
  hooks.streaming = true;
  const FlashReport r = FlashImage(link.get(), MakeImage(&key, {1, 1, 0}, 1, 1, 5000, 2), {});
  EXPECT_EQ(r.outcome, FlashOutcome::kRefused);
  EXPECT_EQ(r.dfu_status, kErrVendor);
  EXPECT_EQ(r.reason.rfind("streaming:", 0), 0u) << r.reason;
  EXPECT_TRUE(r.after.streaming);
  EXPECT_EQ(link->resets, 0);
}

TEST_F(DfuHostTest, UnhealthyFirmwareRollsBack) {
  hooks.health = fw::HealthResult::kUnhealthy;
  const FlashReport r = FlashImage(link.get(), MakeImage(&key, {1, 1, 0}, 1, 1, 50000, 2), {});
  EXPECT_EQ(r.outcome, FlashOutcome::kRolledBack) << r.reason;
  EXPECT_EQ(r.after.VersionString(), "1.0.0");
  EXPECT_EQ(r.after.boot_state, BootState::kRolledBack);
}

TEST_F(DfuHostTest, DryRunChangesNothing) {
  FlashOptions o;
  o.dry_run = true;
  const FlashReport r = FlashImage(link.get(), MakeImage(&key, {1, 1, 0}, 1, 1, 5000, 2), o);
  EXPECT_EQ(r.outcome, FlashOutcome::kDryRun);
  EXPECT_EQ(r.device.functional.transfer_size, 1024);
  EXPECT_EQ(agent->dfu().state(), kAppIdle);
  EXPECT_EQ(link->resets, 0);
}

TEST(UsbDeviceId, Parses) {
  UsbDeviceId id;
  ASSERT_TRUE(UsbDeviceId::Parse("1209:0010", &id));
  EXPECT_EQ(id.vendor_id, 0x1209);
  EXPECT_EQ(id.product_id, 0x0010);
  EXPECT_TRUE(id.serial.empty());
  ASSERT_TRUE(UsbDeviceId::Parse("1209:10:ABC1", &id));
  EXPECT_EQ(id.serial, "ABC1");
  EXPECT_FALSE(UsbDeviceId::Parse("1209", &id));
  EXPECT_FALSE(UsbDeviceId::Parse("1209:0010:", &id));
  EXPECT_FALSE(UsbDeviceId::Parse("12345:1", &id));
}

}  // namespace
}  // namespace d3d::flash
