#!/usr/bin/env bash
# The main job, end to end: the virtual probe (d3d-probe --sim) scans the built-in procedural
# typodont (or --model PATH) along a hand-held full-arch scan path and streams its bursts over DDS
# at 30 Hz; the host (d3d-scan) reconstructs, registers and fuses them live, shows the preview
# (a window; under xvfb-run when there is no display), and writes the mesh, the report with the
# trueness against the scene, and the preview picture.
#   tools/demo.sh [--model typodont|PATH] [--out DIR] [--seconds S] [--start S] [--policy live|lossless] [--headless]
set -euo pipefail
source "$(dirname "$0")/lib/setup.sh"
model=typodont
out="$D3D_ROOT/demo_out"
seconds=4        # of scan path streamed at 30 Hz (the probe pre-renders them first: ~7 bursts/s on 2 cores)
start=0          # s into the scan path
policy=lossless  # the host keeps every burst (reproducible trueness); live: latest wins, drops counted
headless=0
while (($#)); do
  case "$1" in
    --model) model="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --seconds) seconds="$2"; shift 2 ;;
    --start) start="$2"; shift 2 ;;
    --policy) policy="$2"; shift 2 ;;
    --headless) headless=1; shift ;;
    -h|--help) sed -n '2,7p' "$0"; exit 0 ;;
    *) echo "demo.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
[[ "$model" == typodont || -f "$model" ]] || { echo "demo.sh: no mesh at $model" >&2; exit 2; }
[[ "$model" == typodont ]] || model="$(cd "$(dirname "$model")" && pwd)/$(basename "$model")"
d3d_install_deps
d3d_build
bin="$D3D_ROOT/build/bin"
rm -rf "$out"
mkdir -p "$out"
# A domain of our own, so that other DDS users on this machine do not mix in.
domain=$(( 100 + $$ % 100 ))
frames=$(( seconds * 30 ))

# The scan path: the model's full-arch path (seed 1), or its part from --start seconds on (d3d-sim
# writes the path as TUM).
path=full-arch
if [[ "$start" != 0 ]]; then
  "$bin/d3d-sim" --model "$model" --trajectory full-arch --seed 1 --index 0 --frames 1 --out "$out/sim" --quiet >"$out/sim.log" 2>&1
  awk -v t0="$start" '/^#/ || $1 >= t0' "$out/sim/trajectory.tum" >"$out/path.tum"
  path="$out/path.tum"
fi

# The host first (it waits for the probe), in a window: under Xvfb when there is no display.
scan=("$bin/d3d-scan" --out "$out" --domain "$domain" --policy "$policy" --idle-exit 3 --probe-timeout 1
      --reference "$model" --sim-trajectory "$path" --sim-seed 1 --screenshot "$out/preview.png" --quiet)
if ((headless)); then
  scan+=(--headless)
elif [[ -z "${DISPLAY:-}" ]]; then
  if command -v xvfb-run >/dev/null; then scan=(xvfb-run -a -s "-screen 0 1280x1024x24" "${scan[@]}"); else scan+=(--headless); fi
fi
"${scan[@]}" >"$out/scan.json" 2>"$out/scan.log" &
scan_pid=$!
trap 'kill $scan_pid 2>/dev/null || true' EXIT

echo "demo: the probe renders $frames bursts of the $model scan path ($seconds s at 30 Hz), then streams them..."
"$bin/d3d-probe" --sim "$model" --trajectory "$path" --seed 1 --rate 30 --frames "$frames" --sim-cycle "$frames" \
  --wait-subscribers 1 --domain "$domain" >"$out/probe.log" 2>&1 || { tail -5 "$out/probe.log"; echo "demo.sh: d3d-probe failed" >&2; exit 1; }
tail -1 "$out/probe.log"
echo "demo: probe done; the host finishes the model..."
if ! wait $scan_pid; then
  tail -20 "$out/scan.log"
  echo "demo.sh: d3d-scan failed (log: $out/scan.log)" >&2
  exit 1
fi
trap - EXIT
/usr/bin/python3 - "$out/report.json" <<'PY'
import json, sys
j = json.load(open(sys.argv[1]))
f = lambda k, d=1: ("%.*f" % (d, j[k])) if isinstance(j.get(k), (int, float)) else "n/a"
print("demo: bursts received %s, processed %s, fused %s, dropped %s (%s policy); %s bursts/s, latency p50 %s ms, p95 %s ms"
      % (j.get("bursts_received"), j.get("bursts_processed"), j.get("fused"), j.get("bursts_dropped"), j.get("policy"),
         f("bursts_per_s"), f("latency_ms_p50", 0), f("latency_ms_p95", 0)))
print("demo: TRUENESS RMS %s um (mean %s um, p95 %s um) over the scanned region; coverage of the arch %s %%; ATE %s mm"
      % (f("trueness_rms_um"), f("trueness_mean_um"), f("trueness_p95_um"), f("coverage_pct"), f("ate_mm", 3)))
PY
echo "demo: mesh     $out/scan.ply  $out/scan.stl (mm)"
echo "demo: report   $out/report.json"
echo "demo: preview  $out/preview.png"
echo "demo: heat map $out/heatmap.png"
