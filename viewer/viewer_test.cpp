// The preview draws a picture: a synthetic model (a hemisphere of points) rendered offscreen
// (EGL surfaceless) must show the model's shading, the frustum and the status panel. Skips with a
// message when this machine has no EGL/OpenGL.
#include "viewer/viewer.h"

#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgproc.hpp>

namespace d3d {
namespace {

PreviewSnapshot Hemisphere() {
  PreviewSnapshot s;
  for (int i = 0; i < 60; ++i)
    for (int j = 0; j < 120; ++j) {
      const float th = static_cast<float>(i) / 60 * 1.5f,
                  ph = static_cast<float>(j) / 120 * 6.2832f;
      const Eigen::Vector3f n(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph),
                              -std::cos(th));
      s.points.push_back(Eigen::Vector3f(0, 0, 50) + 5.0f * n);
      s.normals.push_back(n);
    }
  for (int i = 0; i < 200; ++i)
    s.view_points.push_back(Eigen::Vector3f(0.05f * static_cast<float>(i) - 5, 0, 45));
  s.view_accepted = true;
  s.have_pose = true;
  s.cue = PreviewCue::kTracking;
  s.model_area_mm2 = 157;
  return s;
}

// A 320 × 240 offscreen viewer (status not ok: this machine has no EGL/OpenGL).
Status OffscreenViewer(std::unique_ptr<Viewer>* v) {
  ViewerOptions o;
  o.headless = true;
  o.width = 320;
  o.height = 240;
  return Viewer::Create(o, v);
}

TEST(Viewer, OffscreenPictureShowsTheModelAndThePanel) {
  std::unique_ptr<Viewer> v;
  const Status s = OffscreenViewer(&v);
  if (!s.ok()) GTEST_SKIP() << "no offscreen OpenGL here: " << s.ToString();
  const PreviewSnapshot snap = Hemisphere();
  PreviewStatus st;
  st.bursts_received = 10;
  cv::Mat empty, full;
  ASSERT_TRUE(v->Render(nullptr, st, 20, &empty));
  ASSERT_TRUE(v->Render(&snap, st, 20, &full));
  ASSERT_EQ(full.size(), cv::Size(320, 240));
  // The model is drawn in the middle of the picture: bright, varied pixels there.
  cv::Mat grey;
  cv::cvtColor(full, grey, cv::COLOR_BGR2GRAY);
  const cv::Mat centre = grey(cv::Rect(110, 80, 100, 100));
  cv::Scalar mean, sd;
  cv::meanStdDev(centre, mean, sd);
  EXPECT_GT(mean[0], 80) << "the model is not drawn";
  EXPECT_GT(sd[0], 5) << "no shading";
  cv::Mat ecentre;
  cv::cvtColor(empty, ecentre, cv::COLOR_BGR2GRAY);
  EXPECT_LT(cv::mean(ecentre(cv::Rect(110, 80, 100, 100)))[0], 60)
      << "an empty preview must stay dark";
  // The status panel: the tracking colour (green) in the top-left box.
  const cv::Vec3b box = full.at<cv::Vec3b>(20, 200);
  EXPECT_GT(box[1], 150);
  EXPECT_LT(box[2], 100);
}

TEST(Viewer, ASegmentApartIsDrawnInTheNewSegmentColour) {
  std::unique_ptr<Viewer> v;
  const Status s = OffscreenViewer(&v);
  if (!s.ok()) GTEST_SKIP() << "no offscreen OpenGL here: " << s.ToString();
  PreviewSnapshot snap = Hemisphere();
  snap.segment_points.swap(snap.points);  // the same hemisphere, as a segment apart
  snap.segment_normals.swap(snap.normals);
  snap.view_points.clear();
  snap.cue = PreviewCue::kNewSegment;
  cv::Mat picture;
  ASSERT_TRUE(v->Render(&snap, PreviewStatus{}, 20, &picture));
  // Blue, not the model's ivory: B high, R low in the middle of the picture.
  const cv::Scalar mean = cv::mean(picture(cv::Rect(110, 80, 100, 100)));
  EXPECT_GT(mean[0], 60) << "the segment is not drawn";
  EXPECT_LT(mean[2], 0.5 * mean[0]) << "the segment is not blue";
}

TEST(Viewer, AFrameThatWouldShowTheSamePictureIsNotDrawnAgain) {
  std::unique_ptr<Viewer> v;
  const Status s = OffscreenViewer(&v);
  if (!s.ok()) GTEST_SKIP() << "no offscreen OpenGL here: " << s.ToString();
  PreviewSnapshot snap = Hemisphere();
  snap.last_burst_seq = 7;
  PreviewStatus st;
  st.bursts_received = 10;
  ASSERT_TRUE(v->Render(&snap, st, 20));
  EXPECT_EQ(v->frames_drawn(), 1);
  // The same snapshot and counters: the picture on screen is current.
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(v->Render(&snap, st, 20));
  EXPECT_EQ(v->frames_drawn(), 1);
  // A new view, a change of cue, a picture asked for: drawn.
  snap.last_burst_seq = 8;
  ASSERT_TRUE(v->Render(&snap, st, 20));
  EXPECT_EQ(v->frames_drawn(), 2);
  st.override_cue = true;
  st.cue_override = PreviewCue::kPaused;
  ASSERT_TRUE(v->Render(&snap, st, 20));
  EXPECT_EQ(v->frames_drawn(), 3);
  cv::Mat picture;
  ASSERT_TRUE(v->Render(&snap, st, 20, &picture));
  EXPECT_EQ(v->frames_drawn(), 4);
  EXPECT_FALSE(picture.empty());
}

}  // namespace
}  // namespace d3d
