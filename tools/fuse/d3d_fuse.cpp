// d3d-fuse: the whole offline chain on the virtual probe or a folder of bursts:
// burst → reconstruction (pipeline/recon) → frame-to-model registration with loss detection and
// relocalisation (pipeline/register) → TSDF fusion (pipeline/fuse) → pose graph with loop
// closures → mesh (PLY, STL, mm) → evaluation against the scene (pipeline/eval) when it is known.
// The scan options are d3d-scan's (pipeline/chain/scan_flags.h); the run is offline_scan.h's.
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "common/options/option_registry.h"
#include "pipeline/chain/scan_flags.h"
#include "tools/fuse/offline_scan.h"

namespace fs = std::filesystem;
using namespace d3d;

namespace {

void DeclareFuseArgs(OptionRegistry* r, OfflineScanArgs* a) {
  r->Add("--sim", &a->sim_model,
         "scan with the virtual probe: 'typodont' or a mesh file (PLY/STL/OBJ, mm)");
  r->Add("--bursts", &a->bursts_dir,
         "a d3d-sim output folder (calibration.json, bursts/NNNNNN/, scene.ply)");
  r->Add("--trajectory", &a->trajectory,
         "--sim: a scan style (" + ScanStyleList() + "), quadrant or a TUM file");
  r->Add("--seed", &a->seed, "--sim: seed of hand motion and sensor noise");
  r->Add("--out", &a->out_dir, "output folder").Required();
  r->Add("--every", &a->every, "use every N-th burst (a lower burst rate, for quick runs)");
  r->Add("--first", &a->first, "first burst index");
  r->Add("--max-bursts", &a->max_bursts, "stop after this many bursts used (-1: all)");
  r->Flag("--no-eval", &a->no_eval, "skip the evaluation against the scene");
  r->Flag("--coverage-ceiling", &a->coverage_ceiling,
          "--sim: also report coverage_seen_pct, the share of the reference tooth surface that the "
          "bursts saw\n"
          "(lit, in the measurement volume, within the fusion's incidence limit): what "
          "coverage_pct can reach");
  r->Flag("--quiet", &a->quiet, "no progress bar");
  r->Flag("--truth-poses", &a->truth_poses,
          "debug: no registration; every view is fused at its true pose (from the virtual probe or "
          "the bursts'\n"
          "truth), which measures the fusion-only error floor");
  r->Add("--trace", &a->trace_path,
         "debug: write one line per burst (burst, accepted, state, icp rmse um, overlap, eigen "
         "ratio,\n"
         "correspondences, new keyframe, loops, true step error um / deg; with --sim also the "
         "registered view's\n"
         "RMS error um, wrong fringe orders % and tooth pixels reconstructed %) to this file");
  r->Add("--pose-graph", &a->graph_path,
         "debug: write the pose graph to this file: one line per keyframe (node, view, burst, its "
         "world_from_cam\n"
         "in the graph: optimised, or with --no-loops the tracked one; and, when known, the true "
         "one: t mm,\n"
         "quaternion x y z w) and per edge (from, to, loop, measured from_from_to, its 6x6 "
         "information\n"
         "row-major, zeros when the edge uses its sigmas)");
}

int Fail(const Status& s) {
  std::fprintf(stderr, "d3d-fuse: %s\n", s.ToString().c_str());
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options(
      "d3d-fuse: registers and fuses a scan into one mesh (mm) and evaluates it when the truth is "
      "known.\n"
      "Input: the virtual probe (--sim MODEL) or a folder of bursts written by d3d-sim (--bursts "
      "DIR).\n"
      "Output: DIR/scan.ply, DIR/scan.stl, DIR/poses.txt (TUM, mm), DIR/report.json, "
      "DIR/heatmap.png,\n"
      "DIR/truth_poses.txt (the true poses of the fused views, scene frame, when the source knows "
      "them).");
  OfflineScanArgs args;
  ScanFlags flags;
  ScanOptions scan;
  bool json = false;
  DeclareFuseArgs(&options, &args);
  DeclareScanFlags(&options, &flags, &scan);
  options.Flag("--json", &json, "print report.json as one line on stdout");
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;
  if (args.sim_model.empty() == args.bursts_dir.empty()) {
    std::fprintf(stderr, "d3d-fuse: give exactly one of --sim MODEL or --bursts DIR\n");
    return 2;
  }
  if (args.every < 1) {
    std::fprintf(stderr, "d3d-fuse: --every must be >= 1\n");
    return 2;
  }
  if (const Status s = ApplyScanFlags(flags, args.every, &scan);
      !s.ok()) {  // a lower burst rate: larger steps
    std::fprintf(stderr, "d3d-fuse: %s\n", s.ToString().c_str());
    return 2;
  }
  try {
    std::error_code ec;
    fs::create_directories(args.out_dir, ec);
    if (ec) return Fail(IoError("cannot create '" + args.out_dir + "'"));
    OfflineSource source;
    if (const Status s = OfflineSource::Open(args, &source); !s.ok()) return Fail(s);
    ScanResult result;
    if (const Status s = RunOfflineScan(args, source, flags, scan, &result); !s.ok())
      return Fail(s);
    if (json) {
      std::printf("%s\n", result.report.dump().c_str());
    } else {
      nlohmann::json brief = result.report;
      brief.erase("events");
      std::printf("%s\n", brief.dump(2).c_str());
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-fuse: %s\n", e.what());
    return 2;
  }
  return 0;
}
