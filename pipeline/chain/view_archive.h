// The frames of a scan's fused views, kept (zstd-compressed) so that the end of the scan can
// reconstruct them again and fuse them at the pose graph's poses (FinishScan's refusion).
//
// Why: the live model is fused at the tracked poses; the pose graph (loop closures) corrects them
// at the end, by 0.15 mm on a 450-burst typodont replay and 0.24-0.31 mm on the same recording
// processed live, where the host drops half the bursts and tracks wider steps. A mesh left at the
// tracked poses then depends on how the tracker drifted: 13.6 µm RMS lossless against 24-46 µm live
// on one recording. Fused again at the optimised poses, both come from the same pose graph.
// A host has no recording to read them back from when it is live, so it keeps them itself.
//
// What is kept: the frames the reconstruction ran on (after binning: 4 × 320 × 240 CV_8U per burst
// for a 640 × 480 probe at bin 2, 307 kB), compressed losslessly with zstd level 1 (~1 ms per
// burst); reconstructing them again gives the same view bit for bit.
//
// Where: in memory by default, ~150 kB a view, so memory grows with the scan's length (4-5 MB/s
// live at 28-30 bursts/s); a host gives the archive a directory to spill to (SpillTo) and keeps
// only an index in memory. A spilled blob is written once (appended, ~1 ms per MB into the page
// cache) and read back once, at the end of the scan.
//
// Threads: a ViewArchive is one thread's at a time (the fuse thread adds, then the thread that
// finishes the scan reads; Get uses a buffer of the archive's). Packing: common/pack/frame_pack.h.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "common/core/status.h"
#include "common/pack/frame_pack.h"

namespace d3d {

class ViewArchive {
 public:
  ViewArchive() = default;
  ~ViewArchive();  // closes the spill file (its space is freed then)
  ViewArchive(const ViewArchive&) = delete;
  ViewArchive& operator=(const ViewArchive&) = delete;

  // From now on keeps the blobs in an unnamed temporary file in directory `dir` instead of memory:
  // memory then holds ~56 bytes per view (its index entry) instead of its ~150-200 kB, so a live
  // scan's memory does not grow with its length through the kept frames. The file is made with
  // O_TMPFILE (or created and unlinked at once where the file system lacks it): it has no name and
  // its space is freed when the archive is destroyed, even when the process is killed. Entries
  // already added stay in memory. IO_ERROR when no such file can be made in `dir` (the archive then
  // keeps using memory); INVALID_ARGUMENT when it spills already.
  [[nodiscard]] Status SpillTo(const std::string& dir);
  bool spilling() const { return fd_ >= 0; }
  // Keeps a copy of `blob` under `burst_seq` (the probe's burst number). Bursts are added in the
  // order they were processed; a burst_seq not above the last one added (a probe that restarted its
  // numbering) replaces nothing: Get finds the latest entry for it. Spilling, the blob is appended
  // to the file; when that write fails (e.g. the disk is full) the blob is kept in memory instead,
  // so nothing is lost, and the write's IO_ERROR is returned. OK otherwise.
  [[nodiscard]] Status Add(uint64_t burst_seq, std::string_view blob);
  // The frames kept for burst_seq. NOT_FOUND when it was never added; IO_ERROR when the spill file
  // cannot be read back; CORRUPT as UnpackFrames.
  [[nodiscard]] Status Get(uint64_t burst_seq, std::vector<cv::Mat>* frames) const;
  // Drops the latest entry for burst_seq (a view taken back by an undo); false when there is none.
  // A spilled entry's space in the file is reused when it was the last one written (as an undo's
  // views are), else not until Clear.
  bool Remove(uint64_t burst_seq);
  void Clear();  // spilling, the file is emptied (and stays the archive's)
  size_t size() const { return entries_.size(); }
  int64_t bytes() const { return bytes_; }  // compressed bytes kept (in memory and in the file)
  // Bytes of memory the entries hold: the blobs kept in memory and the index.
  int64_t memory_bytes() const {
    return bytes_ - spilled_bytes_ + static_cast<int64_t>(entries_.capacity() * sizeof(Entry));
  }
  int64_t spilled_bytes() const { return spilled_bytes_; }  // of bytes(), in the file

 private:
  struct Entry {
    uint64_t burst_seq;
    int64_t offset;    // in the spill file; -1: the blob is in `blob`
    uint64_t size;     // blob bytes
    std::string blob;  // in memory (not spilled)
  };
  std::vector<Entry> entries_;
  bool sorted_ =
      true;  // entries_ in increasing burst_seq (binary search), else a linear search from the back
  int64_t bytes_ = 0;
  int64_t spilled_bytes_ = 0;
  int fd_ = -1;           // the spill file, -1 = none
  int64_t file_end_ = 0;  // where the next blob goes
  mutable std::string
      read_;  // Get's buffer for a spilled blob (the archive is one thread's at a time)
};

}  // namespace d3d
