// Model-guided anchoring on virtual-probe bursts: against a model of the true surface it gives
// orders to pixels the burst alone left out, and every one of them is the true order; against a
// model somewhere else, or a model one fringe order away, it gives none.
#include "pipeline/chain/model_anchor.h"

#include <gtest/gtest.h>

#include <cmath>

#include "pipeline/register/surface_points.h"
#include "sim/session/sim_session.h"

namespace d3d {
namespace {

struct Case {
  std::unique_ptr<SimSession> session;
  Burst burst;
  ReconstructedView view;
};

Case MakeCase(int64_t index) {
  Case c;
  SimSessionOptions so;
  so.model = "typodont";
  so.seed = 1;
  EXPECT_TRUE(SimSession::Create(so, &c.session).ok());
  c.burst = c.session->RenderBurst(index, true);
  Reconstructor recon(c.session->calibration());
  std::vector<cv::Mat> frames;
  for (int k = 0; k < c.session->calibration().pattern.steps; ++k)
    frames.push_back(c.burst.frames[static_cast<size_t>(k)].image);
  EXPECT_TRUE(recon.Reconstruct(frames, &c.view).ok());
  return c;
}

// The true visible surface of the burst as a model in the camera frame, moved by model_from_cam.
PointMap TruthModel(const Case& c, const Rigid3d& model_from_cam) {
  cv::Mat normals;
  OrganisedNormals(c.burst.reference_truth.points_in_cam, 0.15, &normals);
  PointMap model;
  model.Insert(SampleOrganised(c.burst.reference_truth.points_in_cam, normals, cv::Mat(), 1),
               model_from_cam);
  return model;
}

struct Counts {
  int64_t gained = 0, wrong = 0;
};

// Pixels that got an order from the anchorer, and those of them whose Φ is off the truth by > π.
Counts Compare(const Case& c, const cv::Mat& order_before, const ReconstructedView& after) {
  Counts n;
  const FringePatternSpec& spec = c.session->calibration().pattern;
  const FrameTruth& t = c.burst.reference_truth;
  for (int r = 0; r < order_before.rows; ++r)
    for (int x = 0; x < order_before.cols; ++x) {
      if (order_before.at<int32_t>(r, x) >= 0 || after.unwrap.order.at<int32_t>(r, x) < 0) continue;
      ++n.gained;
      EXPECT_TRUE(std::isfinite(after.points_in_cam.at<cv::Vec3f>(r, x)[2]));
      const cv::Vec2f uv = t.projector_uv.at<cv::Vec2f>(r, x);
      const double c_true = uv[spec.axis == 'y' ? 1 : 0];
      if (!std::isfinite(c_true)) continue;
      if (std::abs(after.unwrap.Phi.at<float>(r, x) - spec.AbsolutePhase(c_true)) > M_PI) ++n.wrong;
    }
  return n;
}

TEST(ModelAnchor, AnchorsWhatTheModelConfirmsAndOnlyWithTheTrueOrder) {
  Case c =
      MakeCase(0);  // the first molar: much of its gingiva is in regions the marker cannot anchor
  const cv::Mat before = c.view.unwrap.order.clone();
  const int64_t points_before = c.view.points;
  const uchar* points_data = c.view.points_in_cam.data;
  ModelAnchorer anchorer(c.session->calibration(), {}, 0.15);
  ModelAnchorStats st;
  const int64_t n =
      anchorer.Anchor(TruthModel(c, Rigid3d::Identity()), Rigid3d::Identity(), &c.view, &st);
  const Counts k = Compare(c, before, c.view);
  std::printf("groups %d tested, %d anchored; %lld px anchored, %lld wrong; %.1f ms\n",
              st.groups_tested, st.groups_anchored, static_cast<long long>(n),
              static_cast<long long>(k.wrong), st.ms);
  EXPECT_GT(st.groups_anchored, 0);
  EXPECT_GT(n, 20000);  // 31266 px here: the neck-pruned gingiva and tooth neck
  EXPECT_EQ(k.gained, n);
  // 4 of them are one order off: at a depth step where the model (truth points with a normal) has
  // no sample of the front surface, the wrong order lands on the gingiva behind it.
  EXPECT_LE(k.wrong, n / 2000);
  EXPECT_EQ(c.view.points, points_before + n);
  EXPECT_EQ(c.view.points_in_cam.data,
            points_data);  // rewritten in place (the tracker holds the buffers)
  EXPECT_EQ(st.pixels_anchored, n);
}

TEST(ModelAnchor, AModelElsewhereOrAnOrderAwayAnchorsNothing) {
  Case c = MakeCase(0);
  const cv::Mat before = c.view.unwrap.order.clone();
  ModelAnchorer anchorer(c.session->calibration(), {}, 0.15);
  // The true surface 5 mm to the side: nothing of the view is near it.
  Rigid3d side = Rigid3d::Identity();
  side.translation() = Eigen::Vector3d(5, 0, 0);
  EXPECT_EQ(anchorer.Anchor(TruthModel(c, side), Rigid3d::Identity(), &c.view), 0);
  // The true surface moved along the optical axis by about one fringe order's depth: no K puts
  // a group on it everywhere, and a partial fit is not taken.
  for (const double dz : {-1.6, 1.6}) {
    Rigid3d along = Rigid3d::Identity();
    along.translation() = Eigen::Vector3d(0, 0, dz);
    const int64_t n = anchorer.Anchor(TruthModel(c, along), Rigid3d::Identity(), &c.view);
    const Counts k = Compare(c, before, c.view);
    EXPECT_EQ(k.wrong, 0) << "dz " << dz << ": " << n << " px anchored";
  }
  // Disabled, or an empty model: nothing.
  ModelAnchorOptions off;
  off.enabled = false;
  ModelAnchorer none(c.session->calibration(), off, 0.15);
  EXPECT_EQ(none.Anchor(TruthModel(c, Rigid3d::Identity()), Rigid3d::Identity(), &c.view), 0);
  EXPECT_EQ(anchorer.Anchor(PointMap(), Rigid3d::Identity(), &c.view), 0);
}

TEST(ModelAnchor, OptionsAreChecked) {
  ModelAnchorOptions o;
  EXPECT_NO_THROW(o.Check());
  o.inlier_mm = 1.0;  // above the gate
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = {};
  o.max_rival_share = o.min_inlier_share;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = {};
  o.max_incidence_deg = 90;
  EXPECT_THROW(o.Check(), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
