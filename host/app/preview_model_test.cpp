#include "host/app/preview_model.h"

#include <gtest/gtest.h>

namespace d3d {
namespace {

// A 30 × 30 px view of a plane 50 mm in front of the camera, points 0.5 mm apart.
struct PlaneView {
  cv::Mat points = cv::Mat(30, 30, CV_32FC3), normals = cv::Mat(30, 30, CV_32FC3);
  PlaneView() {
    for (int y = 0; y < 30; ++y)
      for (int x = 0; x < 30; ++x) {
        points.at<cv::Vec3f>(y, x) =
            cv::Vec3f(0.5f * static_cast<float>(x), 0.5f * static_cast<float>(y), 50);
        normals.at<cv::Vec3f>(y, x) = cv::Vec3f(0, 0, -1);
      }
  }
};

Rigid3d At(double x) {
  Rigid3d p = Rigid3d::Identity();
  p.translation().x() = x;
  return p;
}

TrackResult Accepted(const Rigid3d& world_from_cam, int segment, bool in_main) {
  TrackResult t;
  t.accepted = true;
  t.world_from_cam = world_from_cam;
  t.display_from_cam = world_from_cam;
  t.segment = segment;
  t.in_main = in_main;
  return t;
}

PreviewModelOptions PreviewOptions() {
  PreviewModelOptions o;
  o.cell_mm = 0.4;
  o.stride_px = 1;
  return o;
}

TEST(PreviewModel, ASegmentApartIsDrawnBesideTheModelAndJoinsIt) {
  const PlaneView v;
  PreviewModel m(PreviewOptions());
  m.AddView(0, Accepted(At(0), 0, true), v.points, v.normals);
  const size_t model = m.model_points();
  EXPECT_GT(model, 100u);
  EXPECT_EQ(m.views_in_model(), 1u);
  // A segment apart: its own cloud, drawn where display_from_cam puts it; the model is unchanged.
  Rigid3d display = At(40);
  TrackResult apart = Accepted(At(2040), 1, false);
  apart.display_from_cam = display;
  m.AddView(1, apart, v.points, v.normals);
  EXPECT_EQ(m.model_points(), model);
  EXPECT_GT(m.segment_points(), 100u);
  PreviewSnapshot s;
  m.CopyTo(&s);
  ASSERT_FALSE(s.segment_points.empty());
  EXPECT_GE(s.segment_points.front().x(),
            39.9f);  // at display_from_cam, not at the segment's own frame
  EXPECT_EQ(s.points.size(), model);
  // A refused view adds nothing.
  TrackResult refused;
  m.AddView(2, refused, v.points, v.normals);
  EXPECT_EQ(m.model_points(), model);
  // The join: the segment moves into the model where main_from_display puts it (20 mm on from the
  // first view: new ground) and is no longer drawn apart; the joining view itself is the first
  // view's (its cells are taken already).
  TrackResult joined = Accepted(At(0), 1, true);
  joined.segment_joined = true;
  joined.main_from_display = At(-20);
  m.AddView(3, joined, v.points, v.normals);
  EXPECT_EQ(m.segment_points(), 0u);
  EXPECT_EQ(m.model_points(), 2 * model);
  EXPECT_EQ(m.views_in_model(), 2u);
  m.CopyTo(&s);
  EXPECT_TRUE(s.segment_points.empty());
  ASSERT_EQ(s.points.size(), m.model_points());
  EXPECT_GE(s.points.back().x(), 19.9f);
}

TEST(PreviewModel, UndoTakesTheViewsTailOutAndASnapshotCopiesAnew) {
  const PlaneView v;
  PreviewModel m(PreviewOptions());
  m.AddView(0, Accepted(At(0), 0, true), v.points, v.normals);
  const size_t first = m.model_points();
  m.AddView(1, Accepted(At(20), 0, true), v.points, v.normals);
  EXPECT_GT(m.model_points(), first);
  PreviewSnapshot s;
  m.CopyTo(&s);
  EXPECT_EQ(s.points.size(), m.model_points());
  m.Undo(1);
  EXPECT_EQ(m.model_points(), first);
  EXPECT_EQ(m.views_in_model(), 1u);
  m.CopyTo(&s);
  EXPECT_EQ(s.points.size(), first);
  // The undone view's cells are free again.
  m.AddView(2, Accepted(At(20), 0, true), v.points, v.normals);
  EXPECT_GT(m.model_points(), first);
  m.Reset();
  EXPECT_EQ(m.model_points(), 0u);
  m.CopyTo(&s);
  EXPECT_TRUE(s.points.empty());
}

TEST(PreviewModel, ModelAndSegmentShareThePointBudget) {
  const PlaneView v;
  PreviewModelOptions o = PreviewOptions();
  o.max_points = 500;
  PreviewModel m(o);
  m.AddView(0, Accepted(At(0), 0, true), v.points, v.normals);
  EXPECT_LE(m.model_points(), 500u);
  m.AddView(1, Accepted(At(3000), 1, false), v.points, v.normals);
  EXPECT_LE(m.model_points() + m.segment_points(), 500u);
  o.cell_mm = 0;
  EXPECT_THROW(PreviewModel{o}, std::invalid_argument);
}

}  // namespace
}  // namespace d3d
