// Test truth shared by the stereo and multi-plane calibration tests: a 640×480 camera and a
// 912×1140 projector (intrinsics K in px, distortion k1,k2,p1,p2,k3) and their pose cam_from_proj
// (12° about y, 10.63 mm baseline), close to the virtual probe's design.
#pragma once

#include <Eigen/Geometry>
#include <cmath>

#include "calib/model/camera_model.h"
#include "common/core/rigid.h"

namespace d3d::testing {

inline const PinholeBrownConrady kTestCam{640,    480,  2000, 2000,    322.7, 236.9,
                                          -0.045, 0.12, 2e-4, -1.5e-4, 0};
inline const PinholeBrownConrady kTestProj{912,  1140,  2100,  2100,   457.3, 566.4,
                                           0.03, -0.05, -1e-4, 0.8e-4, 0};

inline Rigid3d TestCamFromProj() {
  Rigid3d p = Rigid3d::Identity();
  p.linear() = Eigen::AngleAxisd(-12.0 * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix();
  p.translation() = Eigen::Vector3d(10.63, 0, 0);
  return p;
}

}  // namespace d3d::testing
