// The host's scan graph with "undo last seconds" (ScanApp::RequestUndo), lossless: the undo goes
// through while no burst comes (paused, probe away), the preview loses the undone views' points,
// a save right after it gives the model of a scan that never had those views, and the scan then
// goes on over the model to a report that counts the undo and a model fused from the kept views.
#include "host/app/scan_app.h"

#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include "sim/session/sim_session.h"

namespace d3d {
namespace {

// Pre-rendered bursts of the virtual probe; stops (kNothing, as a probe that went away) before
// burst `hold_at` until Release().
class HeldSource final : public BurstSource {
 public:
  HeldSource(std::vector<Burst> bursts, std::vector<int64_t> seqs, size_t hold_at)
      : bursts_(std::move(bursts)), seqs_(std::move(seqs)), hold_at_(hold_at) {}
  Result Next(IngestedBurst* out) override {
    if (next_ == hold_at_ && !released_.load()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
      return Result::kNothing;
    }
    if (next_ >= bursts_.size()) return Result::kEnd;
    const Burst& b = bursts_[next_];
    out->frames.resize(b.frames.size());
    for (size_t k = 0; k < b.frames.size(); ++k) b.frames[k].image.copyTo(out->frames[k]);
    out->burst_seq = static_cast<uint64_t>(seqs_[next_]);
    out->capture_ns = b.reference_ns;
    out->receive_ns = 0;
    ++next_;
    received_.fetch_add(1);
    return Result::kBurst;
  }
  void Release() { released_.store(true); }

 private:
  std::vector<Burst> bursts_;
  std::vector<int64_t> seqs_;
  size_t hold_at_;
  size_t next_ = 0;
  std::atomic<bool> released_{false};
};

std::string ReadAll(const std::filesystem::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

ScanAppOptions Options() {
  ScanAppOptions o;
  o.scan.tracker = TrackerOptionsForStep(o.scan.tracker, 2);
  // Model anchoring off: a save after an undo fuses the kept views again without it (the register
  // thread owns the model it anchors against), so only then is it the very model of a scan that
  // never had the undone views.
  o.scan.anchor.enabled = false;
  o.scan = ScanOptionsForBin(o.scan, 2);
  o.undo_seconds = 0.15;  // 3 views 66.7 ms apart
  o.undo_max_views = 30;
  return o;
}

// Waits (up to 120 s) until `done` holds.
template <typename F>
bool WaitFor(F done) {
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(120);
  while (!done()) {
    if (std::chrono::steady_clock::now() > until) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return true;
}

// The coarse live volume (kept views, live.voxel_mm > 0) takes the live strides; when it is the
// result (no kept views) or at the scan's voxel it is fused as the scan's volume.
TEST(ScanAppOptions, OnlyTheCoarseLiveVolumeTakesTheLiveStrides) {
  ScanAppOptions o;
  o.keep_views = true;
  o.live.voxel_mm = 0.1;
  o.live.occlusion_stride = 5;
  o.live.pixel_stride = 3;
  const TsdfOptions live = o.LiveTsdf();
  EXPECT_DOUBLE_EQ(live.voxel_mm, 0.1);
  EXPECT_EQ(live.occlusion_stride, 5);
  EXPECT_EQ(live.pixel_stride, 3);
  EXPECT_EQ(live.occlusion_margin_mm, o.scan.tsdf.occlusion_margin_mm);
  // Its band is at least 2 of its voxels: the scan's 0.2 mm at 0.1 mm voxels, 0.4 mm at 0.2 mm.
  EXPECT_DOUBLE_EQ(live.truncation_mm, o.scan.tsdf.truncation_mm);
  ScanAppOptions coarse = o;
  coarse.live.voxel_mm = 0.2;
  EXPECT_DOUBLE_EQ(coarse.LiveTsdf().truncation_mm, 0.4);
  EXPECT_NO_THROW(coarse.Check());
  for (const bool keep : {false, true}) {
    ScanAppOptions result = o;
    result.keep_views = keep;
    result.live.voxel_mm = keep ? 0.0 : 0.1;
    const TsdfOptions t = result.LiveTsdf();
    EXPECT_DOUBLE_EQ(t.voxel_mm, o.scan.tsdf.voxel_mm);
    EXPECT_EQ(t.occlusion_stride, o.scan.tsdf.occlusion_stride);
    EXPECT_EQ(t.pixel_stride, o.scan.tsdf.pixel_stride);
  }
  ScanAppOptions bad = o;
  bad.live.occlusion_stride = 0;
  EXPECT_THROW(bad.Check(), std::invalid_argument);
  bad = o;
  bad.live.pixel_stride = 0;
  EXPECT_THROW(bad.Check(), std::invalid_argument);
}

TEST(ScanAppUndo, UndoneViewsLeaveThePreviewTheSavedModelAndTheReport) {
  SimSessionOptions so;
  so.model = "typodont";
  so.trajectory = "quadrant";
  so.seed = 3;
  std::unique_ptr<SimSession> session;
  ASSERT_TRUE(SimSession::Create(so, &session).ok());
  // Bursts 30, 32, …, 52 (12 views), then the probe back over the model: 41, 43, …, 59.
  std::vector<int64_t> seqs;
  for (int64_t i = 30; i <= 52; i += 2) seqs.push_back(i);
  for (int64_t i = 41; i <= 59; i += 2) seqs.push_back(i);
  std::vector<Burst> bursts;
  for (const int64_t i : seqs) bursts.push_back(session->RenderBurst(i, false));
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / "d3d_scan_app_undo_test";
  std::filesystem::remove_all(dir);

  // The scan that never had views 9-11: its first 9 bursts only, saved.
  {
    HeldSource nine(std::vector<Burst>(bursts.begin(), bursts.begin() + 9), seqs, 9);
    ScanApp app(session->calibration(), Options(), &nine);
    app.Start();
    ASSERT_TRUE(WaitFor([&] {
      return app.CurrentStatus().bursts_fused + app.CurrentStatus().bursts_rejected >= 9;
    }));
    ASSERT_TRUE(app.SaveNow((dir / "nine").string()).ok());
    nine.Release();
    app.RequestStop();
    app.Join();
  }

  HeldSource source(bursts, seqs, 12);
  ScanApp app(session->calibration(), Options(), &source);
  ASSERT_TRUE(app.undo_available());
  app.Start();
  ASSERT_TRUE(WaitFor([&] { return app.CurrentStatus().bursts_processed >= 12; }));
  ASSERT_TRUE(WaitFor([&] {
    const PreviewSnapshot* s = app.LatestSnapshot();
    return s != nullptr && s->bursts_in_model == 12;
  })) << "all 12 views should be in the model";
  const size_t points_before = app.LatestSnapshot()->points.size();
  // Paused, and no burst coming: the undo still goes through. A save right after the key press
  // (before the request has travelled down the graph) already leaves the undone views out: the
  // same model as the scan that never had them (the kept views fused again).
  app.SetPaused(true);
  ASSERT_TRUE(app.RequestUndo());
  ASSERT_TRUE(app.SaveNow((dir / "undone").string()).ok());
  const std::string nine_ply = ReadAll(dir / "nine" / "scan.ply");
  ASSERT_FALSE(nine_ply.empty());
  EXPECT_TRUE(ReadAll(dir / "undone" / "scan.ply") == nine_ply)
      << "the save after the undo is not the model without the undone views";
  EXPECT_EQ(app.undos_done(), 1u);
  EXPECT_NE(app.LastUndoMessage().find("3 views"), std::string::npos) << app.LastUndoMessage();
  ASSERT_TRUE(WaitFor([&] {
    const PreviewSnapshot* s = app.LatestSnapshot();
    return s != nullptr && s->bursts_in_model == 9;
  })) << "the preview still shows the undone views";
  EXPECT_LT(app.LatestSnapshot()->points.size(), points_before);
  EXPECT_FALSE(app.LatestSnapshot()->have_pose);
  // The probe comes back over the model and the scan goes on.
  app.SetPaused(false);
  source.Release();
  app.Join();
  ScanResult result;
  ScanTruth truth;
  truth.reference = &session->scene();
  truth.true_pose = [&](const ScanViewRecord& v, Rigid3d* p) {
    *p = session->trajectory().WorldFromProbe(v.reference_ns);
    return true;
  };
  ASSERT_TRUE(app.Finish(truth, {}, &result).ok()) << result.report.dump();
  const nlohmann::json& j = result.report;
  EXPECT_EQ(j["bursts_processed"], 22);  // the undo's control item is not a burst
  EXPECT_EQ(j["bursts"], 22);
  EXPECT_EQ(j["undo_requests"], 1);
  EXPECT_EQ(j["undos_applied"], 1);
  EXPECT_EQ(j["views_undone"], 3);
  EXPECT_TRUE(j["fused_again_at_optimised_poses"].get<bool>());
  // The saves above wrote the coarse live volume; the final model is at the scan's voxel.
  EXPECT_DOUBLE_EQ(j["live_voxel_mm"].get<double>(), LiveVolumeOptions{}.voxel_mm);
  EXPECT_DOUBLE_EQ(j["voxel_mm"].get<double>(), ScanAppOptions{}.scan.tsdf.voxel_mm);
  EXPECT_EQ(j["views_kept"], result.poses.size());  // the undone views' frames were dropped
  EXPECT_GE(result.poses.size(), 17u) << j["events"].dump();
  EXPECT_LT(j["trueness_rms_um"].get<double>(), 20.0);
  // The memory figures the stages published (the register stage at its 15th view; the fuse stage
  // at its 15th fused view): the model at that time, with its undo journal, keyframes, live volume.
  const ScanMemory m = app.Memory();
  EXPECT_EQ(m.views % ScanApp::kMemoryEvery, 0u);
  EXPECT_GE(m.views, ScanApp::kMemoryEvery);
  EXPECT_GT(m.model_samples, 1000u);
  EXPECT_LE(m.model_samples, j["model_samples"].get<uint64_t>() * 2);
  EXPECT_GE(m.model_mib * 1024 * 1024,
            static_cast<double>(m.model_samples) * 28);  // two Vector3f and a weight each, at least
  EXPECT_GT(m.undo_journal_mib, 0.0);
  EXPECT_GE(m.keyframes, 1u);
  EXPECT_GT(m.keyframes_mib, 0.0);
  EXPECT_GT(m.tsdf_mib, 0.1);
  EXPECT_GT(m.views_kept_memory_mib, 0.0);  // the options keep the frames in memory
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace d3d
