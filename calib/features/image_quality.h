// Step 1 of the calibration (dissertation, "pre-treatment"): reject calibration images that are too
// blurred or too noisy for sub-pixel feature positions, with the measures reported per image.
//
// Sharpness: the blur of the target's edges as a Gaussian σ in pixels. For an edge of contrast C
// blurred by a Gaussian of σ, the largest gradient is C / (σ √(2π)); we take C as the spread
// between the 2nd and 98th percentiles of the image and the largest gradient as the 99.7th
// percentile of the Scharr gradient magnitude (robust to a few hot pixels), so
//   edge_blur_px = C / (√(2π) · g_max).
// A perfectly sharp, pixel-sampled edge gives ≈ 0.4–0.5 px (the pixel's own footprint).
// Noise: Immerkær's fast noise variance estimation ("Fast noise variance estimation", Computer
// Vision and Image Understanding 64(2):300–302, 1996): σ = √(π/2) · mean |I ∗ N| / 6 with the
// Laplacian-difference mask N = [1 −2 1; −2 4 −2; 1 −2 1], here restricted to pixels away from
// edges (Scharr magnitude below its 60th percentile), which the mask would take for noise.
#pragma once

#include <opencv2/core.hpp>
#include <string>

namespace d3d {

struct ImageQualityOptions {
  double max_edge_blur_px = 2.5;  // reject above: corners/centres lose precision, detection fails
  double max_noise_dn = 6.0;      // reject above (8-bit DN; 16-bit images are scaled to 8 bits)
  double min_contrast_dn = 30.0;  // reject below: under-exposed or no target in view
  void Check() const;             // throws std::invalid_argument
};

struct ImageQuality {
  double edge_blur_px = 0;  // Gaussian σ of the edges (see above), px
  double noise_dn = 0;      // σ of the noise, 8-bit DN
  double contrast_dn = 0;   // 98th − 2nd percentile, 8-bit DN
  bool accepted = false;
  std::string reason;  // why rejected ("" when accepted)
};

// gray: H×W CV_8U or CV_16U (16-bit is scaled by 1/257). Throws std::invalid_argument for another
// type or an image smaller than 16 × 16.
ImageQuality AssessImage(const cv::Mat& gray, const ImageQualityOptions& options = {});

}  // namespace d3d
