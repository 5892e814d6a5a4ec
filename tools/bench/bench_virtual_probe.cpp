// d3d-bench-sim: rendering speed of the virtual probe (Google Benchmark).
//   build/bin/d3d-bench-sim [--benchmark_filter=...]
// Reports bursts/s ("items_per_second") for 4-frame bursts of the procedural typodont along the
// full-arch trajectory, at 640×480 and 1280×1024, on 1 and 2 render threads; and the cost of a
// ground-truth-only pass. Each probe owns a oneTBB arena of that many threads. A run whose frames
// are dark or whose truth has no surface reports an error instead of a time.
#include <benchmark/benchmark.h>

#include <map>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <tuple>

#include "sim/session/sim_session.h"

namespace d3d {
namespace {

// Why a burst's frames are not a sane render of the typodont ("" if they are): every frame of the
// burst present and at least a fifth of its pixels lit above the dark level.
std::string CheckFrames(const Burst& b, int width, int height) {
  if (b.frames.size() != 4) return "not 4 frames";
  for (const auto& f : b.frames) {
    if (f.image.rows != height || f.image.cols != width) return "a frame has the wrong size";
    cv::Mat lit;
    cv::compare(f.image, 20, lit, cv::CmpTypes::CMP_GT);  // 8-bit sensor, dark level ≈ 0–5 DN
    if (cv::countNonZero(lit) < width * height / 5) return "a frame is dark";
  }
  return "";
}

// The same for a truth map: at least half of the pixels see a surface at a finite depth.
std::string CheckTruth(const FrameTruth& t) {
  if (!t.has_maps()) return "no truth maps";
  const cv::Mat finite = t.depth_mm == t.depth_mm;  // false where NaN
  if (cv::countNonZero(finite) < t.depth_mm.rows * t.depth_mm.cols / 2)
    return "the truth has too few valid points";
  return "";
}

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
  {                     // before timing: a burst with truth must be sane
    const Burst b = session.RenderBurst(index, true);
    std::string why = CheckFrames(b, width, height);
    if (why.empty()) why = CheckTruth(b.reference_truth);
    if (!why.empty()) {
      state.SkipWithError(("burst with truth: " + why).c_str());
      return;
    }
  }
  Burst b;
  for (auto _ : state) {
    b = session.RenderBurst(index++, false);
    benchmark::DoNotOptimize(b.frames.back().image.data);
  }
  if (const std::string why = CheckFrames(b, width, height);
      !why.empty()) {  // the last timed burst too
    state.SkipWithError(("last burst: " + why).c_str());
    return;
  }
  state.SetItemsProcessed(state.iterations());
  state.SetLabel(std::to_string(width) + "x" + std::to_string(height) + ", " +
                 std::to_string(threads) + " thread(s)");
}
BENCHMARK(BM_RenderBurst)
    ->Args({640, 480, 1})
    ->Args({640, 480, 2})
    ->Args({1280, 1024, 2})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(3.0);

void BM_RenderTruthOnly(benchmark::State& state) {
  const int threads = static_cast<int>(state.range(0));
  SimSession& session = Session(640, 480, threads);
  int64_t index = 300;
  FrameTruth truth;
  for (auto _ : state) {
    session.probe().RenderTruth(session.trajectory().WorldFromProbe(session.BurstStartNs(index++)),
                                &truth);
    benchmark::DoNotOptimize(truth.depth_mm.data);
  }
  if (const std::string why = CheckTruth(truth); !why.empty()) {
    state.SkipWithError(why.c_str());
    return;
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_RenderTruthOnly)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

}  // namespace
}  // namespace d3d

BENCHMARK_MAIN();
