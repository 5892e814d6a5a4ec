// Bridging a gap the live policy left: when the tracker refuses a view that came several bursts
// after the last one it placed, the register stage places a burst from between them first (one the
// live graph had dropped), then tries the refused view again.
//
// Why: a host without CPU headroom keeps 1 burst in 3 to 6. Where the hand turns fast (32°/s on
// the full-arch path's bursts 204–222, docs/decisions/0014) a view 8 bursts after the last placed
// one overlaps the model by a tenth and is lost, while one 4–6 bursts after it still tracks. The
// bursts in between reached the host and were dropped only because a newer one had come; with
// one of them placed first, the refused view is 2–4 bursts from the model again. The cost (a
// reconstruction and a registration, ~50 ms of CPU per attempt) is paid only when a view fails,
// not per view.
//
// BurstRing: the last `capacity` bursts ingested, any burst of the scan whether the graph kept or
// dropped it, binned as the reconstruction bins them (BinFrame): a bridge looks back over the
// pipeline's latency as well as the gap, up to ~3 s at one slow core, and at bin 2 a burst is
// 0.3 MB (640 × 480). GapBridge: picks, rebuilds (at bin 1 on the binned calibration: the same
// view as the reconstruct stage's, as the view archive does) and registers the bridging bursts.
//
// Threads: BurstRing::Put on the ingest thread, Take on the register thread, under one mutex (the
// binning of one burst, ~0.5 ms at 640 × 480). GapBridge belongs to the register thread (its
// reconstructor and view buffer are its own).
#pragma once

#include <cstdint>
#include <mutex>
#include <vector>

#include "host/app/burst_source.h"
#include "pipeline/chain/scan_chain.h"

namespace d3d {

class BurstRing {
 public:
  // capacity ≥ 1 bursts of `frames` frames of width × height CV_8U (the probe's), kept binned by
  // `bin` (allocated now). Throws std::invalid_argument for a capacity, size, frame count or bin
  // < 1, or a size not divisible by bin.
  BurstRing(size_t capacity, int width, int height, int frames = 4, int bin = 1);
  // Ingest thread: keeps `b` binned, replacing the oldest when full (nothing for a burst that
  // cannot be binned: the reconstruct stage refuses it too).
  void Put(const IngestedBurst& b);
  int bin() const { return bin_; }
  // Register thread: copies into *out (binned) the kept burst whose capture time lies strictly
  // between after_ns and before_ns and is nearest to `target_ns` (ties: the later one), skipping
  // those in `exclude` (burst_seq). False when there is none.
  bool TakeNearest(int64_t after_ns, int64_t before_ns, int64_t target_ns,
                   const std::vector<uint64_t>& exclude, IngestedBurst* out) const;
  size_t size() const;

 private:
  int bin_;
  mutable std::mutex mu_;
  std::vector<IngestedBurst> slots_;
  size_t next_ = 0, size_ = 0;
};

struct GapBridgeOptions {
  int ring_bursts =
      96;  // bursts kept for bridging (3.2 s at 30 Hz; 29 MB at 640 × 480, bin 2); 0 = off
  int max_attempts = 2;  // bridging bursts registered per refused view (a fit tried)
  int max_bursts = 4;    // ... and reconstructed (one with too few points costs only that)
  // Bridged only when the refused view came at least this long after the last placed one (ns):
  // with the probe's 33 ms period, 2 bursts apart has one burst between them.
  int64_t min_gap_ns = 60'000'000;
  void Check() const;  // throws std::invalid_argument
};

// Whether a view refused in `state_before` (the tracker's state before it), captured at
// view_capture_ns, the last placed view at last_placed_ns, is one to bridge: bridging is on, the
// track was held until it, it had points, and the gap is at least min_gap_ns.
bool BridgeApplies(const GapBridgeOptions& options, TrackingState state_before,
                   const TrackResult& refused, int64_t view_capture_ns, int64_t last_placed_ns);

class GapBridge {
 public:
  struct Stats {
    uint64_t views = 0;     // refused views a bridge was tried for
    uint64_t attempts = 0;  // bridging bursts reconstructed
    uint64_t placed = 0;    // ... of them placed by the tracker
  };
  // `ring` is borrowed (outlives this). view_calibration: the views' (the probe's binned by the
  // ring's bin); recon: the reconstruct stage's options.
  GapBridge(const GapBridgeOptions& options, const BurstRing* ring,
            const ProbeCalibration& view_calibration, const ReconstructOptions& recon);
  // BridgeApplies with this bridge's options.
  bool Applies(TrackingState state_before, const TrackResult& refused, int64_t view_capture_ns,
               int64_t last_placed_ns) const {
    return BridgeApplies(o_, state_before, refused, view_capture_ns, last_placed_ns);
  }
  // Registers bridging bursts with `registrar` (each a view of its own: it is not fused nor kept,
  // and the scan's report counts it as registered) until one is placed or max_attempts fits or
  // max_bursts reconstructions are spent. The first is the kept burst nearest the middle of the
  // gap; after one with too few points, its later neighbour; after one refused otherwise, the one
  // nearest a third of the gap (closer to the model). A burst the registrar has had since its last
  // placed view (the refused view included) is never taken: its fate is known. Returns whether one
  // was placed, and its capture time in *placed_ns.
  bool Bridge(ScanRegistrar* registrar, int64_t last_placed_ns, int64_t view_capture_ns,
              int64_t* placed_ns);
  // Warms the reconstructor and view buffer up (one blank burst), so that the first bridge does not
  // allocate its maps.
  void WarmUp();
  const Stats& stats() const { return stats_; }

 private:
  GapBridgeOptions o_;
  const BurstRing* ring_;
  ScanReconstructor recon_;
  IngestedBurst burst_;
  ReconstructedView view_;
  std::vector<uint64_t>
      skip_;  // bursts not to take: registered since the last placed view, or tried
  Stats stats_;
};

}  // namespace d3d
