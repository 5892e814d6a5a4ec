// Reading organised range scans stored as PLY with a "range_grid" element (the Stanford 3D
// Scanning Repository's Cyberware scans: obj_info num_cols / num_rows, vertices x y z, then one
// range_grid entry per grid cell, row-major, holding 0 or 1 vertex index).
#pragma once

#include <map>
#include <opencv2/core.hpp>
#include <string>

#include "common/core/rigid.h"
#include "common/core/status.h"

namespace d3d {

// Reads `path` into an organised cloud: num_rows × num_cols CV_32FC3, coordinates multiplied by
// `scale` (the Stanford files are in metres: scale 1000 gives mm), NaN where the cell is empty.
// Errors: NOT_FOUND, IO_ERROR, PARSE_ERROR (not an ascii PLY, no grid size, counts that do not
// match, malformed records), CORRUPT (index out of range, non-finite coordinate). Never throws.
[[nodiscard]] Status LoadRangeGridPly(const std::string& path, double scale, cv::Mat* points);
[[nodiscard]] Status ParseRangeGridPly(const std::string& text, double scale, cv::Mat* points);

// The poses of a Stanford scan set's `.conf` file (lines "bmesh NAME.ply tx ty tz qx qy qz qw",
// metres): scan name without extension → world_from_scan with the translation in mm. The
// rotation is the transpose of the quaternion's matrix (the convention of the data set's README).
// Other lines are ignored. NOT_FOUND when the file cannot be read, PARSE_ERROR when it names no
// scan.
[[nodiscard]] Status LoadRangeScanPoses(const std::string& conf_path,
                                        std::map<std::string, Rigid3d>* world_from_scan);

}  // namespace d3d
