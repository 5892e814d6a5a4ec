// Calibration sessions of the virtual probe: a printed planar target (chessboard or circle grid,
// black print on white paper) at N seeded poses, rendered by the VirtualProbe under white light
// and under multi-frequency phase-shift sets along both projector axes, written to a folder with
// the true calibration, so that calib/ can be tested against known parameters.
//
// Folder layout (read by d3d-calibrate --images DIR/images --projector-phase DIR/phase):
//   DIR/calibration.json        the probe's true calibration (as d3d-sim writes it)
//   DIR/session.json            target, true pose of every view (cam_from_target), options
//   DIR/images/pose_NN.png      white light (projector fully on), 8-bit grey
//   DIR/phase/phase.json        the phase sets: steps N, periods T_j (projector px), axes
//   DIR/phase/pose_NN/A_J_S.png axis A ∈ {x, y}, period index J, step S: projector pattern
//                               ½ + ½ cos(2π c / T_J − 2π S / N), c the projector coordinate
//                               along A (OpenCV convention: the first pixel's centre is 0)
//
// Target mesh: the target plane z = 0 (target frame = world frame), faces toward −z (toward the
// probe). Print is exact geometry: every circle is a 64-gon with 4-fold symmetry (its centroid is
// the circle's centre; its area is the circle's to 1e-3), squares are exact; white faces carry
// label kTooth and black ones kGingiva, whose materials are replaced by matte paper and ink
// (no sub-surface scattering, no gloss, no texture).
//
// White image anti-aliasing: the renderer samples one ray per pixel, which quantises the print's
// edges to pixel centres (a ~0.02 px centroid jitter on a 24-px circle). The white image is
// therefore rendered by a second probe whose camera has twice the resolution (same optics:
// fx, fy doubled, principal point 2c + ½) without noise and at 16 bits, averaged over 2 × 2
// pixels, and then gets the sensor's shot and read noise and 8-bit quantisation at the native
// resolution (the SensorModel of the design). Phase frames are rendered directly.
#pragma once

#include <string>
#include <vector>

#include "calib/features/target.h"
#include "calib/model/probe_calibration.h"
#include "common/core/rigid.h"
#include "common/core/status.h"
#include "common/mesh/mesh.h"
#include "sim/render/probe_design.h"

namespace d3d {

struct CalibrationSessionOptions {
  std::string target = "circles:9x7:1.2:d=0.6";  // calib/features/target.h; circles need d=DIAM
  int poses = 15;
  uint32_t seed = 1;       // poses and sensor noise
  int camera_width = 640;  // 640 × 480 or 1280 × 1024 (probe_design.h)
  int camera_height = 480;
  int steps = 4;  // phase steps per period
  std::vector<double> periods_px = {1200.0, 120.0,
                                    24.0};  // coarse → fine; the first ≥ projector extent
  int white_supersample = 2;                // 1 = no anti-aliasing of the white image
  double paper_albedo = 0.6;      // white paper (kept below saturation at the nearest pose)
  double ink_albedo = 0.04;       // black print
  double min_distance_mm = 46.0;  // camera-to-target-centre distance range
  double max_distance_mm = 54.0;
  double min_tilt_deg = 12.0;  // target tilt range (about a random in-plane axis)
  double max_tilt_deg = 35.0;
  double max_roll_deg = 15.0;  // rotation about the optical axis
  bool noise = true;
  bool gamma = true;   // projector gamma 2.2 as designed (false: linear)
  int threads = 0;     // render threads (0 = all cores)
  void Check() const;  // throws std::invalid_argument
};

struct CalibrationViewTruth {
  std::string name;  // "pose_NN"
  Rigid3d cam_from_target = Rigid3d::Identity();
};

struct CalibrationSessionResult {
  ProbeCalibration truth;
  CalibrationTarget target;
  std::vector<CalibrationViewTruth> views;
  double seconds = 0;
};

// The printed target (see above) with a white margin of margin_mm around the features.
TriangleMesh MakeCalibrationTargetMesh(const CalibrationTarget& target, double margin_mm);

// N seeded poses whose target (features plus one spacing) lies inside the camera's and the
// projector's images with a margin of `margin_px`. INVALID_ARGUMENT if the target cannot fit.
[[nodiscard]] Status MakeCalibrationPoses(const CalibrationSessionOptions& options,
                                          const CalibrationTarget& target,
                                          const ProbeCalibration& calibration, double margin_px,
                                          std::vector<Rigid3d>* cam_from_target);

// Renders and writes the session to out_dir (created). INVALID_ARGUMENT for a bad target text or
// a target that does not fit the view, IO_ERROR for files that cannot be written. Throws
// std::invalid_argument for invalid options. `progress`: a progress bar on stderr.
[[nodiscard]] Status RenderCalibrationSession(const CalibrationSessionOptions& options,
                                              const std::string& out_dir, bool progress,
                                              CalibrationSessionResult* out);

}  // namespace d3d
