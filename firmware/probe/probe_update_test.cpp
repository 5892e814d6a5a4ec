// The update agent hosted in the probe process (ProbeUpdateService), end to end in one process:
// the sim backend streaming over DDS, the host's DFU layer flashing over the sim link, and the
// host receiver reading ProbeInfo. Issue 8: "flash v1.1 over v1.0 on a simulated probe → it boots
// v1.1, confirms, reports it over DDS ProbeInfo"; refusal while streaming; no streaming in DFU
// mode.
#include "firmware/probe/probe_update.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <thread>

#include "firmware/update/test_images.h"
#include "host/flash/dfu_host.h"
#include "host/flash/sim_transport.h"
#include "host/receiver/receiver.h"

namespace d3d {
namespace {

namespace fs = std::filesystem;

class ProbeUpdateTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("d3d_probe_update_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    ASSERT_TRUE(fw::SavePublicKey((dir_ / "signing.pub").string(), key_.pk).ok());
    const std::vector<uint8_t> v10 = fw::testing::MakeImage(&key_, {1, 0, 0}, 1, 1, 30000, 1);
    std::ofstream((dir_ / "v1.0.img").string(), std::ios::binary)
        .write(reinterpret_cast<const char*>(v10.data()), static_cast<std::streamsize>(v10.size()));
  }
  void TearDown() override {
    service_.reset();
    if (app_) {
      app_->RequestStop();
      if (run_.joinable()) run_.join();
    }
    app_.reset();
    if (!HasFailure()) fs::remove_all(dir_);
  }

  // A probe on DDS domain `domain` (idle or streaming) hosting the update agent.
  void StartProbe(int domain, bool streaming) {
    ASSERT_TRUE(pp_.Create({domain, proto::SelectCycloneConfig(nullptr, 0, 0, nullptr)}).ok());
    ASSERT_TRUE(rx_.Start(&pp_).ok());
    CaptureBackendRegistry reg;
    RegisterBuiltinCaptureBackends(&reg);
    CaptureOptions co;
    co.sim_cycle = 1;
    co.seed = 3;
    std::unique_ptr<CaptureBackend> backend;
    ASSERT_TRUE(reg.CreateAndOpen("sim", co, &backend).ok());
    ProbeAppOptions ao;
    ao.start_streaming = streaming;
    ao.firmware_version = "0.0.0-unknown";
    app_ = std::make_unique<ProbeApp>(ao, std::move(backend),
                                      std::make_unique<LoggingProjectorDriver>(nullptr), &pp_);
    ASSERT_TRUE(app_->Start().ok());
    run_ = std::thread([this] { EXPECT_TRUE(app_->Run().ok()); });
    ProbeUpdateOptions uo;
    uo.setup.flash_dir = (dir_ / "flash").string();
    uo.setup.pubkey_path = (dir_ / "signing.pub").string();
    uo.setup.provision_path = (dir_ / "v1.0.img").string();
    uo.setup.erase_bytes = 4096;
    uo.agent.slots.hw_id = 1;
    uo.agent.slots.slot_bytes = 1 << 20;
    uo.socket_path = (dir_ / "probe.sock").string();
    service_ = std::make_unique<ProbeUpdateService>(app_.get(), uo);
    const Status s = service_->Start();
    ASSERT_TRUE(s.ok()) << s.ToString();
  }

  // The firmware version of the newest ProbeInfo the host received (waits up to 5 s for `want`).
  std::string InfoVersion(const std::string& want) {
    std::string got;
    for (int i = 0; i < 100; ++i) {
      proto::InfoMsg info;
      if (rx_.LatestInfo(&info, nullptr)) got = info.firmware_version;
      if (got == want) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    return got;
  }

  flash::FlashReport Flash(std::span<const uint8_t> image) {
    std::unique_ptr<flash::SimTransport> t;
    const Status s = flash::SimTransport::Open((dir_ / "probe.sock").string(), 2000, &t);
    EXPECT_TRUE(s.ok()) << s.ToString();
    if (!s.ok()) return {};
    flash::FlashOptions o;
    o.reconnect_timeout_ms = 3000;
    return flash::FlashImage(t.get(), image, o);
  }

  fw::testing::TestKey key_ = fw::testing::MakeTestKey(1);
  fs::path dir_;
  proto::DdsParticipant pp_;
  BurstReceiver rx_{ReceiverOptions{}};
  std::unique_ptr<ProbeApp> app_;
  std::thread run_;
  std::unique_ptr<ProbeUpdateService> service_;
};

TEST_F(ProbeUpdateTest, FlashesANewVersionAndReportsItInProbeInfo) {
  StartProbe(81, /*streaming=*/false);
  EXPECT_NE(service_->boot_log().find("1.0.0"), std::string::npos) << service_->boot_log();
  EXPECT_EQ(InfoVersion("1.0.0"), "1.0.0")
      << "the provisioned factory image, read from the flash at power-on";
  const std::vector<uint8_t> v11 = fw::testing::MakeImage(&key_, {1, 1, 0}, 2, 1, 35000, 2);
  const flash::FlashReport r = Flash(v11);
  EXPECT_EQ(r.outcome, flash::FlashOutcome::kUpdated) << r.reason;
  EXPECT_EQ(r.after.VersionString(), "1.1.0");
  EXPECT_EQ(r.after.boot_state, dfu::BootState::kConfirmed);
  EXPECT_EQ(InfoVersion("1.1.0"), "1.1.0")
      << "ProbeInfo republished after the confirmed trial boot";
  EXPECT_TRUE(app_->SetStreaming(true).ok()) << "streaming allowed again after the DFU session";
}

TEST_F(ProbeUpdateTest, RefusesWhileStreamingAndStreamingGoesOn) {
  StartProbe(82, /*streaming=*/true);
  const std::vector<uint8_t> v11 = fw::testing::MakeImage(&key_, {1, 1, 0}, 2, 1, 35000, 2);
  const flash::FlashReport r = Flash(v11);
  EXPECT_EQ(r.outcome, flash::FlashOutcome::kRefused);
  EXPECT_EQ(r.reason.rfind("streaming:", 0), 0u) << r.reason;
  EXPECT_TRUE(app_->state().IsStreaming());
  const uint64_t before = app_->counters().bursts_published.load();
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  EXPECT_GT(app_->counters().bursts_published.load(), before)
      << "the probe keeps streaming after refusing";
  // Stopped by the host, a tampered image is refused and the probe streams again on 1.0.0.
  ASSERT_TRUE(app_->SetStreaming(false).ok());
  std::vector<uint8_t> tampered = v11;
  tampered[tampered.size() / 2] ^= 0x10;
  const flash::FlashReport t = Flash(tampered);
  EXPECT_EQ(t.outcome, flash::FlashOutcome::kRefused) << t.reason;
  EXPECT_EQ(t.after.VersionString(), "1.0.0");
  EXPECT_TRUE(app_->SetStreaming(true).ok());
  EXPECT_EQ(InfoVersion("1.0.0"), "1.0.0");
}

TEST_F(ProbeUpdateTest, NoStreamingInDfuMode) {
  StartProbe(83, /*streaming=*/false);
  std::unique_ptr<flash::SimTransport> t;
  ASSERT_TRUE(flash::SimTransport::Open((dir_ / "probe.sock").string(), 2000, &t).ok());
  flash::DfuHost host(t.get());
  flash::DfuDeviceInfo d;
  ASSERT_TRUE(host.ReadDescriptors(&d).ok());
  ASSERT_TRUE(host.Detach(1000).ok());
  ASSERT_TRUE(t->BusReset().ok());
  ASSERT_TRUE(t->Reopen(3000).ok());
  ASSERT_TRUE(host.ReadDescriptors(&d).ok());  // answered after the reset: the probe is in DFU mode
  ASSERT_TRUE(d.dfu_mode);
  const Status refused = app_->SetStreaming(true);
  EXPECT_EQ(refused.code(), StatusCode::kUnavailable);
  EXPECT_NE(refused.message().find("firmware update in progress"), std::string::npos)
      << refused.ToString();
  // Leaving DFU mode (a reset without an image) reboots into 1.0.0; streaming is allowed again.
  ASSERT_TRUE(t->BusReset().ok());
  for (int i = 0; i < 100 && !app_->SetStreaming(true).ok(); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_TRUE(app_->state().IsStreaming());
}

}  // namespace
}  // namespace d3d
