// The scan options every scanning tool takes (d3d-scan, live or replaying a recording, and the
// offline d3d-fuse), declared once: names, help, ranges and defaults, bound to the ScanOptions
// fields they set. A tool declares them on its OptionRegistry next to its own options, parses, and
// applies them with ApplyScanFlags, so both tools run the same profile from the same flags.
#pragma once

#include <string>

#include "common/core/status.h"
#include "common/options/option_registry.h"
#include "pipeline/chain/scan_chain.h"

namespace d3d {

// What the flags set that is not a ScanOptions field as it stands (ApplyScanFlags turns it into
// ScanOptions). The other flags write the ScanOptions fields directly.
struct ScanFlags {
  std::string profile = "live";      // live: LiveScanProfile (d3d-scan's); full: every ICP sample,
                                     // keyframe features and edges as they come
  int bin = 2;                       // camera pixels averaged over bin × bin (ScanOptionsForBin)
  std::string association = "grid";  // the tracker's ICP data association (ParseAssociation)
  double max_rmse_um = 0;            // the tracker's ICP residual gate (µm); the declared
                                     // options' value when declared
  bool refuse = true;                // fuse the kept views again at the pose graph's poses
  double live_voxel_mm = LiveVolumeOptions{}.voxel_mm;  // the live volume's voxel (0: the scan's)
};

// Declares the scan options on `registry`, bound to `flags` and to the fields of `*options`, whose
// values (and flags'.) are the defaults shown. Both must outlive the registry's Parse.
void DeclareScanFlags(OptionRegistry* registry, ScanFlags* flags, ScanOptions* options);

// `*options` as parsed, with what the flags select applied in this order: the profile, the
// tracker's step for views `step` bursts apart (TrackerOptionsForStep), the association, the
// residual gate, refusion (refuse_min_correction_mm 0.01 or -1), then the binning
// (ScanOptionsForBin); then ScanOptions::Check. InvalidArgument names the flag of a bad value.
[[nodiscard]] Status ApplyScanFlags(const ScanFlags& flags, double step, ScanOptions* options);

}  // namespace d3d
