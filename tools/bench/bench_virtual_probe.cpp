// d3d-bench-sim: rendering speed of the virtual probe (Google Benchmark).
//   build/bin/d3d-bench-sim [--benchmark_filter=...]
// Reports bursts/s ("items_per_second") for 4-frame bursts of the procedural typodont along the
// full-arch trajectory, at 640×480 and 1280×1024, on 1 and 2 render threads; and the cost of a
// ground-truth-only pass. Each probe owns a oneTBB arena of that many threads.
#include <benchmark/benchmark.h>

#include <map>
#include <memory>
#include <tuple>
#include <opencv2/core.hpp>

#include "firmware/sim/session/sim_session.h"

namespace d3d {
namespace {

SimSession& Session(int width, int height, int threads) {
  static std::map<std::tuple<int, int, int>, std::unique_ptr<SimSession>> sessions;
  auto& s = sessions[{width, height, threads}];
  if (!s) {
    SimSessionOptions o;
    o.camera_width = width;
    o.camera_height = height;
    o.render.threads = threads;
    const Status st = SimSession::Create(o, &s);
    if (!st.ok()) throw std::runtime_error(st.ToString());
  }
  return *s;
}

void BM_RenderBurst(benchmark::State& state) {
  const int width = static_cast<int>(state.range(0)), height = static_cast<int>(state.range(1));
  const int threads = static_cast<int>(state.range(2));
  cv::setNumThreads(threads);
  SimSession& session = Session(width, height, threads);
  int64_t index = 300;  // over the molars: a full field of teeth
  for (auto _ : state) {
    const Burst b = session.RenderBurst(index++, false);
    benchmark::DoNotOptimize(b.frames.back().image.data);
  }
  state.SetItemsProcessed(state.iterations());
  state.SetLabel(std::to_string(width) + "x" + std::to_string(height) + ", " + std::to_string(threads) + " thread(s)");
}
BENCHMARK(BM_RenderBurst)->Args({640, 480, 1})->Args({640, 480, 2})->Args({1280, 1024, 2})
    ->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(3.0);

void BM_RenderTruthOnly(benchmark::State& state) {
  const int threads = static_cast<int>(state.range(0));
  SimSession& session = Session(640, 480, threads);
  int64_t index = 300;
  FrameTruth truth;
  for (auto _ : state) {
    session.probe().RenderTruth(session.trajectory().WorldFromProbe(session.BurstStartNs(index++)), &truth);
    benchmark::DoNotOptimize(truth.depth_mm.data);
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_RenderTruthOnly)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

}  // namespace
}  // namespace d3d

BENCHMARK_MAIN();
