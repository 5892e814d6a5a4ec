// The evaluation's figures as report.json fields, one writer for every tool that reports them
// (d3d-fuse's and d3d-scan's report through pipeline/scan, d3d-eval).
#pragma once

#include <nlohmann/json.hpp>

#include "pipeline/eval/evaluate_scan.h"

namespace d3d {

// coverage_pct, and the coverage split when the evaluation made one (EvaluateOptions::gap_mm):
// gap_area_pct, coverage_gap_pct, coverage_open_pct (each left out where it is NaN).
void AddCoverageFields(const TruenessReport& t, nlohmann::json* j);

}  // namespace d3d
