#!/usr/bin/env bash
# d3d-live-latency: the host's live criteria measured the way issue 6 states them, repeatably.
#
# The virtual probe's full-arch typodont scan (450 bursts, or --bursts) is recorded once (d3d-probe --sim typodont +
# d3d-record, 640 x 480 at 30 Hz), then published again in real time (d3d-replay --rate 1) to a live
# d3d-scan on the same machine, --runs times. Each run's report gives bursts/s, latency p50/p95/max
# (capture to preview), preview fps, peak RSS and the trueness; the table ends with how many runs
# met >= 28 bursts/s, p95 <= 100 ms and preview >= 15 fps.
#
# --cpu-quota C runs d3d-scan and d3d-replay in a CPU cgroup limited to C cores' worth of time
# (CFS bandwidth, per 10 ms period; cgroup v1 'cpu' or v2 'cpu.max', needs root): a slower machine,
# to see how much of the machine the criteria need. The machine's own speed still varies from hour
# to hour (a run's figures move by more than the builds compared differ): compare builds in
# interleaved runs (--bin A, --bin B, A, B, ...).
set -euo pipefail
# The whole script is read before it runs (the braces): a run of hours survives an edit or a pull of it.
{

usage() {
  cat <<'EOF'
Usage: tools/bench/live_latency.sh [OPTIONS] [-- D3D-SCAN OPTIONS...]

Live d3d-scan against a recording published in real time (d3d-replay --rate 1): the figures of
issue 6's live criteria, per run, and how many runs met them.

Options:
  --runs N           live runs (default 3)
  --cpu-quota C      limit d3d-scan + d3d-replay to C cores' worth of CPU time (e.g. 1.1; root, cgroup)
  --bursts N         bursts of the full-arch path recorded (default 450: 15 s, half the arch;
                     1490: the whole arch)
  --recording FILE   recording to publish (default: OUT/typodont_full_arch_N.d3drec, recorded once
                     from the virtual probe when missing)
  --bin DIR          folder of d3d-scan, d3d-replay, d3d-probe, d3d-record (default: build/bin)
  --out DIR          where the runs' outputs go (default: live_latency_out)
  --domain D         DDS domain id (default 77)
  -h, --help         this help
Anything after -- is passed to d3d-scan (e.g. -- --icp-threads 1).
EOF
}

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
runs=3 quota="" rec="" bursts=450 bin="$root/build/bin" out="live_latency_out" domain=77
extra=()
source "$root/tools/lib/setup.sh"
source "$root/tools/lib/bench.sh"
while [ $# -gt 0 ]; do
  if d3d_bench_option "$1" "${2:-}"; then shift 2; continue; fi
  case "$1" in
    --runs) runs=$2; shift 2 ;;
    --cpu-quota) quota=$2; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    --) shift; extra=("$@"); break ;;
    *) echo "live_latency: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
done
[[ "$runs" =~ ^[1-9][0-9]*$ ]] || { echo "live_latency: --runs must be a positive integer" >&2; exit 2; }
for tool in d3d-scan d3d-replay d3d-probe d3d-record; do
  [ -x "$bin/$tool" ] || { echo "live_latency: $bin/$tool not found (build first: tools/demo.sh, or --bin)" >&2; exit 2; }
done
mkdir -p "$out"
rec=${rec:-$out/typodont_full_arch_$bursts.d3drec}
d3d_record_full_arch "$bin" "$rec" "$out" "$domain" "$bursts" || exit 1

# The CPU cgroup (removed on exit).
cg=""
cleanup() { [ -n "$cg" ] && [ -d "$cg" ] && rmdir "$cg" 2>/dev/null || true; }
trap cleanup EXIT
if [ -n "$quota" ]; then
  quota_us=$(python3 -c "import sys; c=float(sys.argv[1]); assert c > 0; print(int(round(c*10000)))" "$quota") ||
    { echo "live_latency: --cpu-quota must be a number of cores > 0" >&2; exit 2; }
  if [ -w /sys/fs/cgroup/cpu ] && [ -f /sys/fs/cgroup/cpu/cpu.cfs_quota_us ]; then  # cgroup v1
    cg=/sys/fs/cgroup/cpu/d3d-live-$$
    mkdir "$cg"
    echo 10000 > "$cg/cpu.cfs_period_us"
    echo "$quota_us" > "$cg/cpu.cfs_quota_us"
  elif [ -f /sys/fs/cgroup/cgroup.controllers ] && [ -w /sys/fs/cgroup ]; then  # cgroup v2
    grep -qw cpu /sys/fs/cgroup/cgroup.subtree_control || echo +cpu > /sys/fs/cgroup/cgroup.subtree_control
    cg=/sys/fs/cgroup/d3d-live-$$
    mkdir "$cg"
    echo "$quota_us 10000" > "$cg/cpu.max"
  else
    echo "live_latency: --cpu-quota needs a writable CPU cgroup (root; cgroup v1 'cpu' or v2 with the cpu controller)" >&2
    exit 2
  fi
fi

echo "live_latency: $runs run(s), recording $rec${quota:+, CPU limited to $quota cores}${extra[*]:+, d3d-scan ${extra[*]}}"
for i in $(seq 1 "$runs"); do
  dir="$out/run$i"
  rm -rf "$dir"
  mkdir -p "$dir"
  printf 'live_latency: run %d/%d ... ' "$i" "$runs"
  (
    [ -n "$cg" ] && echo "$BASHPID" > "$cg/cgroup.procs"
    "$bin/d3d-scan" --domain "$domain" --policy live --headless --reference typodont --sim-trajectory full-arch \
      --sim-seed 1 --idle-exit 2 --quiet --out "$dir" "${extra[@]}" > "$dir/scan.log" 2>&1 &
    scan=$!
    "$bin/d3d-replay" "$rec" --rate 1 --domain "$domain" > "$dir/replay.log" 2>&1
    wait "$scan"
  ) || { echo "failed (see $dir/scan.log, $dir/replay.log)"; continue; }
  echo "done"
done

python3 - "$out" "$runs" <<'PY'
import json, os, sys
out, runs = sys.argv[1], int(sys.argv[2])
cols = [("bursts/s", "bursts_per_s", "%.2f"), ("p50 ms", "latency_ms_p50", "%.1f"), ("p95 ms", "latency_ms_p95", "%.1f"),
        ("max ms", "latency_ms_max", "%.0f"), ("preview fps", "preview_fps", "%.2f"),
        ("draws/s", "preview_draws_per_s", "%.2f"), ("dropped", "bursts_dropped", "%d"),
        ("peak RSS MiB", "peak_rss_mib", "%.0f"), ("trueness µm", "trueness_rms_um", "%.2f"),
        ("in model", "views_in_model", "%d"), ("processed", "bursts_processed", "%d"),
        ("lost", "tracking_lost", "%d"), ("segments", "segments_started", "%d"),
        ("apart", "segments_apart", "%d"), ("wrong", "wrong_fusions", "%d")]
print("\nrun  " + "  ".join("%12s" % c[0] for c in cols))
met = done = 0
for i in range(1, runs + 1):
    path = os.path.join(out, "run%d" % i, "report.json")
    if not os.path.exists(path):
        print("%-4d (no report)" % i)
        continue
    r = json.load(open(path))
    done += 1
    print("%-4d " % i + "  ".join("%12s" % (f % r[k] if k in r else "-") for _, k, f in cols))
    met += r["bursts_per_s"] >= 28 and r["latency_ms_p95"] <= 100 and r["preview_fps"] >= 15
print("\n%d of %d runs met >= 28 bursts/s, latency p95 <= 100 ms and preview >= 15 fps" % (met, done))
PY
exit
}
