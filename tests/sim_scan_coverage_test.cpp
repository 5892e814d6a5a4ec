// Integration test of the virtual probe with the hand-held scan path, by ground-truth rendering
// along the whole full-arch scan (every 3rd burst of 30 Hz):
//   - the arch stays within the depth of field for ≥ 90 % of the bursts: a burst is "within" when
//     it sees teeth (≥ 5 % of its pixels) and ≥ 80 % of the tooth pixels lie inside the
//     measurement volume [42, 58] mm. (Gum and palate 10–17 mm behind the crowns may lie beyond it,
//     as in a real mouth; the share of all surface pixels inside is printed too.)
//   - ≥ 95 % of the tooth surface (area of tooth-labelled faces) is seen by the camera and lit by
//     the projector, inside the measurement volume, in at least one burst.
// Runs on the procedural typodont and, when ../shared/data is present, on the real upper arch.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>

#include "sim/session/sim_session.h"

namespace d3d {
namespace {

struct ScanCoverage {
  int bursts = 0;
  int bursts_in_dof = 0;
  double pixel_in_dof_share = 0;
  double tooth_coverage = 0;
};

ScanCoverage Measure(const std::string& model) {
  SimSessionOptions o;
  o.model = model;
  o.seed = 1;
  std::unique_ptr<SimSession> session;
  const Status s = SimSession::Create(o, &session);
  EXPECT_TRUE(s.ok()) << s.ToString();
  if (!s.ok()) return {};
  const TriangleMesh& mesh = session->scene();
  const ProbeCalibration& calib = session->calibration();
  std::vector<uint8_t> seen(mesh.faces.size(), 0);
  ScanCoverage c;
  int64_t in_dof_pixels = 0, surface_pixels = 0;
  FrameTruth t;
  for (int64_t i = 0; i < session->NumBursts(); i += 3) {
    session->probe().RenderTruth(session->trajectory().WorldFromProbe(session->BurstStartNs(i)),
                                 &t);
    int surface = 0, inside = 0, tooth = 0, tooth_inside = 0;
    for (int r = 0; r < t.depth_mm.rows; ++r)
      for (int col = 0; col < t.depth_mm.cols; ++col) {
        const uint8_t v = t.visibility.at<uint8_t>(r, col);
        if (v == 0) continue;
        ++surface;
        const float z = t.depth_mm.at<float>(r, col);
        const bool in = z >= calib.depth_min_mm && z <= calib.depth_max_mm;
        inside += in;
        if (t.label.at<uint8_t>(r, col) == static_cast<uint8_t>(SurfaceLabel::kTooth)) {
          ++tooth;
          tooth_inside += in;
        }
        const int f = t.face_index.at<int32_t>(r, col);
        if (v == 2 && in && f >= 0) seen[static_cast<size_t>(f)] = 1;
      }
    ++c.bursts;
    c.bursts_in_dof +=
        tooth >= 0.05 * static_cast<double>(t.depth_mm.total()) && tooth_inside >= 0.8 * tooth;
    in_dof_pixels += inside;
    surface_pixels += surface;
  }
  double tooth_area = 0, seen_area = 0;
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    if (mesh.Label(static_cast<int>(f)) != SurfaceLabel::kTooth) continue;
    const double a = mesh.FaceArea(static_cast<int>(f));
    tooth_area += a;
    seen_area += seen[f] ? a : 0.0;
  }
  c.pixel_in_dof_share = static_cast<double>(in_dof_pixels) /
                         static_cast<double>(std::max<int64_t>(surface_pixels, 1));
  c.tooth_coverage = tooth_area > 0 ? seen_area / tooth_area : 0.0;
  std::printf(
      "[ scan     ] %s: %d bursts checked, %.1f %% within the depth of field, %.1f %% of surface "
      "pixels "
      "inside it, tooth surface covered %.2f %%\n",
      model.c_str(), c.bursts, 100.0 * c.bursts_in_dof / std::max(c.bursts, 1),
      100.0 * c.pixel_in_dof_share, 100.0 * c.tooth_coverage);
  return c;
}

void ExpectGoodScan(const ScanCoverage& c) {
  ASSERT_GT(c.bursts, 100);
  EXPECT_GE(static_cast<double>(c.bursts_in_dof) / c.bursts, 0.90);
  EXPECT_GE(c.tooth_coverage, 0.95);
}

TEST(SimScanCoverage, TypodontFullArch) { ExpectGoodScan(Measure("typodont")); }

TEST(SimScanCoverage, RealUpperArchFullArch) {
  const std::string path = std::string(D3D_SHARED_DATA_DIR) + "/dental/upper_arch_0189MCMV.ply";
  if (!std::filesystem::exists(path))
    GTEST_SKIP() << "../shared/data absent: " << path << " not found";
  ExpectGoodScan(Measure(path));
}

}  // namespace
}  // namespace d3d
