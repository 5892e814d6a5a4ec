// d3d-bench-phase: speed of the phase stage (Google Benchmark), one core.
//   build/bin/d3d-bench-phase [--benchmark_filter=...]      timings
//   build/bin/d3d-bench-phase --gamma_table                  phase RMS table (rad) on renders, then
//   exit
// Timings: PhaseEstimator::Compute on a rendered 4-frame burst of the typodont (gamma 2.2, noise),
// per algorithm, at 640×480 and 1280×1024, with and without marker detection. The estimator (its
// tables) is built once outside the timed loop, as the pipeline does.
#include <benchmark/benchmark.h>

#include <cstring>
#include <iostream>
#include <map>
#include <memory>
#include <opencv2/core.hpp>

#include "sim/eval/phase_eval.h"
#include "sim/session/sim_session.h"

namespace d3d {
namespace {

const std::vector<cv::Mat>& Frames(int width, int height) {
  static std::map<int, std::vector<cv::Mat>> cache;
  auto& frames = cache[width];
  if (frames.empty()) {
    SimSessionOptions o;
    o.camera_width = width;
    o.camera_height = height;
    o.render.threads = 2;
    std::unique_ptr<SimSession> session;
    const Status st = SimSession::Create(o, &session);
    if (!st.ok()) throw std::runtime_error(st.ToString());
    const Burst b = session->RenderBurst(300, false);
    for (int n = 0; n < 4; ++n) frames.push_back(b.frames[n].image);
  }
  return frames;
}

void BM_Phase(benchmark::State& state) {
  const int width = static_cast<int>(state.range(0)), height = static_cast<int>(state.range(1));
  const auto algorithm = static_cast<PhaseAlgorithm>(state.range(2));
  const bool marker = state.range(3) != 0;
  cv::setNumThreads(1);
  const auto& frames = Frames(width, height);
  PhaseOptions o;
  o.algorithm = algorithm;
  o.detect_marker = marker;
  const ProbeCalibration calibration = MakeDefaultProbeDesign(width, height).calibration;
  PhaseEstimator estimator(calibration.pattern, calibration.projector_gamma, o);
  PhaseMaps maps;
  for (auto _ : state) {
    const Status st = estimator.Compute(frames, &maps);
    if (!st.ok()) state.SkipWithError(st.ToString().c_str());
    benchmark::DoNotOptimize(maps.phi.data);
  }
  state.SetItemsProcessed(state.iterations() * width * height);
  state.counters["valid"] = maps.num_valid;
  state.counters["marker_px"] = maps.num_marker;
  state.SetLabel(std::string(PhaseAlgorithmName(algorithm)) + (marker ? " +marker" : "") + " " +
                 std::to_string(width) + "x" + std::to_string(height));
}
BENCHMARK(BM_Phase)
    ->ArgsProduct({{640}, {480}, {0, 1, 2}, {0, 1}})
    ->ArgsProduct({{1280}, {1024}, {0, 1, 2}, {0, 1}})
    ->Unit(benchmark::kMillisecond)
    ->MinTime(1.0);

void PrintGammaTable() {
  std::cout << "Phase RMS (rad) vs truth, lit pixels resolved by >= 8 camera px per fringe; "
               "'outside' = >= 2 projector px\n"
               "from marker stripes (4 frames), 'stripes' = >= 2 px inside them (3 frames + "
               "compensation).\n"
               "std = plain 4-step, lut = Zhang & Yau 2007 LUT from the calibrated gamma, ours = "
               "adaptive harmonic.\n";
  for (const char* scene : {"plane", "sphere", "typodont"})
    for (bool noise : {true, false})
      for (double g : {1.0, 1.6, 2.2, 2.8}) {
        phase_eval::RenderSpec rs;
        rs.scene = scene;
        rs.projector_gamma = g;
        rs.noise = noise;
        ProbeCalibration calibration;
        const Burst b = phase_eval::RenderScene(rs, &calibration);
        const auto e = phase_eval::Evaluate(b, calibration);
        std::cout << phase_eval::FormatRow(std::string(scene) +
                                               (noise ? " noisy g=" : " clean g=") +
                                               std::to_string(g).substr(0, 3),
                                           e)
                  << std::endl;
      }
}

}  // namespace
}  // namespace d3d

int main(int argc, char** argv) {
  for (int i = 1; i < argc; ++i)
    if (std::strcmp(argv[i], "--gamma_table") == 0) {
      d3d::PrintGammaTable();
      return 0;
    }
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
