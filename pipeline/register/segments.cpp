#include "pipeline/register/segments.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <utility>

namespace d3d {

void SegmentOptions::Check() const {
  D3D_CHECK_MSG(after_views >= 0 && max_segments >= 1 && join_every >= 1 &&
                    join_feature_keyframes >= 0 && join_starts_at_end >= 0 &&
                    join_start_gate_mm > 0,
                "SegmentOptions: after_views >= 0 (0 = off), max_segments >= 1, join_every >= 1, "
                "join_feature_keyframes >= 0, join_starts_at_end >= 0, join_start_gate_mm > 0");
  join.Check();
  join_fine_fpfh.Check();
}

Segments::Segments(const SegmentOptions& options, Odometry* odometry, KeyframeGraph* keyframes,
                   bool by_features)
    : o_(options), odometry_(*odometry), keyframes_(*keyframes), by_features_(by_features) {
  o_.Check();
}

int Segments::joined() const {
  int n = 0;
  for (const Segment& seg : segments_) n += seg.joined;
  return n;
}

bool Segments::InMain(int segment) const {
  return segment == 0 || (segment > 0 && segment < static_cast<int>(segments_.size()) &&
                          segments_[static_cast<size_t>(segment)].joined);
}

bool Segments::KeyframeInActive(int k) const {
  const int seg = keyframes_.keyframes()[static_cast<size_t>(k)].segment;
  return seg == active_ || (InMain(seg) && InMain(active_));
}

Rigid3d Segments::MainFromSegmentFrame(int segment) const {
  Rigid3d t = Rigid3d::Identity();
  if (!InMain(segment)) t.translation().x() = -kSegmentSpacingMm * segment;
  return t;
}

bool Segments::StartsAt(int64_t view) const {
  for (size_t s = 1; s < segments_.size(); ++s)
    if (segments_[s].first_view == view) return true;
  return false;
}

bool Segments::CountRefused() {
  return o_.after_views > 0 && ++refused_in_row_ > o_.after_views &&
         static_cast<int>(segments_.size()) < o_.max_segments;
}

bool Segments::JoinDue() {
  if (active_ <= 0 || segments_[static_cast<size_t>(active_)].joined) return false;
  Segment& seg = segments_[static_cast<size_t>(active_)];
  const size_t keyframes = static_cast<size_t>(keyframes_.size());
  if (keyframes < seg.keyframes_at_attempt + static_cast<size_t>(o_.join_every)) return false;
  seg.keyframes_at_attempt = keyframes;
  return true;
}

SurfacePoints Segments::MainSamples() const {
  const PointMap& map = odometry_.model();
  SurfacePoints main;
  for (size_t i = 0; i < map.size(); ++i) {
    if (!InMain(SegmentOfPoint(map.points()[i]))) continue;
    main.points.push_back(map.points()[i]);
    main.normals.push_back(map.normals()[i]);
  }
  return main;
}

void Segments::RefreshJoinTarget() { join_target_ = MakeSegmentJoinTarget(MainSamples(), o_.join); }

void Segments::Start(int64_t view, const Rigid3d& last_pose, Rigid3d* pose, TrackResult* out) {
  const int s = static_cast<int>(segments_.size());
  // The last pose in the main frame's coordinates (the track may be in another segment apart).
  const Rigid3d last_at_origin = MainFromSegmentFrame(active_) * last_pose;
  // The main model rests while the new segment grows: its join features are made once, now.
  const auto t0 = std::chrono::steady_clock::now();
  RefreshJoinTarget();
  const double ms_target =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  segments_.push_back(Segment{view, false, static_cast<size_t>(keyframes_.size())});
  active_ = s;
  *pose = MainFromSegmentFrame(s).inverse() * last_at_origin;
  out->state = TrackingState::kTracking;
  out->new_segment = true;
  char what[160];
  std::snprintf(what, sizeof what,
                "; new segment %d after %d views that could not be placed (join features of the "
                "model: %.0f ms)",
                s, refused_in_row_, ms_target);
  out->reason += what;
  refused_in_row_ = 0;
  undo_barrier_view_ = view + 1;  // undo does not reach back before it
}

int Segments::NewestKeyframe(int s) const {
  const std::vector<Keyframe>& kfs = keyframes_.keyframes();
  for (int k = static_cast<int>(kfs.size()) - 1; k >= 0; --k)
    if (kfs[static_cast<size_t>(k)].segment == s) return k;
  return -1;
}

bool Segments::FindJoin(int s, bool at_end, SegmentJoinResult* join, int* anchor, std::string* how,
                        std::string* why) {
  // The segment's model samples (they lie around its offset) and its newest keyframe.
  const PointMap& map = odometry_.model();
  SurfacePoints seg;
  for (size_t i = 0; i < map.size(); ++i) {
    if (SegmentOfPoint(map.points()[i]) != s) continue;
    seg.points.push_back(map.points()[i]);
    seg.normals.push_back(map.normals()[i]);
  }
  const int newest = NewestKeyframe(s);
  if (seg.empty() || newest < 0) {
    *why = "the segment is empty";
    return false;
  }
  // Thinned and described once for both ways of joining.
  const SegmentJoinTarget source = MakeSegmentJoinTarget(seg, o_.join);
  SegmentJoinResult r = JoinSegment(source, join_target_, o_.join);
  *how = r.settled ? "fpfh (" + r.reason + ")" : "fpfh";
  if (!r.ok) {
    *why = r.reason;
    if (by_features_ && o_.join_feature_keyframes > 0) {
      std::string features_why;
      SegmentJoinResult f = JoinByFeatures(s, newest, source, &features_why);
      if (f.ok) {
        r = std::move(f);
        *how = "features (" + features_why + ")";
      } else {
        *why += "; features: " + features_why;
      }
    }
  }
  *anchor = newest;
  if (!r.ok && at_end && o_.join_fine_at_end) {
    // The main model's fine keypoints, made here: only a segment still apart at the end needs them
    // (made for each segment's try; the coarse ones are made again only after a join).
    SegmentJoinOptions fine = o_.join;
    fine.fpfh = o_.join_fine_fpfh;
    SegmentJoinResult f = JoinSegment(MakeSegmentJoinTarget(seg, fine),
                                      MakeSegmentJoinTarget(MainSamples(), fine), fine);
    if (f.ok) {
      *how = f.settled ? "fine fpfh (" + f.reason + ")" : "fine fpfh";
      r = std::move(f);
    } else {
      *why += "; fine fpfh: " + f.reason;
    }
  }
  if (!r.ok && at_end && o_.join_starts_at_end > 0) {
    std::string starts_why;
    SegmentJoinResult f = JoinFromKeyframeStarts(s, source, anchor, &starts_why);
    if (f.ok) {
      r = std::move(f);
      *how = "keyframe starts (" + starts_why + ")";
    } else {
      *why += "; keyframe starts: " + starts_why;
    }
  }
  if (!r.ok) return false;
  *join = std::move(r);
  return true;
}

SegmentJoinResult Segments::JoinFromKeyframeStarts(int s, const SegmentJoinTarget& seg, int* anchor,
                                                   std::string* why) {
  SegmentJoinResult none;
  if (join_target_.empty() || seg.empty()) {
    *why = "nothing to join";
    return none;
  }
  const std::vector<Keyframe>& kfs = keyframes_.keyframes();
  std::vector<int> main, first;
  for (int k = 0; k < static_cast<int>(kfs.size()); ++k) {
    const int g = kfs[static_cast<size_t>(k)].segment;
    if (g == s && static_cast<int>(first.size()) < o_.join_starts_at_end) first.push_back(k);
    if (g != s && InMain(g)) main.push_back(k);
  }
  // One view held at a main keyframe's camera: a wide first gate brings it in from the few
  // millimetres between two passes' cameras, and capped samples suffice to show that the view lies
  // on the model there; the whole segment's refinement measures the join. No eigenvalue limit on
  // one view: a smooth crown may be degenerate alone, the whole segment is not. (A cheaper screen,
  // 500 samples and an acceptance at 1 mm, held none of incisors-first's right starts:
  // docs/decisions/0005.)
  IcpOptions start = o_.join.icp;
  start.levels = {IcpLevel{1, 20, o_.join_start_gate_mm, 0.5, 1500},
                  IcpLevel{1, 10, 1.0, 0.7, 1500}, IcpLevel{1, 8, 0.3, 0.9, 3000}};
  start.min_overlap = 0.3;
  // A start whose coarse levels leave the model (fewer matches than the last level needs, at
  // gates 10× and 3× wider) ends there.
  start.levels[0].min_overlap = start.levels[1].min_overlap = start.min_overlap;
  start.max_rmse_mm = 0.06;
  start.min_eigen_ratio = 0;
  const KdTreeTarget main_tree(join_target_.samples);
  struct Held {
    SegmentJoinResult join;
    int anchor;
  };
  std::vector<Held> held;
  int starts = 0, views_held = 0;
  std::string refused;  // why the last refinement of a held start failed
  std::string closest;  // why the start that kept the most overlap was not held
  double closest_overlap = -1;
  for (const int k : first) {
    const Rigid3d segment_from_cam = keyframes_.world_from_keyframe(k);
    for (const int j : main) {
      ++starts;
      const IcpResult v = RegisterIcp(kfs[static_cast<size_t>(k)].samples, main_tree,
                                      keyframes_.world_from_keyframe(j), start);
      if (!v.ok) {
        if (v.overlap > closest_overlap) {
          closest_overlap = v.overlap;
          closest = v.reason;
        }
        continue;
      }
      ++views_held;
      const Rigid3d guess = v.target_from_source * segment_from_cam.inverse();
      // A start that lands where an earlier one was refined adds nothing.
      bool known = false;
      for (const Held& h : held)
        known = known || (TranslationDistanceMm(h.join.main_from_segment, guess) < 0.5 &&
                          RotationAngleRad(h.join.main_from_segment, guess) < 1.0 * M_PI / 180);
      if (known) continue;
      SegmentJoinResult r = RefineSegmentJoin(seg, join_target_, guess, o_.join);
      if (r.ok)
        held.push_back({std::move(r), k});
      else
        refused = r.reason;
    }
  }
  char counts[96];
  std::snprintf(counts, sizeof counts, "%d starts, %d views held, %zu joins", starts, views_held,
                held.size());
  if (held.empty()) {
    *why = counts;
    if (!refused.empty()) *why += " (the refinement: " + refused + ")";
    if (views_held == 0 && !closest.empty()) *why += " (the closest start: " + closest + ")";
    return none;
  }
  // The best refined join, and no other far from it.
  size_t best = 0;
  for (size_t i = 1; i < held.size(); ++i)
    if (held[i].join.icp.correspondences > held[best].join.icp.correspondences) best = i;
  const Rigid3d& T = held[best].join.main_from_segment;
  for (const Held& h : held) {
    const double mm = TranslationDistanceMm(h.join.main_from_segment, T);
    const double deg = RotationAngleRad(h.join.main_from_segment, T) * 180 / M_PI;
    if (mm > o_.join.fpfh.ambiguity_mm || deg > o_.join.fpfh.ambiguity_deg) {
      char amb[240];
      std::snprintf(amb, sizeof amb,
                    "%s: ambiguous (two joins %.1f mm / %.1f deg apart, %d and %d samples on the "
                    "model, rmse %.1f and %.1f um)",
                    counts, mm, deg, held[best].join.icp.correspondences,
                    h.join.icp.correspondences, held[best].join.icp.rmse_mm * 1000,
                    h.join.icp.rmse_mm * 1000);
      *why = amb;
      return none;
    }
  }
  *anchor = held[best].anchor;
  *why = counts;
  return std::move(held[best].join);
}

SegmentJoinResult Segments::JoinByFeatures(int s, int newest, const SegmentJoinTarget& seg,
                                           std::string* why) {
  SegmentJoinResult none;
  const std::vector<Keyframe>& kfs = keyframes_.keyframes();
  std::vector<int> main;
  for (int k = 0; k < static_cast<int>(kfs.size()); ++k)
    if (kfs[static_cast<size_t>(k)].segment != s && InMain(kfs[static_cast<size_t>(k)].segment))
      main.push_back(k);
  if (main.empty()) {
    *why = "no main keyframe";
    return none;
  }
  keyframes_.CollectFeatures();
  const ViewFeatures& newest_features = keyframes_.Features(newest);
  Segment& g = segments_[static_cast<size_t>(s)];
  const FeatureOptions& features = keyframes_.options().features;
  const size_t tries = std::min(main.size(), static_cast<size_t>(o_.join_feature_keyframes));
  *why = "no feature match";
  for (size_t i = 0; i < tries; ++i) {
    const int j = main[(g.feature_cursor + i) % main.size()];
    const FeatureAlignResult a = AlignByFeatures(newest_features, keyframes_.Features(j), features);
    if (!a.ok) continue;
    const Rigid3d guess = keyframes_.world_from_keyframe(j) * a.target_from_source *
                          keyframes_.world_from_keyframe(newest).inverse();
    SegmentJoinResult r = RefineSegmentJoin(seg, join_target_, guess, o_.join);
    if (r.ok) {
      g.feature_cursor += i + 1;
      *why =
          "keyframe " + std::to_string(j) + ", " + std::to_string(a.inliers) + " feature inliers";
      return r;
    }
    *why = "keyframe " + std::to_string(j) + ": " + r.reason;
  }
  g.feature_cursor += tries;
  return none;
}

void Segments::Merge(int s, const Rigid3d& T, int anchor, int64_t view) {
  // The segment's keyframes and model samples into the main frame.
  keyframes_.MoveSegment(s, T);
  const PointMap& map = odometry_.model();
  PointMap merged(odometry_.options().map);
  SurfacePoints all;
  const Eigen::Matrix3f R = T.linear().cast<float>();
  const Eigen::Vector3f t = T.translation().cast<float>();
  for (size_t i = 0; i < map.size(); ++i) {
    const Eigen::Vector3f& p = map.points()[i];
    const Eigen::Vector3f& n = map.normals()[i];
    const bool moves = SegmentOfPoint(p) == s;
    all.points.push_back(moves ? Eigen::Vector3f(R * p + t) : p);
    all.normals.push_back(moves ? Eigen::Vector3f(R * n) : n);
  }
  merged.Insert(all, Rigid3d::Identity(), -1, &map.tags());
  odometry_.ReplaceModel(std::move(merged));
  segments_[static_cast<size_t>(s)].joined = true;
  // A loop edge between the anchor keyframe and the nearest main keyframes that overlap it.
  const std::vector<Keyframe>& kfs = keyframes_.keyframes();
  const Keyframe& kn = kfs[static_cast<size_t>(anchor)];
  const Eigen::Vector3d c = keyframes_.CentreInWorld(anchor);
  std::vector<std::pair<double, int>> near;
  for (int j = 0; j < static_cast<int>(kfs.size()); ++j) {
    const Keyframe& kf = kfs[static_cast<size_t>(j)];
    if (kf.segment == s || !InMain(kf.segment)) continue;
    near.emplace_back((keyframes_.CentreInWorld(j) - c).norm(), j);
  }
  std::sort(near.begin(), near.end());
  int edges = 0;
  for (size_t i = 0; i < near.size() && i < 6 && edges < 2; ++i) {
    PoseGraphEdge e;
    const int j = near[i].second;
    if (!keyframes_.MeasureEdge(std::min(j, anchor), std::max(j, anchor), &e)) continue;
    e.loop = true;
    keyframes_.AddEdge(e);
    ++edges;
  }
  if (edges == 0 && !near.empty()) {  // the join's own pose, on the loop σs
    const PoseGraph& graph = keyframes_.graph();
    PoseGraphEdge e;
    e.from = kfs[static_cast<size_t>(near.front().second)].node;
    e.to = kn.node;
    e.from_from_to = graph.pose(e.from).inverse() * graph.pose(e.to);
    e.sigma_translation_mm = keyframes_.options().loop_sigma_mm;
    e.sigma_rotation_rad = keyframes_.options().loop_sigma_rad;
    e.loop = true;
    keyframes_.AddEdge(e);
  }
  // The rebuilt model has no undo journal: undo starts again after this view.
  undo_barrier_view_ = view + 1;
}

}  // namespace d3d
