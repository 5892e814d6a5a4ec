// Step 2 of the calibration: target features in an image.
//
// Chessboard: OpenCV's detector (cv::findChessboardCorners, adaptive threshold + normalisation)
// for the grid and its order, then OpenCV's sub-pixel refinement (cv::cornerSubPix: the corner is
// the point to which the image gradients in a window are orthogonal; Förstner & Gülch 1987).
//
// Circle grid: the grid and its order from cv::findCirclesGrid (blob detection + grid fitting),
// then each centre measured by us from image moments: the centroid of the blob's darkness
// w(x) = clamp((B − I(x)) / (B − D), 0, 1), B the local background (median of a ring around the
// blob), D the blob's interior level (median of its core), summed inside a circular window that
// covers the blob's ellipse plus the blur (radius 2·√λ_max + 2.5 px from the blob's binary second
// moments), re-centred until it moves < 1e-3 px. w is the share of a pixel covered by the dark disk
// once the image is blurred by a symmetric PSF, so the centroid is the centroid of the imaged
// ellipse (sub-pixel, unbiased by the blur).
//
// Perspective bias: the centroid of the imaged ellipse is not the image of the circle's centre
// (Heikkilä 2000, "Geometric camera calibration using circular control points", IEEE TPAMI
// 22(10):1066–1077, sect. 3). The detector reports the ellipse centroid; the camera model of
// calib/camera predicts that same point (the centre of the projected conic) when given the circle
// radius, which is how the bias is handled. m00 (the blob's area in px²) is reported so that an
// unknown circle diameter can be estimated.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "calib/features/target.h"

namespace d3d {

struct FeatureOptions {
  int corner_window_half_px =
      5;  // cv::cornerSubPix window (2·half+1 square; OpenCV's sample: 5 → 11×11)
  int corner_max_iterations = 30;        // cv::cornerSubPix stop: iterations ...
  double corner_epsilon_px = 1e-4;       // ... or a step below this
  double min_blob_area_px = 12;          // circle blobs smaller than this are ignored (noise)
  double max_blob_area_fraction = 0.05;  // ... and larger than this share of the image
  int centroid_iterations = 10;          // moment centroid re-centring passes
  void Check() const;                    // throws std::invalid_argument
};

struct DetectedFeatures {
  bool found = false;
  std::string reason;                      // why not found ("" when found)
  std::vector<Eigen::Vector2d> points_px;  // target.NumFeatures() points, detector order (target.h)
  std::vector<double> blob_area_px;  // circles: m00 of each blob (px²); empty for chessboards
};

// gray: H×W CV_8U (CV_16U is scaled to 8 bits). Throws std::invalid_argument for another type or
// an invalid target/options. A target that is not found (or found with the wrong number of
// features) is an expected failure: found = false with the reason.
DetectedFeatures DetectTarget(const cv::Mat& gray, const CalibrationTarget& target,
                              const FeatureOptions& options = {});

// The moment centroid of one dark blob near `start_px` (see above), window radius limited to
// max_radius_px. Returns false if the blob has no contrast. Exposed for tests and for other
// blob-like targets. area_px (optional): the blob's m00.
bool DarkBlobCentroid(const cv::Mat& gray8, const Eigen::Vector2d& start_px, double max_radius_px,
                      int iterations, Eigen::Vector2d* centre_px, double* area_px = nullptr);

}  // namespace d3d
