// Lossless zstd packing of images (a burst's camera frames, a view's organised points): what a
// scan keeps to reconstruct or match a view again later (pipeline/chain/view_archive.h: the kept
// views' frames; pipeline/register/keyframe_graph.h: a keyframe's feature inputs until they are
// needed).
//
// Threads: a FramePacker is one thread's (it holds a zstd context and a buffer). UnpackFrames is
// free.
#pragma once

#include <opencv2/core.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "common/core/status.h"

namespace d3d {

class FramePacker {
 public:
  // zstd compression level (1 = fastest; ZSTD's range). Throws std::invalid_argument outside [1,
  // 19].
  explicit FramePacker(int level = 1);
  ~FramePacker();
  FramePacker(const FramePacker&) = delete;
  FramePacker& operator=(const FramePacker&) = delete;
  // frames: 1..255 images of one size and type (continuous or not), of depth CV_8U, CV_16U or
  // CV_32F with 1 to 4 channels (camera frames CV_8UC1 / CV_16UC1, organised points CV_32FC3).
  // *blob is replaced (its capacity reused): a 16-byte header (count, rows, cols, type) and one
  // zstd frame of the pixels. INVALID_ARGUMENT for no frames, mixed sizes or types, another type;
  // INTERNAL when zstd fails.
  [[nodiscard]] Status Pack(const std::vector<cv::Mat>& frames, std::string* blob);

 private:
  void* ctx_;  // ZSTD_CCtx
  int level_;
  std::string raw_;  // the pixels, contiguous (reused)
};

// The frames of a Pack()ed blob into *frames (resized; an entry of the right size and type keeps
// its buffer), bit for bit. CORRUPT for a blob that is cut off, has a bad header or does not
// decompress to its size.
[[nodiscard]] Status UnpackFrames(std::string_view blob, std::vector<cv::Mat>* frames);

}  // namespace d3d
