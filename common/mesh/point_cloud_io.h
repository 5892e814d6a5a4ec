// Point clouds as binary little-endian PLY (x, y, z float mm; optional nx, ny, nz float; optional
// grey uchar; optional quality float), e.g. the organised cloud of one reconstructed view.
#pragma once

#include <opencv2/core.hpp>
#include <string>

#include "common/core/status.h"

namespace d3d {

// points: H×W CV_32FC3 (NaN = no point). normals: empty or CV_32FC3 of the same size. grey: empty
// or CV_8U. quality: empty or CV_32F. Writes only the finite points. INVALID_ARGUMENT for maps of
// mismatched sizes/types, IO_ERROR if the file cannot be written. *written (optional) = point
// count.
[[nodiscard]] Status SavePointCloudPly(const std::string& path, const cv::Mat& points,
                                       const cv::Mat& normals, const cv::Mat& grey,
                                       const cv::Mat& quality, int64_t* written = nullptr);

}  // namespace d3d
