// The calling process's resource figures for reports and benchmarks (getrusage, RUSAGE_SELF).
#pragma once

namespace d3d {

// Peak resident set size so far (MiB; Linux's ru_maxrss is in KiB).
double PeakRssMiB();
// User + system CPU time of the whole process so far (ms, every thread).
double ProcessCpuMs();

}  // namespace d3d
