// Reading organised range scans stored as PLY with a "range_grid" element (the Stanford 3D
// Scanning Repository's Cyberware scans: obj_info num_cols / num_rows, vertices x y z, then one
// range_grid entry per grid cell, row-major, holding 0 or 1 vertex index).
#pragma once

#include <opencv2/core.hpp>
#include <string>

#include "common/core/status.h"

namespace d3d {

// Reads `path` into an organised cloud: num_rows × num_cols CV_32FC3, coordinates multiplied by
// `scale` (the Stanford files are in metres: scale 1000 gives mm), NaN where the cell is empty.
// Errors: NOT_FOUND, IO_ERROR, PARSE_ERROR (not an ascii PLY, no grid size, counts that do not
// match, malformed records), CORRUPT (index out of range, non-finite coordinate). Never throws.
[[nodiscard]] Status LoadRangeGridPly(const std::string& path, double scale, cv::Mat* points);
[[nodiscard]] Status ParseRangeGridPly(const std::string& text, double scale, cv::Mat* points);

}  // namespace d3d
