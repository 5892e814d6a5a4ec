// d3d-real-fringe: phase + unwrapping on real fringe images (tools/recon/real_fringe.h).
#include <cstdio>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <string>

#include "tools/recon/real_fringe.h"
#include <CLI/CLI.hpp>

int main(int argc, char** argv) {
  using namespace d3d;
  using namespace d3d::real_fringe;
  CLI::App app{
      "d3d-real-fringe: phase + unwrapping on real fringe images (../shared/data/fringe). On kamino410/object2 "
      "the 3-step 66.67-px set is unwrapped with the Gray code as phase bounds and compared with the decoded "
      "Gray cells and the author's vizualized.png; on kylemcdonald/{zhang,kyle} a relative unwrap is checked "
      "for continuity. Writes PNGs to --out."};
  std::string data = "../shared/data";
  std::string out = "real_fringe_out";
  std::string algo = "adaptive-harmonic";
  KaminoOptions ko;
  app.add_option("--data", data, "the shared data directory (holds fringe/)")->capture_default_str();
  app.add_option("--out", out, "output directory for the PNGs")->capture_default_str();
  app.add_option("--algorithm", algo, "phase algorithm: standard, lut-gamma, adaptive-harmonic")->capture_default_str();
  app.add_option("--gamma", ko.gamma, "projector gamma of kamino410")->capture_default_str();
  app.add_option("--margin", ko.bound_margin_px, "Gray-code bound margin m, projector px")->capture_default_str();
  app.add_option("--tol", ko.agree_tol_px, "agreement tolerance, projector px")->capture_default_str();
  app.add_option("--min-region", ko.min_region_pixels, "UnwrapOptions::min_region_pixels (kamino)")->capture_default_str();
  app.add_option("--edge-ratio", ko.modulation_edge_ratio, "QualityOptions::modulation_edge_ratio (0 = off)")
      ->capture_default_str();
  app.add_option("--depth-fraction", ko.depth_fraction,
                 "UnwrapOptions::depth_fraction (kamino; lower it to see what rejected regions would give)")
      ->capture_default_str();
  app.add_flag("!--no-cross-check", ko.cross_check, "skip the 100-px set comparison");
  app.add_option("--monotonic-x", ko.monotonic_x, "UnwrapOptions::monotonic_x (kamino)")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  if (algo == "standard") ko.algorithm = PhaseAlgorithm::kStandard;
  else if (algo == "lut-gamma") ko.algorithm = PhaseAlgorithm::kLutGamma;
  else if (algo == "adaptive-harmonic") ko.algorithm = PhaseAlgorithm::kAdaptiveHarmonic;
  else {
    std::fprintf(stderr, "unknown --algorithm %s\n", algo.c_str());
    return 2;
  }
  std::filesystem::create_directories(out);
  int rc = 0;

  ko.dir = data + "/fringe/kamino410/object2";
  KaminoReport kr;
  if (Status s = RunKamino(ko, &kr); !s.ok()) {
    std::fprintf(stderr, "kamino410: %s\n", s.ToString().c_str());
    rc = 1;
  } else {
    std::printf("kamino410/object2 (%d x %d), %s, gamma %.2f, margin %.1f px, tol %.1f px  [%.2f s]\n", kr.width,
                kr.height, PhaseAlgorithmName(ko.algorithm), ko.gamma, ko.bound_margin_px, ko.agree_tol_px, kr.seconds);
    std::printf("  frame order (pat01, pat00, pat02): mean |phi - author's atan2| = %.4f rad (naive pat00,01,02: %.3f)\n",
                kr.order_check_rad, kr.order_check_swapped_rad);
    std::printf("  Gray x cell grows with camera x at %.1f %% of cell changes\n", 100.0 * kr.monotonic_corr);
    std::printf("  valid: phase %lld, Gray %lld, unwrapped %lld (regions %d, anchored %d, rejected %d, small %d)\n",
                static_cast<long long>(kr.phase_valid), static_cast<long long>(kr.gray_valid),
                static_cast<long long>(kr.unwrapped_valid), kr.stats.regions_total, kr.regions_anchored,
                kr.stats.regions_rejected, kr.stats.regions_small);
    std::printf("  dropped: discontinuity %lld, conflict %lld, small %lld, rejected %lld\n",
                static_cast<long long>(kr.stats.pixels_discontinuity), static_cast<long long>(kr.stats.pixels_conflict),
                static_cast<long long>(kr.stats.pixels_small), static_cast<long long>(kr.stats.pixels_rejected));
    std::printf("  AGREEMENT with Gray code: %.4f %% (%lld of %lld both valid), median px outside cell %.2f\n",
                100.0 * kr.agree_share, static_cast<long long>(kr.agree), static_cast<long long>(kr.both_valid),
                kr.median_abs_err_px);
    std::printf("  Gray decoding vs vizualized.png: %.4f %% of %lld (viz valid %lld)\n", 100.0 * kr.gray_viz_share,
                static_cast<long long>(kr.gray_viz_both), static_cast<long long>(kr.viz_valid));
    std::printf("  our column vs vizualized.png x: median |c - x| %.3f px (signed %+.3f), within 2 px %.4f %% of %lld\n",
                kr.c_viz_median_px, kr.c_viz_signed_median_px, 100.0 * kr.c_viz_within2_share,
                static_cast<long long>(kr.c_viz_both));
    std::printf("  column from the 66.67-px set vs the 100-px set: median %.3f px (signed %+.3f), RMS %.3f px over %lld px\n",
                kr.cross_median_px, kr.cross_signed_median_px, kr.cross_rms_px, static_cast<long long>(kr.cross_count));
    cv::imwrite(out + "/kamino_gray_disagreement.png", kr.disagreement);
    cv::imwrite(out + "/kamino_viz_disagreement.png", kr.viz_diff);
    cv::imwrite(out + "/kamino_unwrapped_phase.png", PhaseImage(kr.Phi));
  }
  for (const char* name : {"zhang", "kyle"}) {
    RelativeOptions ro;
    ro.dir = data + "/fringe/kylemcdonald/" + name;
    RelativeReport rr;
    if (Status s = RunRelative(ro, &rr); !s.ok()) {
      std::fprintf(stderr, "%s: %s\n", name, s.ToString().c_str());
      rc = 1;
      continue;
    }
    std::printf("kylemcdonald/%s (%d x %d) [%.2f s]: phase valid %lld, unwrapped %lld (%.1f %%, %d of %d regions), "
                "continuity %.4f %% of %lld pairs\n",
                name, rr.width, rr.height, rr.seconds, static_cast<long long>(rr.phase_valid),
                static_cast<long long>(rr.unwrapped_valid), 100.0 * rr.coverage, rr.regions_anchored,
                rr.regions_total, 100.0 * rr.continuity_share, static_cast<long long>(rr.pairs));
    cv::imwrite(out + "/" + name + "_unwrapped_phase.png", PhaseImage(rr.Phi));
  }
  std::printf("PNGs in %s\n", out.c_str());
  return rc;
}
