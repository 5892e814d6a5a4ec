// The evaluation's figures as report.json fields, one writer for every tool that reports them
// (d3d-fuse's and d3d-scan's report through pipeline/chain, d3d-eval).
#pragma once

#include <nlohmann/json.hpp>

#include "pipeline/eval/evaluate_scan.h"

namespace d3d {

// coverage_pct, and the coverage split when the evaluation made one (EvaluateOptions::gap_mm):
// gap_area_pct, coverage_gap_pct, coverage_open_pct (each left out where it is NaN).
void AddCoverageFields(const TruenessReport& t, nlohmann::json* j);

// The trueness figures both reports share: trueness_rms_um, _mean_um, _mean_abs_um, _p95_um (µm),
// best_fit_rmse_um, the coverage fields, and, when the reference has labelled teeth,
// trueness_teeth_rms_um, _mean_um, _p95_um and _points. Each tool adds its own counts.
void AddTruenessFields(const TruenessReport& t, nlohmann::json* j);

}  // namespace d3d
