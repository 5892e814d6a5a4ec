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
// Threads: FramePacker is one thread's (it holds a zstd context); ViewArchive is one thread's at a
// time (the fuse thread adds, then the thread that finishes the scan reads). Unpack is free.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "common/core/status.h"

namespace d3d {

class FramePacker {
 public:
  // zstd compression level (1 = fastest; ZSTD's range). Throws std::invalid_argument outside [1, 19].
  explicit FramePacker(int level = 1);
  ~FramePacker();
  FramePacker(const FramePacker&) = delete;
  FramePacker& operator=(const FramePacker&) = delete;
  // frames: 1..255 images of one size, all CV_8UC1 or all CV_16UC1 (continuous or not). *blob is
  // replaced (its capacity reused): a 16-byte header (count, rows, cols, type) and one zstd frame of
  // the pixels. INVALID_ARGUMENT for no frames, mixed sizes or types, another type; INTERNAL when
  // zstd fails.
  [[nodiscard]] Status Pack(const std::vector<cv::Mat>& frames, std::string* blob);

 private:
  void* ctx_;  // ZSTD_CCtx
  int level_;
  std::string raw_;  // the pixels, contiguous (reused)
};

// The frames of a Pack()ed blob into *frames (resized; an entry of the right size and type keeps its
// buffer). CORRUPT for a blob that is cut off, has a bad header or does not decompress to its size.
[[nodiscard]] Status UnpackFrames(std::string_view blob, std::vector<cv::Mat>* frames);

class ViewArchive {
 public:
  // Keeps a copy of `blob` under `burst_seq` (the probe's burst number). Bursts are added in the
  // order they were processed; a burst_seq not above the last one added (a probe that restarted its
  // numbering) replaces nothing: Get finds the latest entry for it.
  void Add(uint64_t burst_seq, std::string_view blob);
  // The frames kept for burst_seq. NOT_FOUND when it was never added; CORRUPT as UnpackFrames.
  [[nodiscard]] Status Get(uint64_t burst_seq, std::vector<cv::Mat>* frames) const;
  // Drops the latest entry for burst_seq (a view taken back by an undo); false when there is none.
  bool Remove(uint64_t burst_seq);
  void Clear();
  size_t size() const { return entries_.size(); }
  int64_t bytes() const { return bytes_; }  // compressed bytes held

 private:
  struct Entry {
    uint64_t burst_seq;
    std::string blob;
  };
  std::vector<Entry> entries_;
  bool sorted_ = true;  // entries_ in increasing burst_seq (binary search), else a linear search from the back
  int64_t bytes_ = 0;
};

}  // namespace d3d
