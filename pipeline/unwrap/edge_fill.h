// Edge fill: absolute phase for the pixels that the albedo-edge cut of the quality map removed
// (QualityReason::kModulationEdge), taken from the anchored pixels beside them.
// Our method (no published source; the modulation test is the quality map's own, quality_map.h).
//
// Why: the cut (QualityOptions::modulation_edge_ratio) keeps the unwrapper's regions from crossing
// a tooth/gingiva border or a crown's silhouette, where a depth step of nearly one fringe can hide
// in a smooth-looking phase ramp. It is 2–4 px wide on each side of a sharp border, wider where B
// falls steadily (a wall turning away from the camera), and the pixels in it never get a point. On
// a full typodont arch (seed 1, every 4th burst, burst alone) 4.6 of the 4.9 % of the tooth area
// that some burst saw lit but no burst reconstructed was lost there and nowhere else: the
// interproximal walls (2.7 pp), the gingival margin (1.0 pp) and the axial walls where they turn
// away from the camera (0.8 pp). Those surfaces are only ever seen beside a silhouette, so every
// view cuts them, and the fused model had 93.4–94.1 % coverage.
//
// Method: the cut pixels are filled layer by layer (up to `passes` 4-neighbour layers from the
// anchored pixels, the layers of a pass read only earlier layers). A cut pixel p takes Φ from a
// neighbour q that has Φ when the step is one the unwrapper would have joined (|W(φp − φq)| ≤
// max_jump, not backwards along x beyond max_reverse, see UnwrapOptions) and when p's modulation
// lies within max_modulation_ratio of q's: Φp = Φq + W(φp − φq). The modulation test is what
// keeps the fill on q's side of the border: the border is where B steps (albedo 0.70 against 0.35
// at a tooth/gingiva border, the background's B beyond a silhouette), so a fill from the tooth
// stops at the first pixel whose B has dropped, before it could carry the tooth's order across a
// hidden step. Several neighbours must agree on Φp within max_spread; Φp outside the measurement
// volume ([phase_min, phase_max]) is refused.
//
// Measured with the renderer's truth (typodont seed 1, every 4th / 8th burst, modulation
// ratio 1.2): the pixels filled in layers 1 … 3 have a wrong order at 0.001–0.02 % (0.000 % for the
// anchored pixels), in layers 4 … 6 at 0.03–0.08 %, in layers 7 … 11 at 0.1–0.3 %; at ratio 1.5
// already 0.5 % in layer 6, so the ratio stays at 1.2. Their phase error is larger than inside the
// regions (RMS 0.12–0.18 rad against 0.04–0.05 rad, growing with the layer; 10–100 µm RMS per view
// against 9–17 µm), because the camera's blur mixes light from across the border into them and the
// surface is seen grazing there. A filled pixel's quality is quality_factor times the quality of
// the anchored pixel its layer chain started from. Full typodont arch, seed 1, every view fused at
// its true pose (d3d-fuse --truth-poses):
//   passes, quality_factor   0 (off)   3, 0.25   1, 1     3, 1     6, 1
//   coverage %               93.88     94.37     94.39    94.95    95.66   (the bursts saw 96.90)
//   trueness RMS / p95 µm    7.4 / 13  7.6 / 14  8.2 / 15 8.8 / 16 9.2 / 16
// A low quality_factor costs most of the gain: the mesh needs a fused weight of 0.5 at every corner
// (TsdfOptions::min_mesh_weight), which surfaces only a few grazing views saw do not reach. The
// defaults (6, 1) trade 1.8 µm of trueness for 1.8 points of coverage, which the interproximal
// walls and the gingival margin need (a crown margin the scan does not show cannot be prepared
// against).
//
// Threads: one EdgeFiller per thread (it keeps its buffers between calls).
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "common/core/status.h"
#include "pipeline/unwrap/unwrap.h"

namespace d3d {

struct EdgeFillOptions {
  int passes = 6;                     // 4-neighbour layers filled from the anchored pixels; 0 = off
  double max_modulation_ratio = 1.2;  // B(p)/B(q) within [1/r, r] (> 1)
  double max_spread = 0.5;  // rad: the neighbours' predictions of Φp must agree within this
  float quality_factor =
      1.0f;  // a filled pixel's quality: this × its chain's anchored quality, in (0, 1]
  // Throws std::invalid_argument unless 0 ≤ passes ≤ 64, max_modulation_ratio > 1, max_spread > 0,
  // 0 < quality_factor ≤ 1.
  void Check() const;
};

struct EdgeFillStats {
  int64_t pixels_filled = 0;  // cut pixels that got Φ (all layers)
};

class EdgeFiller {
 public:
  // `unwrap`: the unwrapper's options (max_jump, max_reverse, monotonic_x are used).
  // Throws std::invalid_argument for invalid options (either Check()).
  EdgeFiller(const EdgeFillOptions& options, const UnwrapOptions& unwrap);
  const EdgeFillOptions& options() const { return options_; }

  // Inputs (H×W, the same size):
  //   phi         CV_32F wrapped phase φ [rad], NaN invalid
  //   modulation  CV_32F modulation B [DN]
  //   reason      CV_8U QualityReason of the quality map: only kModulationEdge pixels are filled
  //   phase_min, phase_max  CV_32F measurement volume as for Unwrapper::Run (both empty = none)
  // In/out:
  //   Phi         CV_32F absolute phase Φ [rad], NaN where none (Unwrapper's output)
  //   order       CV_32S fringe order k = floor(Φ/2π), −1 where none
  //   quality     CV_32F quality map; filled pixels get their quality (see the file comment)
  // INVALID_ARGUMENT for mismatched sizes or types (nothing written then). OK with passes = 0.
  [[nodiscard]] Status Fill(const cv::Mat& phi, const cv::Mat& modulation, const cv::Mat& reason,
                            const cv::Mat& phase_min, const cv::Mat& phase_max, cv::Mat* Phi,
                            cv::Mat* order, cv::Mat* quality, EdgeFillStats* stats = nullptr);

 private:
  EdgeFillOptions options_;
  UnwrapOptions unwrap_;
  std::vector<uint8_t>
      layer_;                // per pixel: 0 none (or anchored), 1..passes the layer that filled it
  std::vector<float> base_;  // per pixel: the anchored quality its fill chain started from
  std::vector<int32_t> added_;  // pixels filled in the current pass
  std::vector<float> added_phi_, added_base_;
};

}  // namespace d3d
