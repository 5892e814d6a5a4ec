#include "host/app/reconstruct_stage.h"

namespace d3d {

ReconstructStage::ReconstructStage(const ProbeCalibration& probe_calibration,
                                   const ReconstructOptions& options, int bin, bool keep_views)
    : recon_(probe_calibration, options, bin), keep_views_(keep_views) {}

bool ReconstructStage::Run(ScanItem& item) {
  if (item.control) return true;
  item.recon_ok = recon_.Reconstruct(item.burst.frames, &item.view).ok();
  if (!item.recon_ok) {
    failed_.fetch_add(1, std::memory_order_relaxed);
    return false;
  }
  ms_recon_ += item.view.ms_total;
  if (keep_views_) {
    // Copied here, packed by the fuse stage: copyTo into a buffer of the same size and type reuses
    // it, so the item pool allocates nothing after warm-up.
    const std::vector<cv::Mat>& used = recon_.frames_used();
    item.kept_frames.resize(used.size());
    for (size_t i = 0; i < used.size(); ++i) used[i].copyTo(item.kept_frames[i]);
  }
  return true;
}

void ReconstructStage::WarmUp(ScanItem& item) {
  for (cv::Mat& f : item.burst.frames) f.setTo(0);
  (void)recon_.Reconstruct(item.burst.frames,
                           &item.view);  // dark burst: no points, every map allocated
}

}  // namespace d3d
