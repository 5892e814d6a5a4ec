// d3d-bench-preview: the live preview's cost per frame, offscreen (EGL surfaceless, Mesa's
// llvmpipe on one rendering thread as d3d-scan sets it), on a synthetic model that grows the way a
// scan's does: a 30 Hz scan adds a few hundred preview points per burst, the preview draws at its
// frame cap, so each frame sees the model grown by `--grow` points (appended, as the host's
// preview stage does within a generation), up to `--points`.
//
// Prints, per phase (growing, then the full model held): wall ms per frame, the process's CPU ms
// per frame (every thread: the render thread and llvmpipe's) and the render thread's own CPU ms.
// On llvmpipe every millisecond of it is taken from the scan pipeline's two cores. Speed is
// measured here, never in tests.
#include <malloc.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>

#include "common/core/process_stats.h"
#include "common/options/option_registry.h"
#include "host/graph/stage_graph.h"
#include "viewer/viewer.h"

using namespace d3d;

namespace {

double WallMs() {
  return std::chrono::duration<double, std::milli>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}
double ThreadCpuMs() {
  return 1e-6 * static_cast<double>(ThreadCpuNs());
}  // the graph's per-stage CPU clock

// Point i of an arch-like strip: a half torus (radius 25 mm, tube 4 mm), filled in scan order
// along the arch, normals outward. Deterministic.
void ArchPoint(size_t i, size_t n, Eigen::Vector3f* p, Eigen::Vector3f* normal) {
  constexpr int kAround = 96;  // samples around the tube
  const size_t rings = std::max<size_t>(1, n / kAround);
  const float u = static_cast<float>(i / kAround) / static_cast<float>(rings) *
                  static_cast<float>(M_PI);  // along the arch
  const float v = static_cast<float>(i % kAround) / kAround * 1.2f * static_cast<float>(M_PI) -
                  0.1f;  // around the tube
  const Eigen::Vector3f centre(25 * std::cos(u), 25 * std::sin(u) - 12, 50);
  const Eigen::Vector3f radial(std::cos(u), std::sin(u), 0);
  *normal = (std::cos(v) * radial + std::sin(v) * Eigen::Vector3f(0, 0, -1)).normalized();
  *p = centre + 4.0f * *normal;
}

struct Phase {
  double wall = 0, cpu = 0, thread = 0;
  int frames = 0;
};

}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options(
      "d3d-bench-preview: CPU and wall time per preview frame (offscreen, llvmpipe) on a growing "
      "synthetic model");
  size_t points = 150000, grow = 400;
  int hold_frames = 100, width = 960, height = 720;
  float point_size_px = ViewerOptions{}.point_size_px;
  bool glibc_heap = false;
  options.Add("--points", &points, "model points at the end (d3d-scan's preview cap)");
  options.Add("--grow", &grow, "points appended before each frame while growing");
  options.Add("--hold-frames", &hold_frames, "frames drawn of the full model");
  options.Add("--width", &width, "offscreen frame width (px)");
  options.Add("--height", &height, "offscreen frame height (px)");
  options.Add("--point-size", &point_size_px, "model point size (px)");
  options.Flag("--glibc-default-heap", &glibc_heap,
               "leave glibc's heap as a fresh process has it (see the file comment)");
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;
  setenv("LP_NUM_THREADS", "1", 0);  // as d3d-scan
  // llvmpipe allocates and frees buffers of a few MB per frame. In d3d-scan the pipeline's own
  // large blocks have already raised glibc's dynamic mmap and trim thresholds, so those buffers are
  // reused: the render and llvmpipe threads' CPU there was the same with the heap held as below
  // (perf stat per thread, live). In this small process they would be mmapped and page-faulted
  // afresh every frame (two thirds of the render thread's CPU here), which d3d-scan does not pay.
  if (!glibc_heap &&
      (mallopt(M_MMAP_THRESHOLD, 32 << 20) != 1 || mallopt(M_TRIM_THRESHOLD, 256 << 20) != 1))
    std::fprintf(stderr,
                 "d3d-bench-preview: mallopt refused; the figures include page faults d3d-scan "
                 "does not have\n");

  ViewerOptions vo;
  vo.headless = true;
  vo.width = width;
  vo.height = height;
  vo.point_size_px = point_size_px;
  std::unique_ptr<Viewer> viewer;
  if (const Status s = Viewer::Create(vo, &viewer); !s.ok()) {
    std::fprintf(stderr, "d3d-bench-preview: %s\n", s.ToString().c_str());
    return 1;
  }
  PreviewSnapshot snap;
  snap.points.reserve(points);
  snap.normals.reserve(points);
  snap.have_pose = true;
  snap.cue = PreviewCue::kTracking;
  snap.view_accepted = true;
  PreviewStatus st;
  Phase growing, held;
  const auto frame = [&](Phase* ph) {
    // The current view: a small patch at the newest points, as the host's decimated view.
    snap.view_points.clear();
    const size_t from = snap.points.size() > 2000 ? snap.points.size() - 2000 : 0;
    for (size_t i = from; i < snap.points.size(); i += 4)
      snap.view_points.push_back(snap.points[i]);
    st.bursts_received = st.bursts_processed = st.bursts_fused =
        static_cast<uint64_t>(ph->frames) + 1;
    st.bursts_per_s =
        28 + 0.1 * (ph->frames % 10);  // the panel's text changes every frame, as live
    const double w0 = WallMs(), c0 = ProcessCpuMs(), t0 = ThreadCpuMs();
    viewer->Render(&snap, st, 20);
    ph->wall += WallMs() - w0;
    ph->cpu += ProcessCpuMs() - c0;
    ph->thread += ThreadCpuMs() - t0;
    ++ph->frames;
  };
  while (snap.points.size() < points) {
    const size_t to = std::min(points, snap.points.size() + grow);
    for (size_t i = snap.points.size(); i < to; ++i) {
      Eigen::Vector3f p, n;
      ArchPoint(i, points, &p, &n);
      snap.points.push_back(p);
      snap.normals.push_back(n);
    }
    snap.model_area_mm2 = 0.04 * static_cast<double>(snap.points.size());
    frame(&growing);
  }
  for (int f = 0; f < hold_frames; ++f) frame(&held);
  std::printf("%-24s %8s %10s %10s %12s\n", "phase", "frames", "wall ms", "cpu ms",
              "render thr ms");
  for (const auto& [name, ph] :
       {std::pair<const char*, const Phase&>{"growing (0..points)", growing},
        {"full model held", held}})
    if (ph.frames > 0)
      std::printf("%-24s %8d %10.2f %10.2f %12.2f\n", name, ph.frames, ph.wall / ph.frames,
                  ph.cpu / ph.frames, ph.thread / ph.frames);
  return 0;
}
