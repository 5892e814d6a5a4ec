#include "pipeline/eval/report_json.h"

#include <cmath>
#include <ctime>

namespace d3d {

void AddReportHead(const ReportHead& h, nlohmann::json* j) {
  nlohmann::json& r = *j;
  r["schema"] = "d3dscan.scan_report";
  r["schema_version"] = kScanReportSchemaVersion;
  r["tool"] = h.tool;
  r["tool_version"] = h.tool_version;
  r["git_commit"] = h.git_commit;
  r["build_type"] = h.build_type;
  const std::time_t t = static_cast<std::time_t>(h.created_unix_s);
  std::tm utc{};
  gmtime_r(&t, &utc);
  char stamp[32];
  std::strftime(stamp, sizeof stamp, "%Y-%m-%dT%H:%M:%SZ", &utc);
  r["created_utc"] = stamp;
  r["probe_serial"] = h.probe_serial.empty() ? nlohmann::json() : nlohmann::json(h.probe_serial);
  r["reference"] = h.reference.empty() ? nlohmann::json() : nlohmann::json(h.reference);
}

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
