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

}  // namespace d3d
