// Pairwise registration of two organised views from an unknown relative pose: an initial alignment
// by features — SIFT on texture and range images → RANSAC rigid (features.h), or 3-D FPFH
// descriptors → RANSAC rigid (fpfh.h), or SIFT with FPFH as the fallback — then ICP (icp.h, k-d
// tree association) for the refinement. Used for range scans (Stanford bunny) and by the benchmark.
#pragma once

#include <opencv2/core.hpp>
#include <string>

#include "pipeline/register/features.h"
#include "pipeline/register/fpfh.h"
#include "pipeline/register/icp.h"

namespace d3d {

enum class InitialAlignment {
  kSift,          // SIFT on texture / range images (features.h); the default
  kFpfh,          // FPFH on voxel keypoints of the 3-D points (fpfh.h)
  kSiftThenFpfh,  // SIFT, and FPFH when SIFT finds no consensus or its pose fails ICP
};
const char* ToString(InitialAlignment a);

struct PairwiseOptions {
  InitialAlignment initial = InitialAlignment::kSift;
  FeatureOptions features;  // kSift, kSiftThenFpfh
  FpfhOptions fpfh;         // kFpfh, kSiftThenFpfh
  IcpOptions icp;
  double max_gap_mm = 2.0;  // GridNormals
  int source_stride = 1;    // ICP source: every k-th grid sample
  void Check() const;
};

struct PairwiseResult {
  bool ok = false;
  std::string reason;
  Rigid3d target_from_source = Rigid3d::Identity();
  InitialAlignment initial_method =
      InitialAlignment::kSift;  // the method whose pose ICP refined last
  FeatureAlignResult initial;   // of initial_method (an FpfhAlignResult's common part for kFpfh)
  FpfhAlignResult fpfh;         // the FPFH attempt's details (keypoints, overlap, rival consensus)
  std::string
      sift_reason;  // kSiftThenFpfh: why SIFT (or ICP from its pose) failed, empty if it did not
  IcpResult refined;
  double ms_features = 0, ms_icp = 0;  // initial alignment(s), ICP(s): wall time
};

// Options for Cyberware-like range scans in mm (Stanford 3D Scanning Repository: 0.5 mm grid,
// views 45–90° apart): SIFT tuned for the shaded range images, FPFH at 2.5 mm voxels, ICP from
// 5 mm to 1 mm association gates. `initial` as given.
PairwiseOptions RangeScanPairwiseOptions(InitialAlignment initial);

// source_points, target_points: H×W CV_32FC3 (mm, NaN = none), any sizes; textures: H×W CV_8U or
// empty. Throws std::invalid_argument for invalid options; expected failures come back not ok
// with the reason (prefixed "icp: " when the refinement failed).
PairwiseResult RegisterPair(const cv::Mat& source_points, const cv::Mat& source_texture,
                            const cv::Mat& target_points, const cv::Mat& target_texture,
                            const PairwiseOptions& options);

}  // namespace d3d
