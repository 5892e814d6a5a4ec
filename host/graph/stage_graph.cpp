#include "host/graph/stage_graph.h"

#include <cmath>

namespace d3d {

const char* EdgePolicyName(EdgePolicy p) { return p == EdgePolicy::kLive ? "live" : "lossless"; }

double PercentileOf(std::vector<double> v, double pct) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const double rank = std::ceil(pct / 100.0 * static_cast<double>(v.size()));
  const size_t i = static_cast<size_t>(std::clamp(rank, 1.0, static_cast<double>(v.size()))) - 1;
  return v[i];
}

}  // namespace d3d
