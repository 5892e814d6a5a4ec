// Row-parallel loops for the per-pixel passes of an image chain (phase, triangulation, normals).
//
// ForRowBlocks(rows, threads, fn) calls fn(y_begin, y_end) on consecutive blocks of rows that
// cover [0, rows) exactly once: with threads ≤ 1 (or too few rows to split) once, fn(0, rows), on
// the calling thread; otherwise as oneTBB tasks of at most kRowBlock rows (tbb::parallel_for,
// simple partitioner), on the calling thread and the pool's workers. How many run at once is the
// process's oneTBB cap (tbb::global_control, e.g. d3d-scan --threads), not `threads`.
//
// Results do not depend on the schedule when fn writes only its own rows (and per-thread scratch)
// and reads nothing another block writes: every pixel is computed by the same code in the same
// order whichever thread runs its block, so threads = 1 and threads = 2 give the same bits.
//
// Threads: the caller's thread runs blocks and waits for the others; a oneTBB worker runs a block
// only while the caller is in this call. While it waits, the caller may also pick up other oneTBB
// tasks (oneTBB's work stealing; see its "Work Isolation"): the results do not depend on it.
#pragma once

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

namespace d3d {

inline constexpr int kRowBlock = 16;  // rows per task: 15 tasks for a 320 × 240 view

template <class F>
void ForRowBlocks(int rows, int threads, F&& fn) {
  if (rows <= 0) return;
  if (threads <= 1 || rows < 2 * kRowBlock) {
    fn(0, rows);
    return;
  }
  tbb::parallel_for(
      tbb::blocked_range<int>(0, rows, kRowBlock),
      [&fn](const tbb::blocked_range<int>& r) { fn(r.begin(), r.end()); },
      tbb::simple_partitioner());
}

}  // namespace d3d
