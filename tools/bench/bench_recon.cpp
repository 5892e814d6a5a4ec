// d3d-bench-recon: the single-view chain (phase + quality + unwrapping + triangulation) on one core
// and with its per-pixel passes on 2 threads (ReconstructOptions::threads), at 640×480 and
// 1280×1024, on a burst of the virtual probe over the typodont's molars.
// Target (issue "single-view reconstruction"): ≤ 5 ms at 640×480. Per-stage times are reported as
// counters (ms).
#include <benchmark/benchmark.h>
#include <tbb/global_control.h>

#include <map>
#include <memory>
#include <opencv2/core.hpp>

#include "pipeline/recon/reconstruct.h"
#include "sim/session/sim_session.h"

namespace d3d {
namespace {

void BM_Reconstruct(benchmark::State& state) {
  cv::setNumThreads(1);
  SimSessionOptions o;
  o.camera_width = static_cast<int>(state.range(0));
  o.camera_height = static_cast<int>(state.range(1));
  o.render.threads = 2;  // rendering the input is not timed
  std::unique_ptr<SimSession> session;
  if (!SimSession::Create(o, &session).ok()) {
    state.SkipWithError("cannot create the simulated session");
    return;
  }
  const Burst b = session->RenderBurst(300, false);
  std::vector<cv::Mat> frames;
  for (int k = 0; k < 4; ++k) frames.push_back(b.frames[static_cast<size_t>(k)].image);
  ReconstructOptions options;
  options.threads =
      static_cast<int>(state.range(2));  // > 1: per-pixel passes on row blocks (oneTBB)
  tbb::global_control cap(tbb::global_control::max_allowed_parallelism,
                          static_cast<size_t>(options.threads));
  Reconstructor recon(session->calibration(), options);
  ReconstructedView view;
  double phase = 0, quality = 0, unwrap = 0, tri = 0;
  // A time is only worth printing for a reconstruction that gives one: the burst's view must hold
  // points (a chain that rejects the whole view is fast and wrong).
  if (!recon.Reconstruct(frames, &view).ok() || view.points == 0) {
    state.SkipWithError("the reconstruction gives no point on this burst: nothing to time");
    return;
  }
  for (auto _ : state) {
    if (!recon.Reconstruct(frames, &view).ok()) state.SkipWithError("reconstruction failed");
    phase += view.ms_phase;
    quality += view.ms_quality;
    unwrap += view.ms_unwrap;
    tri += view.ms_triangulate;
  }
  const double n = static_cast<double>(state.iterations());
  state.counters["phase_ms"] = phase / n;
  state.counters["quality_ms"] = quality / n;
  state.counters["unwrap_ms"] = unwrap / n;
  state.counters["triangulate_ms"] = tri / n;
  state.counters["points"] = static_cast<double>(view.points);
}
// Args: width, height, ReconstructOptions::threads. Wall time (UseRealTime): with 2 threads the
// calling thread's CPU time leaves out the worker's share.
BENCHMARK(BM_Reconstruct)
    ->Args({640, 480, 1})
    ->Args({640, 480, 2})
    ->Args({1280, 1024, 1})
    ->Args({1280, 1024, 2})
    ->Unit(benchmark::kMillisecond)
    ->MinTime(2.0)
    ->UseRealTime();

}  // namespace
}  // namespace d3d

BENCHMARK_MAIN();
