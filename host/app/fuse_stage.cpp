#include "host/app/fuse_stage.h"

#include <chrono>
#include <filesystem>

#include "common/mesh/mesh_io.h"

namespace d3d {

FuseStage::FuseStage(const ProbeCalibration& view_calibration, const FuseStageOptions& options,
                     const UndoLog* undo)
    : calibration_(view_calibration), o_(options), undo_(undo) {
  fuser_ = MakeFuser();
  if (o_.keep_views && !o_.views_spill_dir.empty()) {
    if (const Status s = archive_.SpillTo(o_.views_spill_dir); !s.ok()) spill_error_ = s.ToString();
  }
}

std::unique_ptr<ScanFuser> FuseStage::MakeFuser() const {
  return std::make_unique<ScanFuser>(calibration_.camera, o_.live_tsdf, o_.free_space);
}

bool FuseStage::Run(ScanItem& item) {
  std::lock_guard<std::mutex> lock(model_mu_);
  if (item.epoch != epoch_) {
    fuser_ = MakeFuser();
    archive_.Clear();
    fused_views_.clear();
    volume_has_undone_ = false;
    epoch_ = item.epoch;
  }
  if (item.undo_gen > undo_gen_) {
    // The undone views' frames go; the volume keeps them until it is fused again (Save, Finish).
    const int64_t cut = undo_->Cut(undo_gen_, item.undo_gen);
    while (!fused_views_.empty() && fused_views_.back().view_index >= cut) {
      (void)archive_.Remove(fused_views_.back().burst_seq);
      fused_views_.pop_back();
      volume_has_undone_ = true;
    }
    undo_gen_ = item.undo_gen;
  }
  if (item.undo_requests >
      undo_requests_) {  // those undos are applied up to here (Save waits for it)
    undo_requests_ = item.undo_requests;
    model_cv_.notify_all();
  }
  if (item.control) {
    control_done_.fetch_add(1);
    return true;
  }
  if (item.track.accepted) {
    // A view of a scan segment apart (not joined to the main model yet) is not fused live: it is
    // kept, and FinishScan fuses it once joined, or on its own.
    item.fused = item.track.in_main && fuser_->Fuse(item.view, item.track.world_from_cam).ok();
    if (item.fused) fused_.fetch_add(1, std::memory_order_relaxed);
    const bool keep = item.fused || !item.track.in_main;
    item.packed_ok = keep && o_.keep_views && packer_.Pack(item.kept_frames, &item.packed).ok();
    if (keep && item.packed_ok) {
      if (const Status s = archive_.Add(item.burst.burst_seq, item.packed);
          !s.ok() && spill_failures_++ == 0)
        spill_failure_ = s.ToString();
      if (item.fused)
        fused_views_.push_back({item.view_index, item.burst.burst_seq, item.track.world_from_cam});
    }
    if (item.fused && ++memory_views_ >= kScanMemoryEvery) {
      memory_views_ = 0;
      constexpr double kMiB = 1.0 / (1024.0 * 1024.0);
      mem_tsdf_mib_.store(static_cast<double>(fuser_->volume().MemoryBytes()) * kMiB,
                          std::memory_order_relaxed);
      mem_views_kept_mib_.store(static_cast<double>(archive_.memory_bytes()) * kMiB,
                                std::memory_order_relaxed);
    }
  }
  return true;
}

Status FuseStage::Save(uint64_t requested, const std::string& dir) {
  // Undos asked for before this save: the request travels down the graph, and a save right after
  // 'u' came before this stage had taken the undone views out and saved them. Every item carries
  // the request count; once one reaches this stage, the register stage has applied those undos
  // and this stage has cut their views.
  TriangleMesh mesh;
  {
    std::unique_lock<std::mutex> lock(model_mu_);
    if (!model_cv_.wait_for(lock, std::chrono::seconds(10),
                            [&] { return undo_requests_ >= requested; }))
      return Unavailable("save: the last undo has not reached the model yet (graph stalled?)");
    if (volume_has_undone_) {
      // The kept views again, at their tracked poses, into a volume that then replaces the live
      // one.
      const ScanViewProvider again = KeptViewProvider(archive_, calibration_, o_.recon);
      ScanFuser rebuilt(calibration_.camera, o_.live_tsdf, o_.free_space);
      ReconstructedView view;
      for (const FusedView& v : fused_views_) {
        ScanViewRecord record;
        record.burst_seq = v.burst_seq;
        D3D_RETURN_IF_ERROR(again(v.view_index, record, &view));
        D3D_RETURN_IF_ERROR(rebuilt.Fuse(view, v.world_from_cam));
      }
      fuser_->AdoptVolume(std::move(rebuilt));
      volume_has_undone_ = false;
    }
    mesh = fuser_->volume().ExtractMesh();
  }
  if (mesh.faces.empty())
    return Status(StatusCode::kInternal, "the model is empty: nothing to save");
  mesh.ComputeVertexNormals();
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  D3D_RETURN_IF_ERROR(SavePlyBinary((std::filesystem::path(dir) / "scan.ply").string(), mesh));
  return SaveStlBinary((std::filesystem::path(dir) / "scan.stl").string(), mesh);
}

Status FuseStage::Finish(const ScanOptions& scan, ScanTimes times, ScanRegistrar* registrar,
                         const ScanViewProvider& provider, const ScanTruth& truth,
                         ScanResult* out) {
  times.ms_fuse = fuser_->ms_fuse();
  // Without a provider, the kept views: their frames again through a reconstructor of the binned
  // calibration (the frames are binned already), so each view comes back as it was fused.
  ScanViewProvider kept;
  if (!provider && o_.keep_views && (archive_.size() > 0 || registrar->views_undone() > 0))
    kept = KeptViewProvider(archive_, calibration_, scan.recon);
  // A refusion replaces the fuser's volume: Save (saver thread) waits meanwhile.
  std::lock_guard<std::mutex> lock(model_mu_);
  return FinishScan(scan, times, registrar, fuser_.get(), provider ? provider : kept, truth, out);
}

void FuseStage::Report(nlohmann::json* host) const {
  nlohmann::json& h = *host;
  h["views_kept"] = archive_.size();
  h["views_kept_mib"] = static_cast<double>(archive_.bytes()) / (1024.0 * 1024.0);
  h["views_kept_memory_mib"] = static_cast<double>(archive_.memory_bytes()) / (1024.0 * 1024.0);
  h["views_spilled"] = archive_.spilling();
  if (!spill_error_.empty()) h["views_spill_error"] = spill_error_;
  h["views_spill_failures"] = spill_failures_;
  if (spill_failures_ > 0) h["views_spill_failure"] = spill_failure_;
}

void FuseStage::Memory(ScanMemory* m) const {
  m->tsdf_mib = mem_tsdf_mib_.load(std::memory_order_relaxed);
  m->views_kept_memory_mib = mem_views_kept_mib_.load(std::memory_order_relaxed);
}

}  // namespace d3d
