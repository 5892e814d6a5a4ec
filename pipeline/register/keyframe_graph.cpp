#include "pipeline/register/keyframe_graph.h"

#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <thread>
#include <utility>

namespace d3d {

FeatureOptions HalfScaleFeatures() {
  FeatureOptions o;
  o.image_scale = 0.5;
  return o;
}

void KeyframeGraphOptions::Check() const {
  features.Check();
  D3D_CHECK_MSG(stride >= 1, "KeyframeGraphOptions: stride >= 1");
  D3D_CHECK_MSG(overlap > 0 && overlap <= 1, "KeyframeGraphOptions: overlap in (0, 1]");
  D3D_CHECK_MSG(max_rotation_deg >= 0 && max_views >= 0,
                "KeyframeGraphOptions: max_rotation_deg and max_views >= 0 (0 = off)");
  D3D_CHECK_MSG(jump_mm >= 0 && jump_deg >= 0,
                "KeyframeGraphOptions: jump_mm and jump_deg >= 0 (0 = off)");
  D3D_CHECK_MSG(reuse_radius_mm >= 0 && reuse_candidates >= 1,
                "KeyframeGraphOptions: reuse_radius_mm >= 0 (0 = off) and reuse_candidates >= 1");
  D3D_CHECK_MSG(loop_min_separation >= 1 && max_loop_candidates >= 0 && near_loop_candidates >= 0,
                "KeyframeGraphOptions: counts");
  D3D_CHECK_MSG(edge_information_scale > 0, "KeyframeGraphOptions: edge_information_scale > 0");
  D3D_CHECK_MSG(tracked_edge_information_factor >= 0,
                "KeyframeGraphOptions: tracked_edge_information_factor >= 0 (0 = none)");
  D3D_CHECK_MSG(near_loop_information_factor > 0 && near_loop_information_factor <= 1,
                "KeyframeGraphOptions: near_loop_information_factor in (0, 1]");
  D3D_CHECK_MSG(
      odometry_sigma_mm > 0 && odometry_sigma_rad > 0 && loop_sigma_mm > 0 && loop_sigma_rad > 0,
      "KeyframeGraphOptions: sigmas");
}

// Keyframe features on a thread of their own (FeatureTiming::kWorker). Track()'s thread submits a
// keyframe's points and texture (copied into the job's own buffers) and collects the results; the
// worker touches only the job it took, and its queues under mu_.
class KeyframeGraph::FeatureWorker {
 public:
  explicit FeatureWorker(const FeatureOptions& options) : o_(options), thread_([this] { Run(); }) {}
  ~FeatureWorker() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stop_ = true;
    }
    work_cv_.notify_one();
    thread_.join();
  }
  // Copies points and texture into a job's buffers (reused from finished jobs: after the first few
  // keyframes a submission allocates nothing) and queues it.
  void Submit(size_t keyframe, const cv::Mat& points, const cv::Mat& texture) {
    Job job;
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (!spare_.empty()) {
        job = std::move(spare_.back());
        spare_.pop_back();
      }
    }
    job.keyframe = keyframe;
    points.copyTo(job.points);
    texture.copyTo(job.texture);
    {
      std::lock_guard<std::mutex> lock(mu_);
      jobs_.push_back(std::move(job));
      ++pending_;
    }
    work_cv_.notify_one();
  }
  // Waits until every submitted job is done; returns (keyframe, features) of those not yet taken.
  std::vector<std::pair<size_t, ViewFeatures>> WaitAll() {
    std::unique_lock<std::mutex> lock(mu_);
    done_cv_.wait(lock, [this] { return pending_ == 0; });
    return std::exchange(done_, {});
  }

 private:
  struct Job {
    size_t keyframe = 0;
    cv::Mat points, texture;
  };
  void Run() {
    for (;;) {
      Job job;
      {
        std::unique_lock<std::mutex> lock(mu_);
        work_cv_.wait(lock, [this] { return stop_ || !jobs_.empty(); });
        if (jobs_.empty()) return;  // stop_ and nothing left
        job = std::move(jobs_.front());
        jobs_.pop_front();
      }
      ViewFeatures f = ExtractViewFeatures(job.points, job.texture, o_);
      {
        std::lock_guard<std::mutex> lock(mu_);
        done_.emplace_back(job.keyframe, std::move(f));
        spare_.push_back(std::move(job));
        --pending_;
      }
      done_cv_.notify_all();
    }
  }
  const FeatureOptions o_;
  std::mutex mu_;
  std::condition_variable work_cv_, done_cv_;
  std::deque<Job> jobs_;
  std::vector<Job> spare_;  // finished jobs' buffers, for the next submissions
  std::vector<std::pair<size_t, ViewFeatures>> done_;
  size_t pending_ = 0;
  bool stop_ = false;
  std::thread thread_;  // last: started once the members above exist
};

namespace {
constexpr double kOverlapVoxelMm = 0.1;  // voxel of the overlap index between keyframes

// The occupancy map of samples `b` (their own frame) that OverlapIndex measures against.
std::unique_ptr<PointMap> OccupancyMap(const SurfacePoints& b, double voxel_mm) {
  PointMapOptions o;
  o.voxel_mm = voxel_mm;
  o.block_mm = std::max(2.0, voxel_mm);
  auto m = std::make_unique<PointMap>(o);
  m->Insert(b, Rigid3d::Identity());
  return m;
}

// Fraction of `a` (frame A) that lies in occupied voxels of `b` (frame B) given B_from_A.
double OverlapIndex(const SurfacePoints& a, const SurfacePoints& b, const Rigid3d& b_from_a,
                    double voxel_mm) {
  return OccupancyMap(b, voxel_mm)->Overlap(a, b_from_a);
}

// Multiplies an edge's weight by `factor`: its information matrix, or (an edge on σs) its
// variances by 1/factor.
void ScaleInformation(double factor, PoseGraphEdge* e) {
  e->information *= factor;
  e->sigma_translation_mm /= std::sqrt(factor);
  e->sigma_rotation_rad /= std::sqrt(factor);
}
}  // namespace

KeyframeGraph::KeyframeGraph(const KeyframeGraphOptions& options, const IcpOptions& tracking_icp,
                             bool with_features)
    : o_(options), keyframe_icp_(KeyframeIcp(tracking_icp)), with_features_(with_features) {
  o_.Check();
  if (o_.feature_timing == KeyframeGraphOptions::FeatureTiming::kWorker && with_features_)
    feature_worker_ = std::make_unique<FeatureWorker>(o_.features);
}

KeyframeGraph::~KeyframeGraph() = default;

void KeyframeGraph::CollectFeatures() {
  if (!feature_worker_) return;
  for (auto& [k, f] : feature_worker_->WaitAll()) keyframes_[k].features = std::move(f);
}

const ViewFeatures& KeyframeGraph::Features(int k) {
  Keyframe* kf = &keyframes_[static_cast<size_t>(k)];
  if (!kf->features_pending())
    return kf->features;  // kOnDemand: the first relocalisation or join that needs them
  std::vector<cv::Mat> points, texture;
  // Packed by this graph: unpacking fails only on damaged memory, and then no features are better
  // than wrong ones (the keyframe is simply not matched).
  if (UnpackFrames(kf->packed_feature_points, &points).ok() &&
      (kf->packed_feature_texture.empty() ||
       UnpackFrames(kf->packed_feature_texture, &texture).ok()))
    kf->features =
        ExtractViewFeatures(points[0], texture.empty() ? cv::Mat() : texture[0], o_.features);
  std::string().swap(kf->packed_feature_points);
  std::string().swap(kf->packed_feature_texture);
  return kf->features;
}

void KeyframeGraph::Update(const cv::Mat& points, const cv::Mat& normals, const cv::Mat& texture,
                           const Rigid3d& pose, int64_t view, int segment, TrackResult* out) {
  SurfacePoints kfs = SampleOrganised(points, normals, cv::Mat(), o_.stride);
  const bool jumped = (o_.jump_mm > 0 && out->prediction_offset_mm > o_.jump_mm) ||
                      (o_.jump_deg > 0 && out->prediction_offset_deg > o_.jump_deg);
  if (current_kf_ >= 0 && !jumped) {
    const Keyframe& current = keyframes_[static_cast<size_t>(current_kf_)];
    const Rigid3d current_from_cam = graph_.pose(current.node).inverse() * pose;
    const bool turned =
        o_.max_rotation_deg > 0 &&
        RotationAngleRad(graph_.pose(current.node), pose) * 180.0 / M_PI > o_.max_rotation_deg;
    const bool aged = o_.max_views > 0 && view - current_since_ >= o_.max_views;
    if (!turned && !aged && current_occupancy_->Overlap(kfs, current_from_cam) >= o_.overlap)
      return;
    if (o_.reuse_radius_mm > 0 && Reuse(kfs, pose, view)) {
      out->keyframe_reused = true;
      return;
    }
  }
  Keyframe kf;
  kf.view = view;
  kf.node = graph_.AddNode(pose);
  kf.centre_in_cam = kfs.Centroid();
  kf.parent = current_kf_;
  kf.segment = segment;
  kf.samples = std::move(kfs);
  kf.samples.points.shrink_to_fit();  // kept for the scan: not the lattice's growth capacity
  kf.samples.normals.shrink_to_fit();
  current_occupancy_ = OccupancyMap(kf.samples, kOverlapVoxelMm);
  if (with_features_) {
    switch (o_.feature_timing) {
      case KeyframeGraphOptions::FeatureTiming::kInTrack:
        kf.features = ExtractViewFeatures(points, texture, o_.features);
        break;
      case KeyframeGraphOptions::FeatureTiming::kWorker:
        feature_worker_->Submit(keyframes_.size(), points, texture);
        break;
      case KeyframeGraphOptions::FeatureTiming::kOnDemand:
        // zstd fails only on exhausted memory: the features are then extracted now (kInTrack).
        if (!packer_.Pack({points}, &kf.packed_feature_points).ok() ||
            (!texture.empty() && !packer_.Pack({texture}, &kf.packed_feature_texture).ok())) {
          kf.packed_feature_points.clear();
          kf.packed_feature_texture.clear();
          kf.features = ExtractViewFeatures(points, texture, o_.features);
        }
        kf.packed_feature_points.shrink_to_fit();  // Pack sized it for the worst case
        kf.packed_feature_texture.shrink_to_fit();
        break;
    }
  }
  keyframes_.push_back(std::move(kf));
  out->new_keyframe = true;
  const int k = static_cast<int>(keyframes_.size()) - 1;
  current_kf_ = k;
  current_since_ = view;
  if (o_.defer_edges)
    deferred_edges_.push_back({-1, k});
  else
    out->loops_added = AddKeyframeEdges(k);
}

bool KeyframeGraph::Reuse(const SurfacePoints& kfs, const Rigid3d& pose, int64_t view) {
  if (kfs.empty()) return false;
  const Eigen::Vector3d centre = pose * kfs.Centroid();
  const double max_turn_rad =
      o_.max_rotation_deg > 0 ? 0.5 * o_.max_rotation_deg * M_PI / 180.0 : M_PI;
  std::vector<std::pair<double, int>> near;
  for (int j = 0; j < static_cast<int>(keyframes_.size()); ++j) {
    if (j == current_kf_) continue;
    const Keyframe& kf = keyframes_[static_cast<size_t>(j)];
    const Rigid3d& world_from_kf = graph_.pose(kf.node);
    const double d = (world_from_kf * kf.centre_in_cam - centre).norm();
    if (d <= o_.reuse_radius_mm && RotationAngleRad(world_from_kf, pose) <= max_turn_rad)
      near.emplace_back(d, j);
  }
  const size_t n = std::min(near.size(), static_cast<size_t>(o_.reuse_candidates));
  std::partial_sort(near.begin(), near.begin() + static_cast<std::ptrdiff_t>(n), near.end());
  for (size_t i = 0; i < n; ++i) {
    const int j = near[i].second;
    const Keyframe& kf = keyframes_[static_cast<size_t>(j)];
    std::unique_ptr<PointMap> occupancy = OccupancyMap(kf.samples, kOverlapVoxelMm);
    if (occupancy->Overlap(kfs, graph_.pose(kf.node).inverse() * pose) < o_.overlap) continue;
    // The view overlaps both the keyframe it leaves and the one it returns to: those two are a loop
    // closed (e.g. a probe back at a tooth it circled before), the edge DetectLoops would have
    // measured had the view become a keyframe.
    const int left = current_kf_;
    current_kf_ = j;
    current_since_ = view;
    current_occupancy_ = std::move(occupancy);
    ++keyframes_reused_;
    if (left >= 0) {
      const DeferredEdge d{std::min(left, j), std::max(left, j)};
      if (o_.defer_edges)
        deferred_edges_.push_back(d);
      else
        AddReuseEdge(d.from, d.to);
    }
    return true;
  }
  return false;
}

void KeyframeGraph::AddReuseEdge(int from, int to) {
  // Checked here rather than when the reuse happened: deferred, the keyframes' own edges (odometry,
  // DetectLoops) are added just before, in Track()'s order, and one pair may be reused many times.
  if (graph_.HasEdge(keyframes_[static_cast<size_t>(from)].node,
                     keyframes_[static_cast<size_t>(to)].node))
    return;
  PoseGraphEdge e;
  if (!MeasureEdge(from, to, &e)) return;
  e.loop = true;
  if (to - from < o_.loop_min_separation) ScaleInformation(o_.near_loop_information_factor, &e);
  graph_.AddEdge(e);
}

int64_t Keyframe::bytes() const {
  const auto mat = [](const cv::Mat& m) { return static_cast<int64_t>(m.total() * m.elemSize()); };
  const auto points = [](const std::vector<Eigen::Vector3f>& v) {
    return static_cast<int64_t>(v.capacity() * sizeof(Eigen::Vector3f));
  };
  return points(samples.points) + points(samples.normals) +
         static_cast<int64_t>(samples.weights.capacity() * sizeof(float)) +
         points(features.texture_points) + points(features.range_points) +
         points(features.shaded_points) + mat(features.texture_descriptors) +
         mat(features.range_descriptors) + mat(features.shaded_descriptors) +
         static_cast<int64_t>(packed_feature_points.capacity() + packed_feature_texture.capacity());
}

int64_t KeyframeGraph::bytes() const {
  int64_t bytes = 0;
  for (const Keyframe& kf : keyframes_) bytes += kf.bytes();
  return bytes;
}

int KeyframeGraph::AddKeyframeEdges(int k) {
  if (const int parent = keyframes_[static_cast<size_t>(k)].parent; parent >= 0) {
    PoseGraphEdge e;
    const bool measured = o_.icp_edges && MeasureEdge(parent, k, &e);
    if (!measured) e = TrackedOdometryEdge(parent, k);
    e.loop = false;
    graph_.AddEdge(e);
    if (measured && o_.tracked_edge_information_factor > 0) {
      // The tracked relative pose: the graph's poses are still the tracked ones (only Optimize
      // moves them, and deferred edges are added before it does), or a loop correction's
      // (OptimizeNow) spread of the drift over the keyframes since.
      e.from_from_to = graph_.pose(e.from).inverse() * graph_.pose(e.to);
      ScaleInformation(o_.tracked_edge_information_factor, &e);
      graph_.AddEdge(e);
    }
  }
  return o_.detect_loops ? DetectLoops(k) : 0;
}

IcpOptions KeyframeIcp(const IcpOptions& base) {
  IcpOptions icp = base;
  icp.levels = {{4, 10, 0.5, 0.8}, {1, 10, 0.2, 1.0}, {1, 8, 0.1, 1.0}};
  // Pose-graph edges keep IcpOptions' strict termination (a few per keyframe, not per burst).
  const IcpOptions strict;
  icp.min_delta_translation_mm = strict.min_delta_translation_mm;
  icp.min_delta_rotation_rad = strict.min_delta_rotation_rad;
  icp.min_relative_error_change = strict.min_relative_error_change;
  return icp;
}

bool MeasureKeyframeEdge(const SurfacePoints& from_samples, const SurfacePoints& to_samples,
                         const Rigid3d& guess, const IcpOptions& icp, double information_scale,
                         PoseGraphEdge* e, IcpResult* result) {
  D3D_CHECK_MSG(information_scale > 0, "MeasureKeyframeEdge: information_scale must be > 0");
  const KdTreeTarget target(from_samples);
  const IcpResult r = RegisterIcp(to_samples, target, guess, icp);
  if (result) *result = r;
  if (!r.ok) return false;
  e->from_from_to = r.target_from_source;
  e->information = EdgeInformationFromIcp(r.information, r.target_from_source, information_scale);
  return true;
}

bool KeyframeGraph::MeasureEdge(int from, int to, PoseGraphEdge* e) const {
  const Keyframe& b = keyframes_[static_cast<size_t>(from)];
  const Keyframe& a = keyframes_[static_cast<size_t>(to)];
  const Rigid3d b_from_a = graph_.pose(b.node).inverse() * graph_.pose(a.node);
  PoseGraphEdge m;
  m.from = b.node;
  m.to = a.node;
  m.sigma_translation_mm = o_.loop_sigma_mm;
  m.sigma_rotation_rad = o_.loop_sigma_rad;
  if (!MeasureKeyframeEdge(b.samples, a.samples, b_from_a, keyframe_icp_, o_.edge_information_scale,
                           &m))
    return false;
  if (!o_.icp_edges) m.information.setZero();  // the σs
  *e = m;
  return true;
}

PoseGraphEdge KeyframeGraph::TrackedOdometryEdge(int parent, int k) const {
  PoseGraphEdge e;
  e.from = keyframes_[static_cast<size_t>(parent)].node;
  e.to = keyframes_[static_cast<size_t>(k)].node;
  e.from_from_to = graph_.pose(e.from).inverse() * graph_.pose(e.to);
  e.sigma_translation_mm = o_.odometry_sigma_mm;
  e.sigma_rotation_rad = o_.odometry_sigma_rad;
  return e;
}

void KeyframeGraph::LoopCandidates(int k, std::vector<std::pair<double, int>>* far,
                                   std::vector<std::pair<double, int>>* near) const {
  const Keyframe& a = keyframes_[static_cast<size_t>(k)];
  const Eigen::Vector3d ca = graph_.pose(a.node) * a.centre_in_cam;
  far->clear();
  if (near) near->clear();
  for (int j = 0; j + 2 <= k; ++j) {
    if (j == a.parent)
      continue;  // joined by the odometry edge (a reused keyframe: older than k − 1)
    const bool is_far = j + o_.loop_min_separation <= k;
    if (!is_far && !near) continue;
    const Keyframe& b = keyframes_[static_cast<size_t>(j)];
    const double d = (graph_.pose(b.node) * b.centre_in_cam - ca).norm();
    if (d >= o_.loop_radius_mm) continue;
    (is_far ? far : near)->emplace_back(d, j);
  }
  std::sort(far->begin(), far->end());
  if (near) std::sort(near->begin(), near->end());
}

int KeyframeGraph::DetectLoops(int k) {
  const Keyframe& a = keyframes_[static_cast<size_t>(k)];
  const Rigid3d wa = graph_.pose(a.node);
  std::vector<std::pair<double, int>> far, near;
  LoopCandidates(k, &far, &near);
  int added = 0;
  for (const auto& [cand, budget] :
       {std::pair{&far, o_.max_loop_candidates}, std::pair{&near, o_.near_loop_candidates}}) {
    int here = 0;
    for (size_t i = 0; i < cand->size() && here < budget; ++i) {
      const Keyframe& b = keyframes_[static_cast<size_t>((*cand)[i].second)];
      const Rigid3d b_from_a = graph_.pose(b.node).inverse() * wa;
      if (OverlapIndex(a.samples, b.samples, b_from_a, kOverlapVoxelMm) < o_.loop_min_overlap)
        continue;
      PoseGraphEdge e;
      if (!MeasureEdge((*cand)[i].second, k, &e)) continue;
      e.loop = true;
      if (cand == &near) ScaleInformation(o_.near_loop_information_factor, &e);
      graph_.AddEdge(e);
      ++here;
    }
    added += here;
  }
  return added;
}

double KeyframeGraph::LoopDiscrepancyMm(int k, int candidates, std::vector<PoseGraphEdge>* loops,
                                        int* tested) const {
  loops->clear();
  *tested = 0;
  if (!o_.detect_loops) return -1;
  const Keyframe& a = keyframes_[static_cast<size_t>(k)];
  const Rigid3d& wa = graph_.pose(a.node);
  std::vector<std::pair<double, int>> far;
  LoopCandidates(k, &far, nullptr);
  if (far.empty()) return -1;
  // k's samples for the overlap test, every 4th: the test looks up 27 voxels per sample.
  SurfacePoints& few = check_samples_;
  few.clear();
  for (size_t s = 0; s < a.samples.size(); s += 4) {
    few.points.push_back(a.samples.points[s]);
    few.normals.push_back(a.samples.normals[s]);
  }
  // The nearest few: a candidate that overlaps is nearly always among them.
  const size_t tried =
      std::min<size_t>(o_.max_loop_candidates, static_cast<size_t>(candidates) + 2);
  double worst = -1;
  int measured = 0;
  for (size_t i = 0; i < far.size() && i < tried && measured < candidates; ++i) {
    ++*tested;
    const int j = far[i].second;
    const Keyframe& b = keyframes_[static_cast<size_t>(j)];
    const Rigid3d b_from_a = graph_.pose(b.node).inverse() * wa;
    if (OverlapIndex(few, b.samples, b_from_a, kOverlapVoxelMm) < o_.loop_min_overlap) continue;
    PoseGraphEdge e;
    if (!MeasureEdge(j, k, &e)) continue;
    ++measured;
    e.loop = true;
    loops->push_back(e);
    // k's centre where the graph has it and where the loop puts it, both in b's frame.
    const Eigen::Vector3d c = a.centre_in_cam;
    worst = std::max(worst, (b_from_a * c - e.from_from_to * c).norm());
  }
  return worst;
}

int KeyframeGraph::loop_edges() const {
  int n = 0;
  for (const auto& e : graph_.edges()) n += e.loop;
  return n;
}

void KeyframeGraph::MoveSegment(int s, const Rigid3d& T) {
  for (Keyframe& kf : keyframes_)
    if (kf.segment == s) graph_.set_pose(kf.node, T * graph_.pose(kf.node));
}

void KeyframeGraph::ForgetCurrent() {
  current_kf_ = -1;
  current_since_ = -1;
  current_occupancy_.reset();
}

Status KeyframeGraph::Optimize(const PoseGraphOptions& options, PoseGraphSummary* summary) {
  // Deferred edges first, in keyframe order: the graph's poses have not moved since the keyframes
  // were made (nothing but Optimize moves them), so these are the edges Track() would have added;
  // or a loop correction moved them (OptimizeNow), and ICP starts from the corrected poses.
  for (const DeferredEdge& d : deferred_edges_) {
    if (d.from < 0)
      AddKeyframeEdges(d.to);
    else
      AddReuseEdge(d.from, d.to);
  }
  deferred_edges_.clear();
  return graph_.Optimize(options, summary);
}

Status KeyframeGraph::OptimizeNow(const PoseGraphOptions& options,
                                  const std::vector<PoseGraphEdge>& loops,
                                  PoseGraphSummary* summary) {
  if (!o_.defer_edges) return Optimize(options, summary);
  PoseGraph provisional = graph_;
  for (const DeferredEdge& d : deferred_edges_) {
    if (d.from >= 0) continue;  // a reuse's loop edge: the chain holds without it
    const int parent = keyframes_[static_cast<size_t>(d.to)].parent;
    if (parent >= 0) provisional.AddEdge(TrackedOdometryEdge(parent, d.to));
  }
  for (const PoseGraphEdge& e : loops) provisional.AddEdge(e);
  D3D_RETURN_IF_ERROR(provisional.Optimize(options, summary));
  for (int node = 0; node < graph_.num_nodes(); ++node)
    graph_.set_pose(node, provisional.pose(node));
  return Status();
}

int KeyframeGraph::DropFrom(int64_t first_view, bool truncate_edges, size_t edges_before,
                            size_t deferred_before) {
  CollectFeatures();  // no job of the feature worker may name a keyframe that goes
  size_t keep = 0;
  while (keep < keyframes_.size() && keyframes_[keep].view < first_view) ++keep;
  const int dropped = static_cast<int>(keyframes_.size() - keep);
  keyframes_.resize(keep);
  D3D_CHECK_MSG(keep == 0 || keyframes_.back().node == static_cast<int>(keep) - 1,
                "KeyframeGraph::DropFrom: keyframe nodes out of order");
  // Edges (and deferred ones) are appended in Track()'s order until Optimize: those added since the
  // counts were taken go, including reuse edges between two kept keyframes.
  if (truncate_edges) {
    graph_.Truncate(static_cast<int>(keep), edges_before);
    deferred_edges_.resize(std::min(deferred_edges_.size(), deferred_before));
  }
  return dropped;
}

void KeyframeGraph::SetCurrent(int k, int64_t since) {
  D3D_CHECK_MSG(k < size(), "KeyframeGraph::SetCurrent: keyframe " << k << " of " << size());
  current_kf_ = k;
  current_since_ = since;
  current_occupancy_ =
      k >= 0 ? OccupancyMap(keyframes_[static_cast<size_t>(k)].samples, kOverlapVoxelMm) : nullptr;
}

}  // namespace d3d
