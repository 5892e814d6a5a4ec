// d3d-fuse's offline scan: the chain of pipeline/chain over bursts rendered by the virtual probe or
// read from a d3d-sim folder, all on the calling thread (a prefetch thread loads the bursts ahead):
// burst → reconstruction → registration → fusion per burst, then the pose graph, the refusion, the
// mesh and the evaluation (FinishScan). Part of the d3d-fuse executable, not a library.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/core/status.h"
#include "pipeline/chain/scan_chain.h"
#include "pipeline/chain/scan_flags.h"
#include "pipeline/chain/view_archive.h"
#include "sim/session/sim_session.h"

namespace d3d {

// d3d-fuse's own options (the scan options are scan_flags.h's).
struct OfflineScanArgs {
  std::string sim_model;                 // --sim: 'typodont' or a mesh file (mm)
  std::string bursts_dir;                // --bursts: a d3d-sim output folder
  std::string trajectory = "full-arch";  // --sim: scan style, quadrant or a TUM file
  uint32_t seed = 1;                     // --sim: hand motion and sensor noise
  std::string out_dir;                   // outputs, and the spill file of the kept views
  int every = 1;                         // every N-th burst
  int64_t first = 0;                     // first burst index
  int64_t max_bursts = -1;               // bursts used at most (-1: all)
  bool no_eval = false;                  // no evaluation against the scene
  bool quiet = false;                    // no progress bar, no per-burst messages
  bool truth_poses = false;              // debug: every view fused at its true pose
  bool coverage_ceiling = false;         // --sim: report coverage_seen_pct
  std::string trace_path;                // debug: one line per burst
  std::string graph_path;                // debug: the pose graph
};

// Where the bursts come from, and which of them the scan uses.
struct OfflineSource {
  std::unique_ptr<SimSession> session;  // --sim; null for a bursts folder
  ProbeCalibration calibration;
  TriangleMesh scene;                   // the truth when known (empty otherwise)
  std::vector<std::string> burst_dirs;  // a bursts folder's bursts, sorted
  std::vector<int64_t> indices;  // the bursts used, in order (--first, --every, --max-bursts)

  // Opens --sim or --bursts (exactly one is set; checked by the caller).
  [[nodiscard]] static Status Open(const OfflineScanArgs& args, OfflineSource* out);
  // Burst `index`, rendered (with its truth maps when `with_truth`) or read.
  [[nodiscard]] Status Load(int64_t index, bool with_truth, Burst* out) const;
  // The true pose at the burst's reference time, when the source knows it (else the identity).
  Rigid3d TruePose(const Burst& burst) const;
};

// Runs the scan over `source`'s bursts with `options` (as ApplyScanFlags made them from `flags`),
// finishes it into *result with d3d-fuse's report fields, and writes the outputs into
// args.out_dir (WriteScanOutputs, and truth_poses.txt when the truth is known); --trace while it
// runs, --pose-graph at the end.
[[nodiscard]] Status RunOfflineScan(const OfflineScanArgs& args, const OfflineSource& source,
                                    const ScanFlags& flags, const ScanOptions& options,
                                    ScanResult* result);

}  // namespace d3d
