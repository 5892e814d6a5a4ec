#include "pipeline/eval/report_json.h"

#include <cmath>

namespace d3d {

void AddCoverageFields(const TruenessReport& t, nlohmann::json* j) {
  (*j)["coverage_pct"] = t.coverage_pct;
  const auto put = [&](const char* key, double value) {
    if (std::isfinite(value)) (*j)[key] = value;
  };
  put("gap_area_pct", t.gap_area_pct);
  put("coverage_gap_pct", t.coverage_gap_pct);
  put("coverage_open_pct", t.coverage_open_pct);
}

void AddTruenessFields(const TruenessReport& t, nlohmann::json* j) {
  (*j)["trueness_rms_um"] = t.rms_um;
  (*j)["trueness_mean_um"] = t.mean_um;
  (*j)["trueness_mean_abs_um"] = t.mean_abs_um;
  (*j)["trueness_p95_um"] = t.p95_um;
  (*j)["best_fit_rmse_um"] = t.alignment_rmse_mm * 1000;
  AddCoverageFields(t, j);
  if (t.teeth_points > 0) {
    (*j)["trueness_teeth_rms_um"] = t.teeth_rms_um;
    (*j)["trueness_teeth_mean_um"] = t.teeth_mean_um;
    (*j)["trueness_teeth_p95_um"] = t.teeth_p95_um;
    (*j)["trueness_teeth_points"] = t.teeth_points;
  }
}

}  // namespace d3d
