#!/usr/bin/env bash
# d3d-thinned-replay: what a slow live host's thinning costs the model, measured offline and
# deterministically (issues 50, 51).
#
# A live host that cannot keep up processes a subset of the bursts (1 in 2 to 1 in 6, at
# irregular gaps). Which subset it processes decides the trueness more than the number does, so a
# live run's figure cannot be repeated. Here the full-arch recording (live_latency.sh's, 450 bursts or --bursts)
# is replayed losslessly through d3d-scan with only some bursts listed (--replay-views): every N-th
# burst at each offset, and the views of given live runs (their poses.txt). A live run's views
# replayed this way give its trueness again, to 0.01 µm (docs/decisions/0014, "Stop 69"). The bursts
# left out reach the gap bridge's ring, as a live graph's dropped bursts do (decision 0014, "Stop 71").
# Per pattern: views fused, trueness RMS, ATE (and after aligning the trajectories), the pose
# graph's largest correction and the wrong fusions; per N the median and range of the trueness.
set -euo pipefail
{

usage() {
  cat <<'EOF'
Usage: tools/bench/thinned_replay.sh [OPTIONS] [-- D3D-SCAN OPTIONS...]

Lossless replays of the full-arch recording with only every N-th burst, or only a live run's views.

Options:
  --every LIST       N values, comma-separated, each at offsets 0 .. N-1 (default 1,2,3; 1 = all)
  --views FILE       also replay the bursts this TUM file lists, e.g. a live run's poses.txt
                     (repeatable)
  --bursts N         bursts of the full-arch path recorded (default 450: 15 s, half the arch;
                     1490: the whole arch)
  --recording FILE   the recording (default: OUT/typodont_full_arch_N.d3drec, made once as
                     live_latency.sh makes it)
  --bin DIR          folder of d3d-scan (default: build/bin)
  --out DIR          outputs (default: thinned_replay_out)
  --domain D         DDS domain id for making the recording (default 79)
  -h, --help         this help
Anything after -- goes to every d3d-scan run (e.g. -- --tracked-edge-factor 1).
EOF
}

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
every="1,2,3" rec="" bursts=450 bin="$root/build/bin" out="thinned_replay_out" domain=79
views=() extra=()
source "$root/tools/lib/setup.sh"
source "$root/tools/lib/bench.sh"
while [ $# -gt 0 ]; do
  if d3d_bench_option "$1" "${2:-}"; then shift 2; continue; fi
  case "$1" in
    --every) every=$2; shift 2 ;;
    --views) [ -f "$2" ] || { echo "thinned_replay: --views: no file '$2'" >&2; exit 2; }; views+=("$2"); shift 2 ;;
    -h|--help) usage; exit 0 ;;
    --) shift; extra=("$@"); break ;;
    *) echo "thinned_replay: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
done
[[ "$every" =~ ^[1-9][0-9]*(,[1-9][0-9]*)*$ ]] || { echo "thinned_replay: --every must list positive integers, e.g. 1,2,3" >&2; exit 2; }
[ -x "$bin/d3d-scan" ] || { echo "thinned_replay: $bin/d3d-scan not found (build first: tools/demo.sh, or --bin)" >&2; exit 2; }
mkdir -p "$out"
rec=${rec:-$out/typodont_full_arch_$bursts.d3drec}
d3d_record_full_arch "$bin" "$rec" "$out" "$domain" "$bursts" || exit 1

replay() {  # replay NAME [VIEWS-FILE]: one lossless replay into OUT/NAME
  local name=$1 list=${2:-}
  rm -rf "${out:?}/$name"
  printf 'thinned_replay: %-12s ... ' "$name"
  if "$bin/d3d-scan" --replay "$rec" --headless --reference typodont --sim-trajectory full-arch --sim-seed 1 --quiet \
    ${list:+--replay-views "$list"} --out "$out/$name" "${extra[@]}" > "$out/$name.log" 2>&1; then
    echo "done"
  else
    echo "failed (see $out/$name.log)"
  fi
}

# All bursts first: its poses.txt gives every burst's capture time, from which the patterns are cut.
replay all
[ -f "$out/all/poses.txt" ] || { echo "thinned_replay: the lossless replay gave no poses.txt (see $out/all.log)" >&2; exit 1; }
names=(all)
for n in ${every//,/ }; do
  [ "$n" = 1 ] && continue
  for ((o = 0; o < n; ++o)); do
    awk -v n="$n" -v o="$o" '/^#/ { print; next } { if (k++ % n == o) print }' "$out/all/poses.txt" > "$out/every${n}_$o.tum"
    replay "every${n}_$o" "$out/every${n}_$o.tum"
    names+=("every${n}_$o")
  done
done
for ((i = 0; i < ${#views[@]}; ++i)); do
  cp "${views[$i]}" "$out/views$((i + 1)).tum"
  replay "views$((i + 1))" "$out/views$((i + 1)).tum"
  names+=("views$((i + 1))")
done

python3 - "$out" "${names[@]}" <<'PY'
import json, os, statistics, sys
out, names = sys.argv[1], sys.argv[2:]
print("\n%-12s %9s %11s %8s %13s %13s %7s %8s" % ("pattern", "in model", "trueness µm", "ATE mm", "ATE aligned", "graph corr mm", "wrong",
                                                "seg/apart"))
def listed(name):  # bursts the subset lists (all: the lossless replay's poses)
    path = os.path.join(out, "all", "poses.txt") if name == "all" else os.path.join(out, name + ".tum")
    return sum(1 for line in open(path) if line.strip() and not line.startswith("#"))
partial = []
groups = {}
for name in names:
    path = os.path.join(out, name, "report.json")
    r = json.load(open(path)) if os.path.exists(path) else {}
    # Views in the saved model: those fused live, and those of segments that joined (fused at the
    # end, at their optimised poses).
    fused, rms = r.get("views_in_model", r.get("fused", 0)), r.get("trueness_rms_um")
    # A run's figures are shown only when they are sane: views fused and a trueness found.
    if not fused or rms is None or rms != rms:
        print("%-12s (no model: see %s.log)" % (name, os.path.join(out, name)))
        continue
    n = listed(name)
    print("%-12s %9s %11.2f %8.3f %13.3f %13.3f %7d %8s" % (name, "%d/%d" % (fused, n), rms, r["ate_mm"], r["ate_trajectory_aligned_mm"],
                                                          r["pose_graph_max_correction_mm"], r["wrong_fusions"],
                                                          "%d/%d" % (r.get("segments_started", 0), r.get("segments_apart", 0))))
    if fused < 0.9 * n:
        partial.append(name)
    groups.setdefault(name.split("_")[0], []).append(rms)
print()
for g, v in groups.items():
    if len(v) > 1:
        print("%-12s trueness median %.2f µm [%.2f – %.2f] over %d offsets" % (g, statistics.median(v), min(v), max(v), len(v)))
if partial:
    print("fewer than 90 %% of the listed views in the model (the track lost, a segment apart): %s; their trueness is of a part of the scan" % ", ".join(partial))
PY
exit
}
