// The evaluation's figures as report.json fields, one writer for every tool that reports them
// (d3d-fuse's and d3d-scan's report through pipeline/chain, d3d-eval).
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>

#include "pipeline/eval/evaluate_scan.h"

namespace d3d {

// The head of a scan's report.json (d3d-fuse, d3d-scan): what the file is, what made it and when,
// from which probe, and what its trueness and coverage were measured against.
//   schema "d3dscan.scan_report", schema_version (kScanReportSchemaVersion), tool, tool_version,
//   git_commit, build_type, created_utc ("2026-11-29T06:40:00Z"), probe_serial and reference (null
//   when unknown / none).
inline constexpr int kScanReportSchemaVersion = 1;
struct ReportHead {
  std::string tool, tool_version, git_commit, build_type;
  std::string probe_serial;  // "" unknown
  std::string reference;     // the reference mesh (a file, or the virtual probe's scene); "" none
  int64_t created_unix_s = 0;
};
void AddReportHead(const ReportHead& head, nlohmann::json* j);

// coverage_pct, and the coverage split when the evaluation made one (EvaluateOptions::gap_mm):
// gap_area_pct, coverage_gap_pct, coverage_open_pct (each left out where it is NaN).
void AddCoverageFields(const TruenessReport& t, nlohmann::json* j);

// The trueness figures both reports share: trueness_rms_um, _mean_um, _mean_abs_um, _p95_um (µm),
// best_fit_rmse_um, the coverage fields, and, when the reference has labelled teeth,
// trueness_teeth_rms_um, _mean_um, _p95_um and _points. Each tool adds its own counts.
void AddTruenessFields(const TruenessReport& t, nlohmann::json* j);

}  // namespace d3d
