// d3d-real-fringe: phase + unwrapping on real fringe images (pipeline/recon/real_fringe.h).
#include <cstdio>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <string>

#include "common/options/option_registry.h"
#include "pipeline/recon/real_fringe.h"

namespace {

using namespace d3d;
using namespace d3d::real_fringe;

// Everything the command line sets.
struct ToolOptions {
  std::string data = "../shared/data";
  std::string out = "real_fringe_out";
  std::string algo = "adaptive-harmonic";
  KaminoOptions kamino;
};

void DeclareOptions(OptionRegistry* options, ToolOptions* o) {
  KaminoOptions& ko = o->kamino;
  options->Add("--data", &o->data, "the shared data directory (holds fringe/)");
  options->Add("--out", &o->out, "output directory for the PNGs");
  options->Add("--algorithm", &o->algo, "phase algorithm: standard, lut-gamma, adaptive-harmonic");
  options->Add("--gamma", &ko.gamma, "projector gamma of kamino410");
  options->Add("--margin", &ko.bound_margin_px, "Gray-code bound margin m, projector px");
  options->Add("--tol", &ko.agree_tol_px, "agreement tolerance, projector px");
  options->Add("--min-region", &ko.min_region_pixels, "UnwrapOptions::min_region_pixels (kamino)");
  options->Add("--edge-ratio", &ko.modulation_edge_ratio,
               "QualityOptions::modulation_edge_ratio (0 = off)");
  options->Add(
      "--depth-fraction", &ko.depth_fraction,
      "UnwrapOptions::depth_fraction (kamino; lower it to see what rejected regions would give)");
  options->Flag("!--no-cross-check", &ko.cross_check, "skip the 100-px set comparison");
  options->Add("--monotonic-x", &ko.monotonic_x, "UnwrapOptions::monotonic_x (kamino)");
}

// kamino410/object2: the Gray-code-bounded unwrap, its checks printed and its PNGs written to
// `out`. Returns false (after printing why) when the set could not be processed.
bool RunKaminoReport(const KaminoOptions& ko, const std::string& out) {
  KaminoReport kr;
  if (Status s = RunKamino(ko, &kr); !s.ok()) {
    std::fprintf(stderr, "kamino410: %s\n", s.ToString().c_str());
    return false;
  }
  std::printf(
      "kamino410/object2 (%d x %d), %s, gamma %.2f, margin %.1f px, tol %.1f px  [%.2f s]\n",
      kr.width, kr.height, PhaseAlgorithmName(ko.algorithm), ko.gamma, ko.bound_margin_px,
      ko.agree_tol_px, kr.seconds);
  std::printf(
      "  frame order (pat01, pat00, pat02): mean |phi - author's atan2| = %.4f rad (naive "
      "pat00,01,02: %.3f)\n",
      kr.order_check_rad, kr.order_check_swapped_rad);
  std::printf("  Gray x cell grows with camera x at %.1f %% of cell changes\n",
              100.0 * kr.monotonic_corr);
  std::printf(
      "  valid: phase %lld, Gray %lld, unwrapped %lld (regions %d, anchored %d, rejected %d, small "
      "%d)\n",
      static_cast<long long>(kr.phase_valid), static_cast<long long>(kr.gray_valid),
      static_cast<long long>(kr.unwrapped_valid), kr.stats.regions_total, kr.regions_anchored,
      kr.stats.regions_rejected, kr.stats.regions_small);
  std::printf("  dropped: discontinuity %lld, conflict %lld, small %lld, rejected %lld\n",
              static_cast<long long>(kr.stats.pixels_discontinuity),
              static_cast<long long>(kr.stats.pixels_conflict),
              static_cast<long long>(kr.stats.pixels_small),
              static_cast<long long>(kr.stats.pixels_rejected));
  std::printf(
      "  AGREEMENT with Gray code: %.4f %% (%lld of %lld both valid), median px outside cell "
      "%.2f\n",
      100.0 * kr.agree_share, static_cast<long long>(kr.agree),
      static_cast<long long>(kr.both_valid), kr.median_abs_err_px);
  std::printf("  Gray decoding vs vizualized.png: %.4f %% of %lld (viz valid %lld)\n",
              100.0 * kr.gray_viz_share, static_cast<long long>(kr.gray_viz_both),
              static_cast<long long>(kr.viz_valid));
  std::printf(
      "  our column vs vizualized.png x: median |c - x| %.3f px (signed %+.3f), within 2 px %.4f "
      "%% of %lld\n",
      kr.c_viz_median_px, kr.c_viz_signed_median_px, 100.0 * kr.c_viz_within2_share,
      static_cast<long long>(kr.c_viz_both));
  std::printf(
      "  column from the 66.67-px set vs the 100-px set: median %.3f px (signed %+.3f), RMS %.3f "
      "px over %lld px\n",
      kr.cross_median_px, kr.cross_signed_median_px, kr.cross_rms_px,
      static_cast<long long>(kr.cross_count));
  cv::imwrite(out + "/kamino_gray_disagreement.png", kr.disagreement);
  cv::imwrite(out + "/kamino_viz_disagreement.png", kr.viz_diff);
  cv::imwrite(out + "/kamino_unwrapped_phase.png", PhaseImage(kr.Phi));
  return true;
}

// kylemcdonald/`name`: a relative unwrap checked for continuity, printed and its PNG written to
// `out`. Returns false (after printing why) when the set could not be processed.
bool RunRelativeReport(const std::string& data, const char* name, const std::string& out) {
  RelativeOptions ro;
  ro.dir = data + "/fringe/kylemcdonald/" + name;
  RelativeReport rr;
  if (Status s = RunRelative(ro, &rr); !s.ok()) {
    std::fprintf(stderr, "%s: %s\n", name, s.ToString().c_str());
    return false;
  }
  std::printf(
      "kylemcdonald/%s (%d x %d) [%.2f s]: phase valid %lld, unwrapped %lld (%.1f %%, %d of %d "
      "regions), "
      "continuity %.4f %% of %lld pairs\n",
      name, rr.width, rr.height, rr.seconds, static_cast<long long>(rr.phase_valid),
      static_cast<long long>(rr.unwrapped_valid), 100.0 * rr.coverage, rr.regions_anchored,
      rr.regions_total, 100.0 * rr.continuity_share, static_cast<long long>(rr.pairs));
  cv::imwrite(out + "/" + name + "_unwrapped_phase.png", PhaseImage(rr.Phi));
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options(
      "d3d-real-fringe: phase + unwrapping on real fringe images (../shared/data/fringe). On "
      "kamino410/object2 "
      "the 3-step 66.67-px set is unwrapped with the Gray code as phase bounds and compared with "
      "the decoded "
      "Gray cells and the author's vizualized.png; on kylemcdonald/{zhang,kyle} a relative unwrap "
      "is checked "
      "for continuity. Writes PNGs to --out.");
  ToolOptions o;
  DeclareOptions(&options, &o);
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;
  KaminoOptions& ko = o.kamino;
  if (o.algo == "standard")
    ko.algorithm = PhaseAlgorithm::kStandard;
  else if (o.algo == "lut-gamma")
    ko.algorithm = PhaseAlgorithm::kLutGamma;
  else if (o.algo == "adaptive-harmonic")
    ko.algorithm = PhaseAlgorithm::kAdaptiveHarmonic;
  else {
    std::fprintf(stderr, "unknown --algorithm %s\n", o.algo.c_str());
    return 2;
  }
  std::filesystem::create_directories(o.out);
  int rc = 0;
  ko.dir = o.data + "/fringe/kamino410/object2";
  if (!RunKaminoReport(ko, o.out)) rc = 1;
  for (const char* name : {"zhang", "kyle"})
    if (!RunRelativeReport(o.data, name, o.out)) rc = 1;
  std::printf("PNGs in %s\n", o.out.c_str());
  return rc;
}
