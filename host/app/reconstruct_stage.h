// The host graph's reconstruct stage (reconstruct thread): a burst into a view (ScanReconstructor:
// binning, phase, unwrapping, triangulation), and, when the views are kept, a copy of the frames
// it used for the fuse stage to pack.
// Threads: Run and WarmUp on the reconstruct thread (WarmUp at set-up, before the graph starts);
// failed() from any thread; ms_recon() after the graph has joined.
#pragma once

#include <atomic>
#include <cstdint>

#include "host/app/scan_item.h"
#include "pipeline/chain/scan_chain.h"

namespace d3d {

class ReconstructStage {
 public:
  // `probe_calibration`: the probe's (unbinned); views come out binned by `bin`.
  ReconstructStage(const ProbeCalibration& probe_calibration, const ReconstructOptions& options,
                   int bin, bool keep_views);

  bool Run(ScanItem& item);
  // One reconstruction of a dark burst into `item`: its maps are allocated and paged in now
  // rather than by its first burst (no points come out).
  void WarmUp(ScanItem& item);

  uint64_t failed() const { return failed_.load(); }
  double ms_recon() const { return ms_recon_; }  // the views' reconstruction time in all (ms)

 private:
  ScanReconstructor recon_;
  const bool keep_views_;
  double ms_recon_ = 0;
  std::atomic<uint64_t> failed_{0};
};

}  // namespace d3d
