// Firmware update end to end, with separate processes: d3d-update-agent is the simulated probe
// (file-backed flash, killed and restarted to cut its power), d3d-flash / the host DFU layer talk
// to it over the sim link, d3d-fwpack makes and checks the images.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <thread>

#include "firmware/update/agent_process.h"
#include "firmware/update/image_format.h"
#include "firmware/update/test_images.h"
#include "host/flash/dfu_host.h"
#include "host/flash/sim_transport.h"
#include "host/receiver/receiver.h"
#include "protocol/dds_setup.h"

namespace d3d {
namespace {

namespace fs = std::filesystem;
using flash::FlashOutcome;
using flash::FlashReport;
using fw::testing::MakeImage;
using fw::testing::MakeTestKey;

const std::string kBin = D3D_BIN_DIR;

struct RunResult {
  int exit_code = -1;
  std::string output;
};

RunResult RunCmd(const std::string& cmd) {
  RunResult r;
  FILE* p = ::popen((cmd + " 2>&1").c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = std::fread(buf, 1, sizeof(buf), p)) > 0) r.output.append(buf, n);
  const int status = ::pclose(p);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

void WriteFile(const fs::path& p, std::span<const uint8_t> d) {
  std::ofstream f(p, std::ios::binary);
  f.write(reinterpret_cast<const char*>(d.data()), static_cast<std::streamsize>(d.size()));
}

class FirmwareUpdateTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir = fs::temp_directory_path() /
          ("d3d_fwtest_" + std::to_string(::getpid()) + "_" +
           ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir);
    fs::create_directories(dir);
    ASSERT_TRUE(fw::SavePublicKey((dir / "signing.pub").string(), key.pk).ok());
    ASSERT_TRUE(fw::SaveSecretKey((dir / "signing.key").string(), key.sk).ok());
    v10 = MakeImage(&key, {1, 0, 0}, 1, 1, 40000, 1);
    v11 = MakeImage(&key, {1, 1, 0}, 1, 1, 45000, 2);
    WriteFile(dir / "v1.0.img", v10);
    WriteFile(dir / "v1.1.img", v11);
    sock = (dir / "probe.sock").string();
  }
  void TearDown() override {
    agent.Kill();
    if (!HasFailure()) fs::remove_all(dir);
  }
  // The simulated probe: 4 KiB erase blocks, 256 B pages, 1 MiB slots, 4 KiB DFU blocks.
  std::vector<std::string> AgentArgs(std::vector<std::string> extra = {}) {
    std::vector<std::string> a = {"--socket",       sock,
                                  "--flash",        (dir / "flash").string(),
                                  "--pubkey",       (dir / "signing.pub").string(),
                                  "--provision",    (dir / "v1.0.img").string(),
                                  "--erase-kib",    "4",
                                  "--slot-mib",     "1",
                                  "--sim-controls", "--quiet"};
    a.insert(a.end(), extra.begin(), extra.end());
    return a;
  }
  void StartAgent(std::vector<std::string> extra = {}) {
    const Status s = agent.Start(kBin + "/d3d-update-agent", AgentArgs(extra), sock,
                                 (dir / "agent.log").string());
    ASSERT_TRUE(s.ok()) << s.ToString();
  }
  FlashReport FlashOver(std::span<const uint8_t> image, flash::FlashOptions o = {}) {
    std::unique_ptr<flash::SimTransport> t;
    const Status s = flash::SimTransport::Open(sock, 2000, &t);
    EXPECT_TRUE(s.ok()) << s.ToString();
    if (!s.ok()) return {};
    o.reconnect_timeout_ms = 3000;
    return flash::FlashImage(t.get(), image, o);
  }
  dfu::FirmwareInfo Info() {
    std::unique_ptr<flash::SimTransport> t;
    dfu::FirmwareInfo f;
    if (!flash::SimTransport::Open(sock, 2000, &t).ok()) return f;
    flash::DfuHost host(t.get());
    flash::DfuDeviceInfo d;
    EXPECT_TRUE(host.ReadDescriptors(&d).ok());
    EXPECT_TRUE(host.GetFirmwareInfo(&f).ok());
    return f;
  }
  bool StartStreaming() {
    std::unique_ptr<flash::SimTransport> t;
    if (!flash::SimTransport::Open(sock, 2000, &t).ok()) return false;
    flash::DfuHost host(t.get());
    flash::DfuDeviceInfo d;
    return host.ReadDescriptors(&d).ok() && host.SetSimStreaming(true).ok();
  }

  fw::testing::TestKey key = MakeTestKey(1);
  fs::path dir;
  std::string sock;
  std::vector<uint8_t> v10, v11;
  fw::AgentProcess agent;
};

TEST_F(FirmwareUpdateTest, HappyPathWithD3dFlashBootsAndConfirmsTheNewVersion) {
  StartAgent();
  const RunResult r = RunCmd(kBin + "/d3d-flash " + (dir / "v1.1.img").string() +
                             " --device sim:" + sock + " --no-progress");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("runs 1.0.0 (slot A, confirmed)"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("after 1.1.0 (slot B, confirmed)"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("result: UPDATED 1.0.0 -> 1.1.0"), std::string::npos) << r.output;
  // Still 1.1.0 after a power cycle of the probe.
  agent.Kill();
  StartAgent();
  const dfu::FirmwareInfo f = Info();
  EXPECT_EQ(f.VersionString(), "1.1.0");
  EXPECT_EQ(f.running_slot, 1);
  EXPECT_EQ(f.boot_state, dfu::BootState::kConfirmed);
}

// The agent hosted in the probe's acquisition process: d3d-flash over the sim link to d3d-probe,
// and the host sees the new version in DDS ProbeInfo.
TEST_F(FirmwareUpdateTest, D3dProbeHostsTheAgentAndReportsTheNewVersionOverDds) {
  constexpr int kDomain = 74;
  const Status started = agent.Start(kBin + "/d3d-probe",
                                     {"--sim",
                                      "typodont",
                                      "--sim-cycle",
                                      "1",
                                      "--idle",
                                      "--domain",
                                      std::to_string(kDomain),
                                      "--update-socket",
                                      sock,
                                      "--flash",
                                      (dir / "flash").string(),
                                      "--pubkey",
                                      (dir / "signing.pub").string(),
                                      "--provision",
                                      (dir / "v1.0.img").string(),
                                      "--hw",
                                      "1",
                                      "--slot-mib",
                                      "1",
                                      "--erase-kib",
                                      "4"},
                                     sock, (dir / "probe.log").string(), 60000);
  ASSERT_TRUE(started.ok()) << started.ToString();
  proto::DdsParticipant pp;
  ASSERT_TRUE(pp.Create({kDomain, proto::SelectCycloneConfig(nullptr, 0, 0, nullptr)}).ok());
  BurstReceiver rx(ReceiverOptions{});
  ASSERT_TRUE(rx.Start(&pp).ok());
  auto version = [&](const std::string& want) {
    std::string got;
    for (int i = 0; i < 200 && got != want; ++i) {
      proto::InfoMsg info;
      if (rx.LatestInfo(&info, nullptr)) got = info.firmware_version;
      if (got != want) std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    return got;
  };
  EXPECT_EQ(version("1.0.0"), "1.0.0");
  const RunResult r = RunCmd(kBin + "/d3d-flash " + (dir / "v1.1.img").string() +
                             " --device sim:" + sock + " --no-progress");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("result: UPDATED 1.0.0 -> 1.1.0"), std::string::npos) << r.output;
  EXPECT_EQ(version("1.1.0"), "1.1.0") << "ProbeInfo.firmware_version after the confirmed update";
  EXPECT_EQ(agent.Stop(), 0);
}

TEST_F(FirmwareUpdateTest, DryRunSendsNothing) {
  StartAgent();
  const RunResult r = RunCmd(kBin + "/d3d-flash " + (dir / "v1.1.img").string() +
                             " --device sim:" + sock + " --dry-run --no-progress");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("result: DRY RUN"), std::string::npos) << r.output;
  EXPECT_EQ(Info().VersionString(), "1.0.0");
}

struct Refusal {
  std::string name;
  std::vector<uint8_t> image;
  uint8_t dfu_status;
  std::string token;
};

// Every refusal of the issue: exact reason (the same d3d-fwpack --verify gives), the old version
// still running, and the probe can stream again.
TEST_F(FirmwareUpdateTest, RefusedImagesNameTheExactReasonAndTheOldVersionKeepsRunning) {
  const auto other = MakeTestKey(2);
  auto flip = [&](size_t byte, int bit) {
    auto img = v11;
    img[byte] ^= static_cast<uint8_t>(1 << bit);
    return img;
  };
  std::vector<Refusal> cases = {
      {"unsigned", MakeImage(nullptr, {1, 1, 0}, 1, 1, 45000, 2), dfu::kErrFile, "unsigned"},
      {"wrong key", MakeImage(&other, {1, 1, 0}, 1, 1, 45000, 2), dfu::kErrFile, "unknown-key"},
      {"flipped header bit (version)", flip(16, 0), dfu::kErrFile, "bad-signature"},
      {"flipped header bit (hash)", flip(50, 3), dfu::kErrVerify, "payload-hash"},
      {"flipped payload bit", flip(fw::kHeaderBytes + 20000, 5), dfu::kErrVerify, "payload-hash"},
      {"flipped signature bit", flip(v11.size() - 10, 7), dfu::kErrFile, "bad-signature"},
      {"truncated", std::vector<uint8_t>(v11.begin(), v11.end() - 1000), dfu::kErrNotDone,
       "truncated"},
      {"wrong hardware id", MakeImage(&key, {1, 1, 0}, 1, 2, 45000, 2), dfu::kErrTarget,
       "wrong-hardware"},
      {"downgrade (counter 0 < floor 1)", MakeImage(&key, {1, 2, 0}, 0, 1, 45000, 2), dfu::kErrFile,
       "downgrade"},
      {"oversize (2 MiB > 1 MiB slot)", MakeImage(&key, {1, 1, 0}, 1, 1, 2 << 20, 2),
       dfu::kErrAddress, "oversize"},
  };
  StartAgent();
  for (const Refusal& c : cases) {
    SCOPED_TRACE(c.name);
    const FlashReport r = FlashOver(c.image);
    EXPECT_EQ(r.outcome, FlashOutcome::kRefused)
        << flash::FlashOutcomeName(r.outcome) << " " << r.reason;
    EXPECT_EQ(r.dfu_status, c.dfu_status) << dfu::StatusName(r.dfu_status) << " " << r.reason;
    EXPECT_EQ(r.reason.rfind(c.token + ":", 0), 0u) << r.reason;
    // The probe's reason is the one d3d-fwpack --verify gives for the same bytes.
    fw::ImagePolicy policy;
    policy.check_hw_id = true;
    policy.hw_id = 1;
    policy.min_security_counter = 1;
    policy.max_image_bytes = 1 << 20;
    const fw::Verdict v = fw::VerifyImageBytes(c.image, key.pk, policy);
    EXPECT_EQ(std::string(fw::RejectToken(v.reason)), c.token) << v.message;
    ASSERT_TRUE(r.have_after);
    EXPECT_EQ(r.after.VersionString(), "1.0.0");
    EXPECT_EQ(r.after.running_slot, 0);
    EXPECT_EQ(r.after.boot_state, dfu::BootState::kConfirmed);
    EXPECT_FALSE(r.after.dfu_mode);
  }
  // After all that the probe streams on its active slot and still takes a good image.
  EXPECT_TRUE(StartStreaming());
  EXPECT_TRUE(Info().streaming);
}

TEST_F(FirmwareUpdateTest, ImageSentWhileStreamingIsRefusedAndStreamingGoesOn) {
  StartAgent({"--streaming"});
  const RunResult r = RunCmd(kBin + "/d3d-flash " + (dir / "v1.1.img").string() +
                             " --device sim:" + sock + " --no-progress");
  EXPECT_EQ(r.exit_code, 3) << r.output;
  EXPECT_NE(r.output.find("REFUSED by the probe (errVENDOR): streaming:"), std::string::npos)
      << r.output;
  const dfu::FirmwareInfo f = Info();
  EXPECT_TRUE(f.streaming);
  EXPECT_EQ(f.VersionString(), "1.0.0");
  EXPECT_FALSE(f.dfu_mode);
}

TEST_F(FirmwareUpdateTest, D3dFlashReportsARefusalWithExitCode3) {
  StartAgent();
  WriteFile(dir / "wrong_hw.img", MakeImage(&key, {1, 1, 0}, 1, 9, 45000, 2));
  const RunResult r = RunCmd(kBin + "/d3d-flash " + (dir / "wrong_hw.img").string() +
                             " --device sim:" + sock + " --no-progress");
  EXPECT_EQ(r.exit_code, 3) << r.output;
  EXPECT_NE(r.output.find("REFUSED by the probe (errTARGET): wrong-hardware: image is for hardware "
                          "0x0009, this probe is 0x0001"),
            std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find("still runs 1.0.0 (slot A, confirmed)"), std::string::npos) << r.output;
}

// A firmware that fails its health check, and one that never answers it: both roll back.
TEST_F(FirmwareUpdateTest, NewVersionThatNeverConfirmsRollsBack) {
  for (const std::string flag : {"--unhealthy-version", "--silent-version"}) {
    SCOPED_TRACE(flag);
    fs::remove_all(dir / "flash");
    StartAgent({flag, "1.1.0"});
    const FlashReport r = FlashOver(v11);
    EXPECT_EQ(r.outcome, FlashOutcome::kRolledBack) << r.reason;
    EXPECT_EQ(r.after.VersionString(), "1.0.0");
    EXPECT_EQ(r.after.boot_state, dfu::BootState::kRolledBack);
    agent.Kill();
    StartAgent();  // a later power-on stays on 1.0.0, and a good image still goes in
    EXPECT_EQ(Info().VersionString(), "1.0.0");
    const FlashReport again = FlashOver(v11);
    EXPECT_EQ(again.outcome, FlashOutcome::kUpdated) << again.reason;
    agent.Kill();
  }
}

// Cut the transfer after every block k (SIGKILL the probe), restart it: it boots a good signed
// version (the old one), and a full update afterwards succeeds.
TEST_F(FirmwareUpdateTest, PowerLossAfterEveryBlockAlwaysBootsAGoodVersion) {
  const int64_t blocks = static_cast<int64_t>((v11.size() + 4095) / 4096);
  for (int64_t k = 0; k <= blocks; ++k) {
    SCOPED_TRACE("cut after block " + std::to_string(k));
    fs::remove_all(dir / "flash");
    StartAgent();
    flash::FlashOptions o;
    o.stop_after_blocks = k;
    const FlashReport cut = FlashOver(v11, o);
    if (k < blocks) {
      EXPECT_EQ(cut.outcome, FlashOutcome::kLinkLost);
      EXPECT_EQ(cut.blocks, k);
    }
    agent.Kill();  // power loss
    StartAgent();
    const dfu::FirmwareInfo f = Info();
    const bool good = (f.VersionString() == "1.0.0" && f.running_slot == 0) ||
                      (f.VersionString() == "1.1.0" && f.running_slot == 1);
    EXPECT_TRUE(good) << f.VersionString();
    EXPECT_NE(f.boot_state, dfu::BootState::kUnknown);
    if (k < blocks) {
      EXPECT_EQ(f.VersionString(), "1.0.0");
    }
    const FlashReport again = FlashOver(v11);
    EXPECT_TRUE(again.outcome == FlashOutcome::kUpdated) << again.reason;
    agent.Kill();
  }
}

// Cut the power at every flash operation (erase / page program) the probe makes during a full
// update — download, manifestation (verification + boot-control write), trial boot, confirmation —
// with the agent exiting at the injected cut; restart: always a good signed version.
TEST_F(FirmwareUpdateTest, PowerLossAtEveryFlashOperationIncludingManifestation) {
  // Ops of a clean update, counted by giving an unreachable cut.
  int64_t k = 0;
  int manifest_cuts = 0, boot_cuts = 0, download_cuts = 0, completed = 0;
  for (;; ++k) {
    SCOPED_TRACE("power cut at flash operation " + std::to_string(k));
    fs::remove_all(dir / "flash");
    StartAgent({"--power-cut-after-ops", std::to_string(k)});
    const FlashReport r = FlashOver(v11);
    const int code = agent.WaitExit(3000);
    if (r.outcome == FlashOutcome::kUpdated) {
      ++completed;
      agent.Kill();
      break;  // k is past the last operation of the update
    }
    EXPECT_EQ(code, 86) << "agent did not die of the injected cut: "
                        << flash::FlashOutcomeName(r.outcome) << " " << r.reason;
    if (r.blocks < static_cast<int64_t>((v11.size() + 4095) / 4096)) {
      ++download_cuts;
    } else if (r.manifest_s == 0 && r.reboot_s == 0) {
      ++manifest_cuts;  // all blocks were in; the cut hit verification / marking the slot
    } else {
      ++boot_cuts;
    }
    agent.Kill();
    StartAgent();
    const dfu::FirmwareInfo f = Info();
    const bool good = (f.VersionString() == "1.0.0" && f.running_slot == 0) ||
                      (f.VersionString() == "1.1.0" && f.running_slot == 1);
    ASSERT_TRUE(good) << f.VersionString() << " slot " << int(f.running_slot);
    agent.Kill();
    ASSERT_LT(k, 2000) << "the update never completed";
  }
  EXPECT_GT(download_cuts, 0);
  EXPECT_GT(manifest_cuts, 0);
  EXPECT_GT(boot_cuts, 0);
  RecordProperty("cut_points", static_cast<int>(k));
  RecordProperty("manifestation_cuts", manifest_cuts);
  std::printf(
      "power-cut matrix: %lld cut points (download %d, manifestation %d, reboot/confirm %d), all "
      "booted a good version\n",
      static_cast<long long>(k), download_cuts, manifest_cuts, boot_cuts);
}

// dfu-util (Debian's), the reference DFU 1.1 client, flashes the simulated probe: its libusb calls
// are carried over the sim link by an LD_PRELOAD stand-in (tests/dfu_util/libusb_sim_shim.cpp).
TEST_F(FirmwareUpdateTest, DfuUtilAsReferenceClient) {
  if (RunCmd("command -v dfu-util").exit_code != 0)
    GTEST_SKIP() << "dfu-util is not installed (tools/deps.txt lists it)";
  StartAgent();
  const std::string env = std::string("LD_PRELOAD=") + D3D_SIM_SHIM + " D3D_SIM_SOCKET=" + sock +
                          " timeout 60 dfu-util ";
  RunResult r = RunCmd(env + "-l");
  EXPECT_NE(r.output.find("Found Runtime: [1209:0010]"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("serial=\"SIM0001\""), std::string::npos) << r.output;
  r = RunCmd(env + "-d 1209:0010 -D " + (dir / "v1.1.img").string() + " -R -E 0");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("Device returned transfer size 4096"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("DFU state(7) = dfuMANIFEST, status(0)"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("DFU state(2) = dfuIDLE, status(0)"), std::string::npos) << r.output;
  dfu::FirmwareInfo f = Info();
  EXPECT_EQ(f.VersionString(), "1.1.0");
  EXPECT_EQ(f.boot_state, dfu::BootState::kConfirmed);
  EXPECT_FALSE(f.dfu_mode);
  // An image signed with another key: dfu-util shows the probe's errFILE, the probe keeps 1.1.0.
  const auto other = MakeTestKey(2);
  WriteFile(dir / "other.img", MakeImage(&other, {1, 2, 0}, 1, 1, 45000, 2));
  r = RunCmd(env + "-d 1209:0010 -D " + (dir / "other.img").string() + " -R -E 0");
  EXPECT_NE(r.output.find("DFU state(10) = dfuERROR, status(2)"), std::string::npos) << r.output;
  f = Info();
  EXPECT_EQ(f.VersionString(), "1.1.0");
  EXPECT_FALSE(f.dfu_mode);
}

TEST_F(FirmwareUpdateTest, FwpackKeygenPackVerify) {
  const std::string keys = (dir / "keys").string();
  RunResult r = RunCmd(kBin + "/d3d-fwpack --keygen --out " + keys);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(RunCmd(kBin + "/d3d-fwpack --keygen --out " + keys).exit_code,
            2);  // never overwrites a key
  WriteFile(dir / "payload.bin", fw::testing::MakePayload(10000, 3));
  r = RunCmd(kBin + "/d3d-fwpack --key " + keys +
             "/signing.key --version 2.3.4 --hw 0x0001 --counter 3 --in " +
             (dir / "payload.bin").string() + " --out " + (dir / "out.img").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = RunCmd(kBin + "/d3d-fwpack --verify --pubkey " + keys +
             "/signing.pub --hw 0x0001 --min-counter 3 " + (dir / "out.img").string());
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("version    2.3.4"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("verdict    OK"), std::string::npos) << r.output;
  struct Bad {
    std::string args, token;
  };
  for (const Bad& b : std::vector<Bad>{{"--hw 0x0002", "wrong-hardware"},
                                       {"--min-counter 4", "downgrade"},
                                       {"--max-size 5000", "oversize"}}) {
    r = RunCmd(kBin + "/d3d-fwpack --verify --pubkey " + keys + "/signing.pub " + b.args + " " +
               (dir / "out.img").string());
    EXPECT_EQ(r.exit_code, 1) << r.output;
    EXPECT_NE(r.output.find("verdict    REFUSED: " + b.token + ":"), std::string::npos) << r.output;
  }
  r = RunCmd(kBin + "/d3d-fwpack --verify --pubkey " + (dir / "signing.pub").string() + " " +
             (dir / "out.img").string());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("REFUSED: unknown-key:"), std::string::npos) << r.output;
  r = RunCmd(kBin + "/d3d-fwpack --unsigned --version 1.0.0 --hw 1 --in " +
             (dir / "payload.bin").string() + " --out " + (dir / "u.img").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = RunCmd(kBin + "/d3d-fwpack --verify --pubkey " + keys + "/signing.pub " +
             (dir / "u.img").string());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("REFUSED: unsigned:"), std::string::npos) << r.output;
}

TEST_F(FirmwareUpdateTest, UsbTransportSaysClearlyThatThereIsNoProbe) {
  RunResult r = RunCmd(kBin + "/d3d-flash --list");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("usb: "), std::string::npos) << r.output;
  r = RunCmd("timeout 10 " + kBin + "/d3d-flash " + (dir / "v1.1.img").string() +
             " --device usb:1209:0010 --no-progress");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_TRUE(r.output.find("no USB device usb:1209:0010 is attached") != std::string::npos ||
              r.output.find("libusb cannot be initialised") != std::string::npos)
      << r.output;
}

}  // namespace
}  // namespace d3d
