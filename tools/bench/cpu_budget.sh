#!/usr/bin/env bash
# d3d-cpu-budget: the host's CPU per burst, stage by stage, of this build against an older commit
# built beside it (issue 51), side by side on one machine in alternating runs (A B A B ...).
#
# The virtual probe's full-arch typodont recording (450 bursts by default) (made once, shared with
# live_latency.sh) is replayed losslessly through d3d-scan by each build: every burst processed, so
# the report's stage CPU ms per burst compare like for like. With --live the same recording is also
# published in real time to a live d3d-scan (live_latency.sh, optionally at --cpu-quota): bursts/s,
# processed share and latency. d3d-bench-recon's single-thread 640 x 480 reconstruction is timed by
# each build too. Every run's result is checked before its time is shown: a run with no burst
# processed, no trueness or a trueness above 100 µm is marked and left out of the medians.
set -euo pipefail
{

usage() {
  cat <<'EOF'
Usage: tools/bench/cpu_budget.sh [OPTIONS] [-- D3D-SCAN OPTIONS...]

CPU ms per burst per stage (reconstruct, register, fuse), bursts/s and latency of this build (B)
against a base (A), in alternating runs; medians and ranges.

Options:
  --base COMMIT      the base build: COMMIT built (Release) in a worktree under OUT (default 4a94ecd,
                     issue 51's reference); reused when already built
  --base-bin DIR     the base build's bin folder instead of --base
  --bin DIR          this build's bin folder (default: build/bin)
  --runs N           lossless replays per build (default 3)
  --live             also N live runs per build at real time (live_latency.sh)
  --cpu-quota C      --live: limit d3d-scan + d3d-replay to C cores' worth of CPU (root, cgroup)
  --bursts N         bursts of the full-arch path recorded (default 450: 15 s, half the arch;
                     1490: the whole arch)
  --recording FILE   the recording (default: OUT/typodont_full_arch_N.d3drec, made once)
  --out DIR          outputs (default: cpu_budget_out)
  --domain D         DDS domain id for recording and live runs (default 78)
  -h, --help         this help
Anything after -- is passed to every d3d-scan instead of the default --threads 1 (one thread per
stage, as live: a stage's CPU figure is its thread's, and work lent to a thread pool is not in it).
EOF
}

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
source "$root/tools/lib/setup.sh"
source "$root/tools/lib/bench.sh"
base=4a94ecd base_bin="" bin="$root/build/bin" runs=3 live=0 quota="" rec="" bursts=450 out="cpu_budget_out" domain=78
extra=(--threads 1)
while [ $# -gt 0 ]; do
  if d3d_bench_option "$1" "${2:-}"; then shift 2; continue; fi
  case "$1" in
    --base) base=$2; shift 2 ;;
    --base-bin) base_bin=$2; shift 2 ;;
    --runs) runs=$2; shift 2 ;;
    --live) live=1; shift ;;
    --cpu-quota) quota=$2; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    --) shift; extra=("$@"); break ;;
    *) echo "cpu_budget: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
done
[[ "$runs" =~ ^[1-9][0-9]*$ ]] || { echo "cpu_budget: --runs must be a positive integer" >&2; exit 2; }
tools=(d3d-scan d3d-replay d3d-probe d3d-record d3d-bench-recon)
for t in "${tools[@]}"; do
  [ -x "$bin/$t" ] || { echo "cpu_budget: $bin/$t not found (build first: tools/demo.sh, or --bin)" >&2; exit 2; }
done
mkdir -p "$out"
out=$(cd "$out" && pwd)
if [ -z "$base_bin" ]; then
  base_bin=$(d3d_build_commit "$base" "$out/base-$base" "${tools[@]}") || exit 1
fi
for t in "${tools[@]}"; do
  [ -x "$base_bin/$t" ] || { echo "cpu_budget: $base_bin/$t not found" >&2; exit 2; }
done
rec=${rec:-$out/typodont_full_arch_$bursts.d3drec}
d3d_record_full_arch "$bin" "$rec" "$out" "$domain" "$bursts" || exit 1

echo "cpu_budget: A = $base_bin, B = $bin; $runs lossless run(s) each${extra[*]:+, d3d-scan ${extra[*]}}"
for i in $(seq 1 "$runs"); do
  for ab in A B; do
    b=$bin
    [ "$ab" = A ] && b=$base_bin
    dir="$out/lossless_${ab}$i"
    rm -rf "$dir"
    printf 'cpu_budget: lossless %s run %d/%d ... ' "$ab" "$i" "$runs"
    # bash's time keyword: the process's user + system CPU seconds (all threads) into DIR.cpu.
    TIMEFORMAT='%U %S'
    if { time "$b/d3d-scan" --replay "$rec" --no-preview --quiet --reference typodont --sim-trajectory full-arch \
      --sim-seed 1 --out "$dir" "${extra[@]}" > "$dir.log" 2>&1; } 2> "$dir.cpu"; then echo done; else echo "failed (see $dir.log)"; fi
    printf 'cpu_budget: d3d-bench-recon %s ... ' "$ab"
    "$b/d3d-bench-recon" --benchmark_filter='640/480/1/' --benchmark_format=json > "$out/recon_${ab}$i.json" 2> /dev/null &&
      echo done || echo "failed"
  done
done
if ((live)); then
  for i in $(seq 1 "$runs"); do
    for ab in A B; do
      b=$bin
      [ "$ab" = A ] && b=$base_bin
      echo "cpu_budget: live $ab run $i/$runs"
      "$root/tools/bench/live_latency.sh" --runs 1 --bin "$b" --recording "$rec" --out "$out/live_${ab}$i" \
        --domain "$domain" ${quota:+--cpu-quota "$quota"} -- "${extra[@]}" > "$out/live_${ab}$i.log" 2>&1 ||
        echo "cpu_budget: live $ab run $i failed (see $out/live_${ab}$i.log)"
    done
  done
fi

python3 - "$out" "$runs" "$live" <<'PY'
import json, math, os, statistics, sys
out, runs, live = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1"

def load(path):
    try:
        return json.load(open(path))
    except (OSError, ValueError):
        return None

def sane(r):  # a run is timed only when it reconstructed and fused something true
    t = r.get("trueness_rms_um") if r else None
    return r is not None and r.get("bursts_processed", 0) > 0 and isinstance(t, (int, float)) and math.isfinite(t) and t < 100

def stage_cpu(r, s):
    return r.get("stages", {}).get(s, {}).get("cpu_ms_mean")

def process_cpu(path, r):  # user + system CPU of the whole process (all threads, set-up and end) per burst
    try:
        user, system = map(float, open(path).read().split()[-2:])
    except (OSError, ValueError):
        return None
    return 1000.0 * (user + system) / max(r.get("bursts_processed", 0), 1)

def lossless_run(ab, i):
    r = load(os.path.join(out, "lossless_%s%d" % (ab, i), "report.json"))
    if r is not None:
        r["process_cpu_ms"] = process_cpu(os.path.join(out, "lossless_%s%d.cpu" % (ab, i)), r)
    return r

rows = [("reconstruct CPU ms/burst", lambda r: stage_cpu(r, "reconstruct")),
        ("register CPU ms/burst", lambda r: stage_cpu(r, "register")),
        ("fuse CPU ms/burst", lambda r: stage_cpu(r, "fuse")),
        ("3 stages CPU ms/burst", lambda r: sum(stage_cpu(r, s) or 0 for s in ("reconstruct", "register", "fuse"))),
        ("process CPU ms/burst", lambda r: r.get("process_cpu_ms")),
        ("bursts/s", lambda r: r.get("bursts_per_s")),
        ("trueness RMS um", lambda r: r.get("trueness_rms_um")),
        ("wrong fusions", lambda r: r.get("wrong_fusions"))]

def fmt(vals):
    vals = [v for v in vals if isinstance(v, (int, float))]
    if not vals:
        return "-"
    return "%.2f [%.2f-%.2f]" % (statistics.median(vals), min(vals), max(vals))

def table(title, kind, rows, loader):
    runs_ab = {ab: [loader(ab, i) for i in range(1, runs + 1)] for ab in "AB"}
    bad = {ab: sum(not sane(r) for r in rs) for ab, rs in runs_ab.items()}
    print("\n%s (median [min-max] of %d run(s) each)" % (title, runs))
    print("%-28s %26s %26s %8s" % ("", "A (base)", "B (this build)", "B/A"))
    for name, get in rows:
        a = [get(r) for r in runs_ab["A"] if sane(r)]
        b = [get(r) for r in runs_ab["B"] if sane(r)]
        a_n = [v for v in a if isinstance(v, (int, float))]
        b_n = [v for v in b if isinstance(v, (int, float))]
        ratio = "%.2f" % (statistics.median(b_n) / statistics.median(a_n)) if a_n and b_n and statistics.median(a_n) else "-"
        print("%-28s %26s %26s %8s" % (name, fmt(a), fmt(b), ratio))
    for ab in "AB":
        if bad[ab]:
            print("  %s: %d %s run(s) left out: no burst processed or no sane trueness" % (ab, bad[ab], kind))

table("Lossless replay of the recording", "lossless", rows, lossless_run)

# d3d-bench-recon, 640 x 480, one thread: the reconstruction's parts.
recon_rows = [(n, (lambda k: lambda r: r.get(k))(k)) for n, k in
              [("recon 640x480 1 thread ms", "real_time"), ("  phase ms", "phase_ms"), ("  quality ms", "quality_ms"),
               ("  unwrap ms", "unwrap_ms"), ("  triangulate ms", "triangulate_ms"), ("  points", "points")]]

def recon_run(ab, i):
    j = load(os.path.join(out, "recon_%s%d.json" % (ab, i)))
    for bm in (j or {}).get("benchmarks", []):
        if "640/480/1/" in bm.get("name", "") and not bm.get("error_occurred"):
            r = dict(bm)
            r["bursts_processed"] = 1 if bm.get("points", 0) > 0 else 0
            r["trueness_rms_um"] = 0.0
            return r
    return None

table("d3d-bench-recon", "benchmark", recon_rows, recon_run)

if live:
    live_rows = [("bursts/s", lambda r: r.get("bursts_per_s")),
                 ("processed %", lambda r: 100.0 * r["bursts_processed"] / max(r.get("bursts_received", 0), 1)),
                 ("latency p50 ms", lambda r: r.get("latency_ms_p50")),
                 ("latency p95 ms", lambda r: r.get("latency_ms_p95")),
                 ("reconstruct CPU ms/burst", lambda r: stage_cpu(r, "reconstruct")),
                 ("register CPU ms/burst", lambda r: stage_cpu(r, "register")),
                 ("fuse CPU ms/burst", lambda r: stage_cpu(r, "fuse")),
                 ("trueness RMS um", lambda r: r.get("trueness_rms_um")),
                 ("wrong fusions", lambda r: r.get("wrong_fusions"))]
    table("Live at real time (live_latency.sh)", "live", live_rows,
          lambda ab, i: load(os.path.join(out, "live_%s%d" % (ab, i), "run1", "report.json")))
PY
exit
}
