// Planar calibration targets: the chessboard and the (symmetric or asymmetric) circle grid, their
// feature coordinates on the target (mm, z = 0) in the order the detectors return them, and the
// text form the tools take (`chessboard:9x6:25`, `circles:9x7:1.2`, `circles:4x11:2:asymmetric`).
//
// Feature order (OpenCV's, so OpenCV's detectors and reference files line up with ours): row-major,
// `cols` features per row, `rows` rows;
//   chessboard: inner corner (r, c) at (c·s, r·s), s = square side;
//   symmetric circle grid: centre (r, c) at (c·s, r·s), s = centre spacing;
//   asymmetric circle grid: centre (r, c) at ((2c + r mod 2)·s, r·s), s = half the distance between
//   two circles of one row (OpenCV's convention for CALIB_CB_ASYMMETRIC_GRID).
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "common/core/status.h"

namespace d3d {

enum class TargetKind { kChessboard, kCircleGrid, kAsymmetricCircleGrid };

struct CalibrationTarget {
  TargetKind kind = TargetKind::kChessboard;
  int cols = 9;                     // inner corners or circles per row
  int rows = 6;                     // rows of inner corners or circles
  double spacing_mm = 1.0;          // square side, or circle spacing (see above)
  double circle_diameter_mm = 0.0;  // circles only; 0 = unknown (the calibration estimates it)

  // Throws std::invalid_argument: fewer than 3 × 3 features (2 × 3 asymmetric), spacing ≤ 0,
  // a diameter that does not fit between neighbours.
  void Check() const;
  bool IsCircles() const { return kind != TargetKind::kChessboard; }
  int NumFeatures() const { return cols * rows; }
  // Feature coordinates on the target, mm, z = 0, in detector order (see above).
  std::vector<Eigen::Vector3d> FeaturePoints() const;
  // Smallest distance between two features on the target, mm.
  double NearestFeatureDistanceMm() const;
  // Extent of the features on the target: (min, max) corners of their bounding box, mm.
  std::pair<Eigen::Vector2d, Eigen::Vector2d> FeatureBounds() const;
  // The text form (round trip of ParseTarget).
  std::string ToString() const;
};

// Parses "chessboard:COLSxROWS:SQUARE_MM" or
// "circles:COLSxROWS:SPACING_MM[:asymmetric][:d=DIAM_MM]". INVALID_ARGUMENT naming what is wrong.
[[nodiscard]] Status ParseTarget(const std::string& text, CalibrationTarget* out);

}  // namespace d3d
