#include "pipeline/unwrap/unwrap.h"

#include <gtest/gtest.h>

#include <climits>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <opencv2/imgproc.hpp>

#include "pipeline/unwrap/quality_map.h"
#include "pipeline/unwrap/synthetic_fringes.h"

namespace d3d {
namespace {

constexpr float kInvalid = std::numeric_limits<float>::quiet_NaN();

struct Eval {
  int64_t lit = 0;           // pixels with a phase (truth order ≥ 0)
  int64_t kept = 0;          // with an output order
  int64_t wrong = 0;         // kept with order ≠ truth
  int64_t inconsistent = 0;  // kept with order ≠ floor(Φ/2π) or |Φ − Φ_true| > π
  double KeptShare() const { return lit > 0 ? static_cast<double>(kept) / lit : 0.0; }
};

Eval Evaluate(const SyntheticScene& s, const UnwrapResult& r, const cv::Mat& only = cv::Mat()) {
  Eval e;
  for (int y = 0; y < s.phi.rows; ++y) {
    for (int x = 0; x < s.phi.cols; ++x) {
      if (!only.empty() && only.at<uint8_t>(y, x) == 0) continue;
      const int truth = s.order_true.at<int32_t>(y, x);
      if (truth >= 0) ++e.lit;
      const float Phi = r.Phi.at<float>(y, x);
      const int k = r.order.at<int32_t>(y, x);
      if (!std::isfinite(Phi)) {
        EXPECT_EQ(k, -1);
        continue;
      }
      ++e.kept;
      if (k != truth) ++e.wrong;
      if (k != static_cast<int>(std::floor(Phi / (2 * M_PI) + 1e-6)) ||
          std::fabs(Phi - s.Phi_true.at<float>(y, x)) > M_PI) {
        ++e.inconsistent;
      }
    }
  }
  return e;
}

// Prints the regions that matter (for failing tests).
void DumpRegions(const UnwrapResult& r) {
  const UnwrapStats& st = r.stats;
  std::printf("usable %lld valid %lld conflict %lld small %lld rejected %lld outside %lld\n",
              static_cast<long long>(st.pixels_usable), static_cast<long long>(st.pixels_valid),
              static_cast<long long>(st.pixels_conflict), static_cast<long long>(st.pixels_small),
              static_cast<long long>(st.pixels_rejected),
              static_cast<long long>(st.pixels_outside));
  for (size_t i = 0; i < r.regions.size(); ++i) {
    const RegionInfo& g = r.regions[i];
    if (g.pixels < 100) continue;
    std::printf(
        "region %zu: %d px, %s, K %d, hits %d/%d rival %d, bounded %d admitting %d, candidates "
        "%d\n",
        i, g.pixels, RegionAnchorName(g.anchor), g.offset, g.marker_hits, g.marker_predicted,
        g.marker_rival_hits, g.bounded_pixels, g.admitting_pixels, g.candidates);
  }
}

UnwrapResult RunAll(const SyntheticScene& s, const UnwrapOptions& opt = {}, bool use_marker = true,
                    bool use_bounds = true, const QualityOptions& qopt = {}) {
  cv::Mat q;
  EXPECT_TRUE(ComputeQualityMap(s.phi, s.modulation, s.valid, qopt, &q).ok());
  UnwrapResult r;
  const Status st =
      UnwrapPhase(s.phi, q, use_marker ? s.marker : cv::Mat(), use_bounds ? s.phase_min : cv::Mat(),
                  use_bounds ? s.phase_max : cv::Mat(), opt, &r);
  EXPECT_TRUE(st.ok()) << st.ToString();
  return r;
}

// Naive path-following unwrapping (Itoh along rows, then the first column), relative: compared up
// to the best single global offset. The reference for "naive unwrapping fails".
int64_t NaiveWrongPixels(const SyntheticScene& s) {
  const int h = s.phi.rows, w = s.phi.cols;
  cv::Mat k(h, w, CV_32SC1, cv::Scalar(0));
  auto step = [](float a, float b) { return b - a > M_PI ? -1 : (b - a < -M_PI ? 1 : 0); };
  for (int y = 0; y < h; ++y) {
    if (y > 0)
      k.at<int>(y, 0) =
          k.at<int>(y - 1, 0) + step(s.phi.at<float>(y - 1, 0), s.phi.at<float>(y, 0));
    for (int x = 1; x < w; ++x) {
      k.at<int>(y, x) =
          k.at<int>(y, x - 1) + step(s.phi.at<float>(y, x - 1), s.phi.at<float>(y, x));
    }
  }
  std::map<int, int64_t> diff;
  int64_t lit = 0;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (s.order_true.at<int32_t>(y, x) < 0) continue;
      ++diff[s.order_true.at<int32_t>(y, x) - k.at<int>(y, x)];
      ++lit;
    }
  }
  int64_t best = 0;
  for (const auto& [d, n] : diff) best = std::max(best, n);
  return lit - best;
}

SyntheticNoise Noise(uint64_t seed = 1) {
  SyntheticNoise n;
  n.seed = seed;
  return n;
}

// Two whole scenes composed: `from`'s pixels in `rect` replace those of *to (a depth map with a
// step would darken the rows beside it).
void CopyRect(const SyntheticScene& from, const cv::Rect& rect, SyntheticScene* to) {
  for (auto [dst, src] : {std::pair{&to->depth, &from.depth},
                          {&to->Phi_true, &from.Phi_true},
                          {&to->order_true, &from.order_true},
                          {&to->phi, &from.phi},
                          {&to->modulation, &from.modulation},
                          {&to->valid, &from.valid},
                          {&to->marker, &from.marker},
                          {&to->phase_min, &from.phase_min},
                          {&to->phase_max, &from.phase_max}}) {
    (*src)(rect).copyTo((*dst)(rect));
  }
}

// Depth at which the scene is shifted by `fringes` relative to depth z on the same pixel.
double DepthForShift(const SyntheticProbe& p, double z, double fringes) {
  // Φ ∝ −fp·b/Z: Δfringes = fp·b/T·(1/z − 1/z2).
  return 1.0 / (1.0 / z - fringes * p.period_px / (p.fp * p.baseline_mm));
}

TEST(Unwrap, TiltedPlaneAnchoredByMarker) {
  const SyntheticProbe probe;
  const SyntheticScene s = MakeFringeScene(PlaneDepth(probe, 50.0, 0.004, -0.003), probe, Noise());
  const UnwrapResult r = RunAll(s);
  const Eval e = Evaluate(s, r);
  EXPECT_EQ(e.wrong, 0);
  EXPECT_EQ(e.inconsistent, 0);
  EXPECT_GT(e.KeptShare(), 0.97);
  EXPECT_EQ(r.stats.regions_marker, 1);
  EXPECT_EQ(r.stats.pixels_valid, e.kept);
  EXPECT_EQ(r.stats.pixels_dropped, r.stats.pixels_discontinuity + r.stats.pixels_conflict +
                                        r.stats.pixels_small + r.stats.pixels_rejected +
                                        r.stats.pixels_outside + r.stats.pixels_neck);
}

// A fragment that lies inside a marker stripe (cut out of the surface around it) shows no stripe
// edge: its order cannot be verified by the marker, so it is dropped, never anchored.
TEST(Unwrap, FragmentInsideAStripeIsNotAnchoredByIt) {
  const SyntheticProbe probe;
  SyntheticScene s = MakeFringeScene(PlaneDepth(probe, 50.0, 0.004, -0.003), probe, Noise());
  int inside = 0;
  for (int y = 0; y < s.phi.rows; ++y)
    for (int x = 0; x < s.phi.cols; ++x) {
      const bool keep =
          s.order_true.at<int32_t>(y, x) == 14 && y >= 120 && y < 360;  // the order-14 stripe
      if (!keep) {
        s.valid.at<uint8_t>(y, x) = 0;
        s.phi.at<float>(y, x) = std::nanf("");
      }
      inside += keep;
    }
  ASSERT_GT(inside, 2000);
  const UnwrapResult r = RunAll(s);
  EXPECT_EQ(r.stats.pixels_valid, 0) << "a stripe fragment must not anchor itself";
  EXPECT_EQ(r.stats.regions_marker, 0);
  UnwrapOptions no_rule;
  no_rule.marker_max_stripe_share =
      1.0;  // without the rule the stripe alone "anchors" the fragment
  EXPECT_GT(RunAll(s, no_rule).stats.pixels_valid, 0);
  // The same fragment with a band of surface on both sides of the stripe is anchored.
  SyntheticScene wide = MakeFringeScene(PlaneDepth(probe, 50.0, 0.004, -0.003), probe, Noise());
  for (int y = 0; y < wide.phi.rows; ++y)
    for (int x = 0; x < wide.phi.cols; ++x) {
      const int k = wide.order_true.at<int32_t>(y, x);
      if (!(k >= 12 && k <= 16 && y >= 120 && y < 360)) {
        wide.valid.at<uint8_t>(y, x) = 0;
        wide.phi.at<float>(y, x) = std::nanf("");
      }
    }
  const UnwrapResult w = RunAll(wide);
  EXPECT_EQ(Evaluate(wide, w).wrong, 0);
  EXPECT_EQ(w.stats.regions_marker, 1);
}

TEST(Unwrap, SphereCap) {
  const SyntheticProbe probe;
  const SyntheticScene s =
      MakeFringeScene(SphereDepth(probe, 300, 250, 6.0, 47.0), probe, Noise(2));
  const UnwrapResult r = RunAll(s);
  const Eval e = Evaluate(s, r);
  EXPECT_EQ(e.wrong, 0);
  EXPECT_EQ(e.inconsistent, 0);
  EXPECT_GT(e.KeptShare(), 0.9);
}

TEST(Unwrap, NonIntegerStepWhereNaiveUnwrappingFails) {
  const SyntheticProbe probe;
  cv::Mat depth = PlaneDepth(probe, 48.0, 0.0, 0.0);
  const double z2 = DepthForShift(probe, 48.0, 2.4);  // the right half: 2.4 fringes further
  depth(cv::Rect(320, 0, 320, 480)).setTo(z2);
  const SyntheticScene s = MakeFringeScene(depth, probe, Noise(3));
  // Both halves see a marker stripe.
  cv::Mat left = cv::Mat::zeros(480, 640, CV_8UC1), right = left.clone();
  left(cv::Rect(0, 0, 320, 480)).setTo(255);
  right(cv::Rect(320, 0, 320, 480)).setTo(255);
  ASSERT_GT(cv::countNonZero(s.marker & left), 1000);
  ASSERT_GT(cv::countNonZero(s.marker & right), 1000);

  const int64_t naive_wrong = NaiveWrongPixels(s);
  EXPECT_GT(naive_wrong, 100000) << "the naive unwrapping should be off by 2 orders on one half";

  const UnwrapResult r = RunAll(s);
  const Eval e = Evaluate(s, r);
  EXPECT_EQ(e.wrong, 0);
  EXPECT_EQ(e.inconsistent, 0);
  EXPECT_GT(e.KeptShare(), 0.97);
  EXPECT_EQ(r.stats.regions_marker, 2);
}

TEST(Unwrap, HiddenIntegerStepIsRejectedNotGuessed) {
  // 3.0 fringes: the wrapped phase shows no trace of the step, so both halves grow into one region;
  // their marker stripes vote for offsets 3 apart and the region is rejected.
  const SyntheticProbe probe;
  cv::Mat depth = PlaneDepth(probe, 48.0, 0.0, 0.0);
  depth(cv::Rect(320, 0, 320, 480)).setTo(DepthForShift(probe, 48.0, 3.0));
  SyntheticScene s = MakeFringeScene(depth, probe, Noise(4));
  s.modulation.setTo(40.0f);  // no dark edge at the step either
  const UnwrapResult r = RunAll(s);
  const Eval e = Evaluate(s, r);
  EXPECT_EQ(e.wrong, 0);
  EXPECT_EQ(r.stats.regions_marker, 0);
  EXPECT_GE(r.stats.regions_rejected, 1);
}

TEST(Unwrap, AlbedoEdgeWithHiddenNearIntegerStepIsNotCrossed) {
  // Tooth (top, B 40) over gingiva (bottom, B 18) 0.93 fringes further: along y the step shows as a
  // small W(Δφ) ≈ −0.44 rad that region growing would cross, giving the gingiva an order off by
  // one. Only the tooth's stripe is detected (the gingiva's stripe lies where its orders are).
  const SyntheticProbe probe;
  cv::Mat depth = PlaneDepth(probe, 48.0, 0.0, 0.0);
  depth(cv::Rect(0, 240, 640, 240)).setTo(DepthForShift(probe, 48.0, 0.93));
  SyntheticScene s = MakeFringeScene(depth, probe, Noise(11));
  s.modulation(cv::Rect(0, 0, 640, 240)).setTo(40.0f);    // no dark edge at the step (the optics
  s.modulation(cv::Rect(0, 240, 640, 240)).setTo(18.0f);  // blur it away), only the albedo edge
  s.marker(cv::Rect(0, 240, 640, 240)).setTo(0);
  cv::Mat top = cv::Mat::zeros(480, 640, CV_8UC1), bottom = top.clone();
  top(cv::Rect(0, 0, 640, 240)).setTo(255);
  bottom(cv::Rect(0, 240, 640, 240)).setTo(255);
  ASSERT_GT(cv::countNonZero(s.marker & top), 1000);
  const UnwrapResult r = RunAll(s);
  const Eval e = Evaluate(s, r);
  EXPECT_EQ(e.wrong, 0);
  EXPECT_EQ(e.inconsistent, 0);
  EXPECT_GT(Evaluate(s, r, top).KeptShare(), 0.95);
  if (HasFailure()) DumpRegions(r);
  // Without the modulation-edge cut the two halves form one region: either it is rejected (its
  // stripe density is too low) or the gingiva gets a wrong order.
  QualityOptions no_edge;
  no_edge.modulation_edge_ratio = 0;
  const UnwrapResult r0 = RunAll(s, {}, true, true, no_edge);
  const Eval e0 = Evaluate(s, r0);
  EXPECT_TRUE(e0.wrong > 0 || Evaluate(s, r0, top).KeptShare() < 0.5);
}

TEST(Unwrap, NarrowLeakIntoAnUnverifiedPartIsPruned) {
  // A plane with a stripe (top) and, 1.0 fringe further, a patch without any stripe (bottom, where
  // neither its true orders nor those one off are stripe orders), joined only through a 2 px gap in
  // an invalid band. The integer step leaves no trace in φ, so the region grows through the gap and
  // the patch would inherit the top's offset, one order off. Neck pruning drops it.
  const SyntheticProbe probe;
  // Two whole planes composed at row 245 (a depth map with the step would darken the rows beside
  // it).
  SyntheticScene s = MakeFringeScene(PlaneDepth(probe, 48.0, 0.0, 0.0), probe, Noise(12));
  const SyntheticScene far = MakeFringeScene(
      PlaneDepth(probe, DepthForShift(probe, 48.0, 1.0), 0.0, 0.0), probe, Noise(13));
  const cv::Rect lower(0, 245, 640, 235);
  CopyRect(far, lower, &s);
  // A 150 px wide window of the bottom whose orders k and k − 1 avoid every stripe order.
  int x0 = -1;
  for (int x = 0; x + 150 <= 640 && x0 < 0; x += 5) {
    bool clear = true;
    for (int xx = x; xx < x + 150 && clear; ++xx) {
      const int k = s.order_true.at<int32_t>(300, xx);
      for (int km = probe.marker_first_order; km <= 40; km += probe.marker_spacing_orders) {
        clear = clear && k != km && k - 1 != km;
      }
    }
    if (clear) x0 = x;
  }
  ASSERT_GE(x0, 0);
  cv::Mat invalid = cv::Mat::zeros(480, 640, CV_8UC1);
  invalid(cv::Rect(0, 240, 640, 240)).setTo(255);
  invalid(cv::Rect(x0, 250, 150, 230)).setTo(0);    // the patch
  invalid(cv::Rect(x0 + 74, 240, 2, 10)).setTo(0);  // the 2 px gap
  s.phi.setTo(kInvalid, invalid);
  s.valid.setTo(0, invalid);
  s.marker.setTo(0, invalid);
  cv::Mat patch = cv::Mat::zeros(480, 640, CV_8UC1), top = patch.clone();
  patch(cv::Rect(x0, 250, 150, 230)).setTo(255);
  top(cv::Rect(0, 0, 640, 240)).setTo(255);
  ASSERT_GT(cv::countNonZero(s.marker & top), 1000);

  UnwrapOptions no_prune;
  no_prune.neck_radius = 0;
  const Eval e0 = Evaluate(s, RunAll(s, no_prune), patch);
  EXPECT_GT(e0.wrong, 10000) << "without pruning the patch should inherit a wrong order";

  const UnwrapResult r = RunAll(s);
  const Eval e = Evaluate(s, r);
  EXPECT_EQ(e.wrong, 0);
  EXPECT_EQ(Evaluate(s, r, patch).kept, 0);
  EXPECT_GT(Evaluate(s, r, top).KeptShare(), 0.95);
  EXPECT_GT(r.stats.pixels_neck, 10000);
  if (HasFailure()) DumpRegions(r);
}

// A plane at 57.9 mm (just inside the 42–58 mm volume) with, below it, a patch 1.0 fringe further
// (61.8 mm, beyond the far limit) whose orders are 11–14, `rows` rows high: it shows stripe 14,
// while with the plane's offset (one order less) it would show none. The integer step leaves no
// trace in φ, so both grow into one region.
struct HiddenStepScene {
  SyntheticScene s;
  cv::Mat patch, top;  // CV_8U masks
};
HiddenStepScene MakeHiddenStepIntoAFarPatch(const SyntheticProbe& probe, int rows) {
  HiddenStepScene h;
  SyntheticScene& s = h.s;
  const double z_far = DepthForShift(probe, 57.9, 1.0);
  EXPECT_GT(z_far, probe.z_max + 3.0);
  s = MakeFringeScene(PlaneDepth(probe, 57.9, 0.0, 0.0), probe, Noise(21));
  const SyntheticScene far = MakeFringeScene(PlaneDepth(probe, z_far, 0.0, 0.0), probe, Noise(22));
  const cv::Rect lower(0, 240, 640, 240);
  CopyRect(far, lower, &s);
  // The patch: the lower half's columns with orders 11..14; the rest of the lower half is unlit.
  h.patch = cv::Mat::zeros(480, 640, CV_8UC1);
  h.top = h.patch.clone();
  h.top(cv::Rect(0, 0, 640, 240)).setTo(255);
  for (int x = 0; x < 640; ++x) {
    const int k = s.order_true.at<int32_t>(300, x);
    if (k >= 11 && k <= 14) h.patch(cv::Rect(x, 240, 1, rows)).setTo(255);
  }
  const cv::Mat unlit = ~(h.patch | h.top);
  s.phi.setTo(kInvalid, unlit);
  s.valid.setTo(0, unlit);
  s.marker.setTo(0, unlit);
  s.order_true.setTo(-1, unlit);
  return h;
}

// The patch's stripe order lies one order beyond its admissible ones; only the stripe window
// widened on the far side (marker_margin_above) lets it vote, as a rival, and the region is
// rejected. Without the margin the region took the plane's K, and the patch, one order nearer,
// lies inside the volume and is kept a whole order off (real arch seed 2, burst 713).
TEST(Unwrap, HiddenStepIntoAPartBeyondTheVolumeIsRejected) {
  const SyntheticProbe probe;
  const HiddenStepScene h = MakeHiddenStepIntoAFarPatch(probe, 240);
  ASSERT_GT(cv::countNonZero(h.patch), 15000);
  ASSERT_GT(cv::countNonZero(h.s.marker & h.patch), 3000) << "the patch shows its stripe";

  UnwrapOptions no_margin;
  no_margin.marker_margin_above = 0;
  const Eval e0 = Evaluate(h.s, RunAll(h.s, no_margin), h.patch);
  EXPECT_GT(e0.wrong, 10000) << "without the margin the patch should be kept one order off";

  const UnwrapResult r = RunAll(h.s);
  const Eval e = Evaluate(h.s, r);
  EXPECT_EQ(e.wrong, 0);
  EXPECT_EQ(Evaluate(h.s, r, h.patch).kept, 0);
  EXPECT_GE(r.stats.regions_rejected, 1);
  if (HasFailure()) DumpRegions(r);
}

// The same with a patch 40 rows high: over the whole region, its K also predicts a stripe on the
// plane's pixels one order short of the plane's stripes, where nothing is detected, so its
// density stays under marker_rival_density. In the patch's own tiles it is dense: the tile-local
// rival test rejects the region (real arch seed 2, burst 778).
TEST(Unwrap, ASmallPartBeyondAHiddenStepIsCaughtInItsTiles) {
  const SyntheticProbe probe;
  const HiddenStepScene h = MakeHiddenStepIntoAFarPatch(probe, 40);
  ASSERT_GT(cv::countNonZero(h.s.marker & h.patch), 500) << "the patch shows its stripe";

  UnwrapOptions no_tiles;
  no_tiles.marker_tile_rival_votes = 0;
  const UnwrapResult r0 = RunAll(h.s, no_tiles);
  EXPECT_GT(Evaluate(h.s, r0, h.patch).wrong, 2000)
      << "the region-wide rival test alone should miss it";

  const UnwrapResult r = RunAll(h.s);
  EXPECT_EQ(Evaluate(h.s, r).wrong, 0);
  EXPECT_EQ(Evaluate(h.s, r, h.patch).kept, 0);
  if (HasFailure()) DumpRegions(r);
}

// The stripe window is not widened on the near side: there false detections would vote (real arch
// seed 2, burst 799: 10 hits of 16 predicted for K − 5 rejected a whole tooth).
TEST(Unwrap, FalseStripeHitsJustNearerThanTheVolumeDoNotVote) {
  const SyntheticProbe probe;
  // A plane 1 mm behind the near limit (0.5 orders): the lowest order its pixels admit is their
  // own.
  SyntheticScene s =
      MakeFringeScene(PlaneDepth(probe, probe.z_min + 1.0, 0.0, 0.0), probe, Noise(23));
  // The columns one order past a stripe order are unlit except a 4-row bridge joining the parts;
  // false detections over the bridge's stripe core in one of them would put some 60 hits on K − 1
  // at a high density (the bridge is all K − 1 predicts), were the window widened below.
  const auto past_stripe = [&](int k) {
    return (k - probe.marker_first_order) % probe.marker_spacing_orders == 1;
  };
  cv::Mat cut = cv::Mat::zeros(480, 640, CV_8UC1);
  for (int x = 0; x < 640; ++x)
    if (past_stripe(s.order_true.at<int32_t>(300, x))) cut(cv::Rect(x, 0, 1, 480)).setTo(255);
  cut(cv::Rect(0, 200, 640, 4)).setTo(0);
  ASSERT_GT(cv::countNonZero(cut), 10000);
  s.phi.setTo(kInvalid, cut);
  s.valid.setTo(0, cut);
  s.marker.setTo(0, cut);
  s.order_true.setTo(-1, cut);
  s.marker(cv::Rect(0, 200, 640, 4)).setTo(0);
  int placed = 0;
  for (int y = 200; y < 204; ++y)
    for (int x = 0; x < 640; ++x) {
      const float phi = s.phi.at<float>(y, x);
      if (s.order_true.at<int32_t>(y, x) == 15 && phi > 1.0f && phi < 5.2f) {
        s.marker.at<uint8_t>(y, x) = 255;
        ++placed;
      }
    }
  ASSERT_GT(placed, 40);
  const UnwrapResult r = RunAll(s);
  EXPECT_EQ(Evaluate(s, r).wrong, 0);
  EXPECT_GT(Evaluate(s, r).KeptShare(), 0.95);
  if (HasFailure()) DumpRegions(r);
  // Widened below, the window attributes them to stripe 14, a rival that rejects the plane.
  UnwrapOptions near_margin;
  near_margin.marker_margin_below = 1;
  const UnwrapResult r1 = RunAll(s, near_margin);
  EXPECT_LT(Evaluate(s, r1).KeptShare(), 0.5);
  if (HasFailure()) DumpRegions(r1);
}

TEST(Unwrap, SeparatedTeethOnlySomeWithMarker) {
  const SyntheticProbe probe;
  const cv::Mat depth = TeethDepth(probe, 4, 12.0, 7);
  const SyntheticScene s = MakeFringeScene(depth, probe, Noise(5));
  const UnwrapResult r = RunAll(s);
  const Eval e = Evaluate(s, r);
  EXPECT_EQ(e.wrong, 0);
  EXPECT_EQ(e.inconsistent, 0);
  EXPECT_GE(r.stats.regions_marker, 2);
  // Every anchored region is right; a region that saw no marker is either anchored by depth or
  // dropped. Blobs crossed by a stripe are kept almost entirely.
  for (const RegionInfo& info : r.regions) {
    if (info.anchor == RegionAnchor::kMarker) {
      EXPECT_GE(info.marker_hits, UnwrapOptions{}.min_marker_votes);
    }
  }
  EXPECT_GT(e.KeptShare(), 0.5);
  // Region-relative orders: every grown pixel has one, and an anchored pixel's order is it plus
  // its region's offset; the dropped regions keep theirs (for model-guided anchoring).
  int64_t relative_dropped = 0;
  for (int y = 0; y < r.region.rows; ++y)
    for (int x = 0; x < r.region.cols; ++x) {
      const int rid = r.region.at<int32_t>(y, x), rel = r.relative.at<int32_t>(y, x),
                k = r.order.at<int32_t>(y, x);
      ASSERT_EQ(rid < 0, rel == INT32_MIN) << x << "," << y;
      if (k >= 0) {
        ASSERT_EQ(k, rel + r.regions[static_cast<size_t>(rid)].offset) << x << "," << y;
      }
      relative_dropped += rid >= 0 && k < 0;
    }
  EXPECT_GT(relative_dropped, 0);
  if (HasFailure()) DumpRegions(r);
}

TEST(Unwrap, RegionsWithoutMarkerAreDroppedUnderTheWideVolume) {
  // 42–58 mm admit ≈ 6 orders per pixel: without a marker no region is unique, all are dropped.
  const SyntheticProbe probe;
  const SyntheticScene s = MakeFringeScene(TeethDepth(probe, 3, 15.0, 8), probe, Noise(6));
  const UnwrapResult r = RunAll(s, {}, /*use_marker=*/false);
  const Eval e = Evaluate(s, r);
  EXPECT_EQ(e.kept, 0);
  EXPECT_EQ(r.stats.regions_marker + r.stats.regions_depth, 0);
  EXPECT_GE(r.stats.regions_rejected, 3);
}

TEST(Unwrap, DepthConstraintAnchorsWhenTheWindowIsNarrow) {
  // A volume of ±0.45 fringes around the truth leaves one admissible offset per region.
  const SyntheticProbe probe;
  SyntheticScene s = MakeFringeScene(TeethDepth(probe, 4, 12.0, 9), probe, Noise(7));
  for (int y = 0; y < s.phi.rows; ++y) {
    for (int x = 0; x < s.phi.cols; ++x) {
      const float t = s.Phi_true.at<float>(y, x);
      s.phase_min.at<float>(y, x) =
          std::isfinite(t) ? t - 0.45f * 2 * static_cast<float>(M_PI) : kInvalid;
      s.phase_max.at<float>(y, x) =
          std::isfinite(t) ? t + 0.45f * 2 * static_cast<float>(M_PI) : kInvalid;
    }
  }
  const UnwrapResult r = RunAll(s, {}, /*use_marker=*/false);
  const Eval e = Evaluate(s, r);
  EXPECT_EQ(e.wrong, 0);
  EXPECT_GE(r.stats.regions_depth, 3);
  EXPECT_GT(e.KeptShare(), 0.8);
  if (HasFailure()) DumpRegions(r);
}

TEST(Unwrap, NoiseHolesAndBlurredMarker) {
  const SyntheticProbe probe;
  cv::Mat holes = cv::Mat::zeros(480, 640, CV_8UC1);
  cv::RNG rng(11);
  for (int i = 0; i < 25; ++i) {
    cv::circle(holes, {rng.uniform(0, 640), rng.uniform(0, 480)}, rng.uniform(3, 15), 255,
               cv::FILLED);
  }
  SyntheticNoise noise = Noise(8);
  noise.intensity_sigma = 5.0;  // σ_φ ≈ 0.09 rad at B = 40, ≈ 0.35 rad at B = 10
  noise.marker_false_rate = 0.01;
  SyntheticScene s = MakeFringeScene(SphereDepth(probe, 320, 240, 7.0, 46.0), probe, noise, holes);
  // The marker detection bleeds 2 px past the stripe edges.
  cv::dilate(s.marker, s.marker, cv::getStructuringElement(cv::MORPH_RECT, {5, 1}));
  const UnwrapResult r = RunAll(s);
  const Eval e = Evaluate(s, r);
  EXPECT_EQ(e.wrong, 0);
  EXPECT_EQ(e.inconsistent, 0);
  EXPECT_GT(e.KeptShare(), 0.8);
  EXPECT_GE(r.stats.regions_marker, 1);
  if (HasFailure()) DumpRegions(r);
}

TEST(Unwrap, OutsideTheVolumeIsDropped) {
  // A plane from 55 to 61 mm: the part beyond 58 mm is outside the volume.
  const SyntheticProbe probe;
  const SyntheticScene s = MakeFringeScene(PlaneDepth(probe, 58.0, 0.0, 0.0125), probe, Noise(9));
  UnwrapOptions opt;
  opt.marker_depth_fraction = 0.3;
  UnwrapResult r = RunAll(s, opt);
  Eval e = Evaluate(s, r);
  EXPECT_EQ(e.wrong, 0);
  EXPECT_GT(r.stats.pixels_outside, 50000);
  for (int y = 0; y < 480; ++y) {
    const float z = s.depth.at<float>(y, 320);
    if (z > 58.3f) {
      EXPECT_FALSE(std::isfinite(r.Phi.at<float>(y, 320))) << y;
    }
    if (z < 57.7f) {
      EXPECT_TRUE(std::isfinite(r.Phi.at<float>(y, 320))) << y;
    }
  }
  opt.drop_outside_volume = false;
  r = RunAll(s, opt);
  e = Evaluate(s, r);
  EXPECT_EQ(e.wrong, 0);
  EXPECT_EQ(r.stats.pixels_outside, 0);
  EXPECT_GT(e.KeptShare(), 0.97);
}

TEST(Unwrap, AMarkedRegionReachingBeyondTheVolumeKeepsItsPartInside) {
  // A plane from 54 to 60 mm (gum behind the crowns): a third of it lies beyond 58 mm and does not
  // admit the marker's K. With the default majority rule the region keeps its marker order and only
  // the part outside the volume is dropped; requiring 80 % (the old default) lost it whole.
  const SyntheticProbe probe;
  const SyntheticScene s = MakeFringeScene(PlaneDepth(probe, 57.0, 0.0, 0.0125), probe, Noise(12));
  const cv::Mat inside = s.depth < 57.7f;  // CV_8U 255 inside the volume (less a margin)
  UnwrapResult r = RunAll(s);
  Eval e = Evaluate(s, r);
  EXPECT_EQ(e.wrong, 0);
  EXPECT_EQ(e.inconsistent, 0);
  EXPECT_GT(r.stats.pixels_outside, 50000);
  EXPECT_GT(Evaluate(s, r, inside).KeptShare(), 0.97);
  UnwrapOptions strict;
  strict.marker_depth_fraction = 0.8;
  r = RunAll(s, strict);
  EXPECT_LT(Evaluate(s, r, inside).KeptShare(), 0.05);
}

TEST(Unwrap, OneStripeWithoutBounds) {
  // marker_spacing_orders = 0: a single stripe identifies its order without any depth bound.
  SyntheticProbe probe;
  probe.marker_first_order = 19;
  probe.marker_spacing_orders = 0;
  const SyntheticScene s = MakeFringeScene(PlaneDepth(probe, 50.0, 0.002, 0.0), probe, Noise(10));
  UnwrapOptions opt;
  opt.marker_first_order = 19;
  opt.marker_spacing_orders = 0;
  const UnwrapResult r = RunAll(s, opt, true, /*use_bounds=*/false);
  const Eval e = Evaluate(s, r);
  EXPECT_EQ(e.wrong, 0);
  EXPECT_GT(e.KeptShare(), 0.97);
  // With several stripes and no bounds, a stripe's order is ambiguous: nothing is anchored.
  const UnwrapResult r2 = RunAll(s, {}, true, false);
  EXPECT_EQ(Evaluate(s, r2).kept, 0);
}

TEST(Unwrap, ReusedUnwrapperMatchesFreshRuns) {
  const SyntheticProbe p1;
  const SyntheticProbe p2 = SyntheticProbe::ForSize(320, 200);
  const SyntheticScene a = MakeFringeScene(TeethDepth(p1, 4, 12.0, 1), p1, Noise(1));
  const SyntheticScene b = MakeFringeScene(PlaneDepth(p2, 50.0, 0.0, 0.0), p2, Noise(2));
  Unwrapper unwrapper;
  for (const SyntheticScene* s : {&a, &b, &a}) {
    cv::Mat q;
    ASSERT_TRUE(ComputeQualityMap(s->phi, s->modulation, s->valid, {}, &q).ok());
    UnwrapResult reused, fresh;
    ASSERT_TRUE(unwrapper.Run(s->phi, q, s->marker, s->phase_min, s->phase_max, &reused).ok());
    ASSERT_TRUE(UnwrapPhase(s->phi, q, s->marker, s->phase_min, s->phase_max, {}, &fresh).ok());
    EXPECT_EQ(cv::norm(reused.order, fresh.order, cv::NORM_INF), 0.0);
    EXPECT_EQ(cv::norm(reused.region, fresh.region, cv::NORM_INF), 0.0);
    EXPECT_EQ(reused.stats.pixels_valid, fresh.stats.pixels_valid);
  }
}

TEST(Unwrap, AllInvalidIsOkAndEmpty) {
  cv::Mat phi(30, 40, CV_32FC1, cv::Scalar(kInvalid));
  cv::Mat q(30, 40, CV_32FC1, cv::Scalar(0.0f));
  UnwrapResult r;
  ASSERT_TRUE(UnwrapPhase(phi, q, cv::Mat(), cv::Mat(), cv::Mat(), {}, &r).ok());
  EXPECT_EQ(r.stats.pixels_valid, 0);
  EXPECT_EQ(r.stats.regions_total, 0);
  EXPECT_EQ(cv::countNonZero(r.order != -1), 0);
  EXPECT_EQ(cv::countNonZero(r.region != -1), 0);
  // Good quality but NaN phase, and NaN quality: still nothing, no crash.
  q.setTo(1.0f);
  ASSERT_TRUE(UnwrapPhase(phi, q, cv::Mat(), cv::Mat(), cv::Mat(), {}, &r).ok());
  EXPECT_EQ(r.stats.pixels_usable, 0);
  cv::Mat phi0(30, 40, CV_32FC1, cv::Scalar(1.0f));
  q.setTo(kInvalid);
  ASSERT_TRUE(UnwrapPhase(phi0, q, cv::Mat(), cv::Mat(), cv::Mat(), {}, &r).ok());
  EXPECT_EQ(r.stats.pixels_usable, 0);
}

TEST(Unwrap, BadInputs) {
  const cv::Mat phi(20, 30, CV_32FC1, cv::Scalar(1.0f));
  const cv::Mat q(20, 30, CV_32FC1, cv::Scalar(1.0f));
  const cv::Mat none;
  UnwrapResult r;
  auto code = [&](const Status& s) { return s.code(); };
  const StatusCode bad = StatusCode::kInvalidArgument;
  EXPECT_EQ(code(UnwrapPhase(none, q, none, none, none, {}, &r)), bad);
  EXPECT_EQ(code(UnwrapPhase(phi, none, none, none, none, {}, &r)), bad);
  EXPECT_EQ(code(UnwrapPhase(phi, cv::Mat(20, 31, CV_32FC1), none, none, none, {}, &r)), bad);
  EXPECT_EQ(code(UnwrapPhase(phi, cv::Mat(20, 30, CV_64FC1), none, none, none, {}, &r)), bad);
  EXPECT_EQ(code(UnwrapPhase(cv::Mat(20, 30, CV_8UC1), q, none, none, none, {}, &r)), bad);
  EXPECT_EQ(code(UnwrapPhase(phi, q, cv::Mat(20, 30, CV_32FC1), none, none, {}, &r)), bad);
  EXPECT_EQ(code(UnwrapPhase(phi, q, cv::Mat(21, 30, CV_8UC1), none, none, {}, &r)), bad);
  EXPECT_EQ(code(UnwrapPhase(phi, q, none, phi.clone(), none, {}, &r)), bad);
  EXPECT_EQ(code(UnwrapPhase(phi, q, none, phi.clone(), cv::Mat(20, 29, CV_32FC1), {}, &r)), bad);
  EXPECT_EQ(code(UnwrapPhase(phi, q, none, none, none, {}, nullptr)), bad);
  UnwrapOptions opt;
  opt.max_jump = 4.0;
  EXPECT_EQ(code(UnwrapPhase(phi, q, none, none, none, opt, &r)), bad);
  EXPECT_THROW(Unwrapper{opt}, std::invalid_argument);
  opt = {};
  opt.quality_levels = 1;
  EXPECT_THROW(opt.Check(), std::invalid_argument);
  opt = {};
  opt.marker_density = 0.0;
  EXPECT_THROW(opt.Check(), std::invalid_argument);
  EXPECT_NO_THROW(UnwrapOptions{}.Check());
  // Output aliasing an input.
  UnwrapResult alias;
  alias.Phi = phi;
  EXPECT_EQ(code(UnwrapPhase(phi, q, none, none, none, {}, &alias)), bad);
  // NaN and reversed bounds are "unknown", not errors.
  cv::Mat pmin(20, 30, CV_32FC1, cv::Scalar(kInvalid)), pmax(20, 30, CV_32FC1, cv::Scalar(-5.0f));
  EXPECT_TRUE(UnwrapPhase(phi, q, none, pmin, pmax, {}, &r).ok());
  pmin.setTo(10.0f);
  EXPECT_TRUE(UnwrapPhase(phi, q, none, pmin, pmax, {}, &r).ok());
  EXPECT_EQ(r.stats.pixels_valid, 0);
}

TEST(Unwrap, ExtremeValuesDoNotCrash) {
  // Huge bounds are clamped; infinities are unknown; phases out of [0, 2π) are reduced.
  const SyntheticProbe probe = SyntheticProbe::ForSize(64, 48);
  SyntheticScene s = MakeFringeScene(PlaneDepth(probe, 50.0, 0.0, 0.0), probe, Noise(12));
  s.phase_min.setTo(-1e30f);
  s.phase_max.setTo(1e30f);
  s.phase_min.at<float>(3, 3) = -std::numeric_limits<float>::infinity();
  s.phi.at<float>(5, 5) = 1e6f;
  s.phi.at<float>(6, 6) = -7.0f;
  cv::Mat q;
  ASSERT_TRUE(ComputeQualityMap(s.phi, s.modulation, s.valid, {}, &q).ok());
  UnwrapResult r;
  ASSERT_TRUE(UnwrapPhase(s.phi, q, s.marker, s.phase_min, s.phase_max, {}, &r).ok());
  EXPECT_EQ(r.stats.pixels_valid, cv::countNonZero(r.order != -1));
}

}  // namespace
}  // namespace d3d
