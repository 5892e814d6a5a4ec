// What travels through the host's stage graph (one ScanItem per burst, from a pool the graph owns)
// and what the stages publish of the memory they hold.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "host/app/burst_source.h"
#include "pipeline/chain/scan_chain.h"

namespace d3d {

struct ScanItem {
  uint64_t epoch = 0;
  bool control =
      false;  // an undo request without a burst (ingest writes; every stage lets it through)
  uint64_t undo_requests = 0;  // undo requests up to this item (ingest writes)
  uint64_t undo_gen = 0;       // undos the register stage had done by this item (register writes)
  int64_t view_index = -1;     // the registrar's index of this view (register writes)
  IngestedBurst burst;
  bool recon_ok = false;
  ReconstructedView view;
  TrackResult track;
  bool fused = false;
  // keep_views: the frames the reconstruction used (binned), copied (reconstruct writes, fuse
  // reads), and packed for the view archive by the fuse stage, off the latency path (zstd: ~0.6 ms
  // a burst).
  std::vector<cv::Mat> kept_frames;
  std::string packed;  // fuse writes and reads
  bool packed_ok = false;
};

// What the scan's growing parts hold, published by the stages that own them (ScanApp::Memory):
// to be read beside the process's RSS, which says how much but not what.
struct ScanMemory {
  uint64_t views = 0;          // views registered (register stage)
  uint64_t model_samples = 0;  // the tracking model's samples (register stage)
  double model_mib = 0;  // the tracking model without its undo journal (PointMap::memory_bytes)
  double undo_journal_mib = 0;  // the model's undo journal (PointMap::journal_bytes)
  uint64_t keyframes = 0;
  double keyframes_mib = 0;          // Tracker::keyframe_bytes
  double tsdf_mib = 0;               // the live volume (fuse stage; TsdfVolume::MemoryBytes)
  double views_kept_memory_mib = 0;  // the kept frames in memory (ViewArchive::memory_bytes)
  uint64_t preview_points =
      0;  // the preview's decimated model (preview stage; ScanAppOptions::preview_max_points)
};

// The register and fuse stages publish their memory figures every this many views (~0.5 s at 30
// bursts/s).
constexpr uint64_t kScanMemoryEvery = 15;

}  // namespace d3d
