#!/usr/bin/env bash
# d3d-scan-zoo: the offline chain (d3d-fuse: the virtual probe, reconstruction, tracking, fusion and
# the evaluation against the scene) over the named scan-path styles (sim/trajectory/
# scan_styles.h), seeds and arches of issue 50, and one table of what must hold: trueness RMS / p95,
# coverage (and that of the open surface, outside narrow gaps: docs/decisions/0009), ATE, the
# largest pose error of any fused view against the truth (camera centre: max mm, max deg; its
# footprint, the surface it sees: foot mm), and wrong fusions (fused views whose footprint is off by
# > 0.2 mm or turned > 1 deg; centre: the same rule at the camera centre). A run's outputs stay in OUT/ARCH/STYLE_sSEED; a run
# whose report.json is there is not run again (the zoo is long: start it in the background, stop
# it, start it again).
set -euo pipefail
# The whole script is read before it runs (the braces): a run of hours survives an edit or a pull of it.
{

usage() {
  cat <<'EOF'
Usage: tools/bench/scan_zoo.sh [OPTIONS] [-- D3D-FUSE OPTIONS...]

Options:
  --styles LIST   comma-separated styles (default: all; full-arch runs --full-seeds, the others --seeds)
  --seeds LIST    seeds of the styles other than full-arch (default 1,2,3)
  --full-seeds L  seeds of full-arch (default 1,...,10)
  --arches LIST   typodont and/or mesh files (default: typodont and, when present,
                  ../shared/data/dental/upper_arch_0189MCMV.ply)
  --quick         full-arch seeds 1-3 and lifts seed 1, typodont only
  --jobs N        runs at a time (default 2; each renders on every core)
  --bin DIR       folder of d3d-fuse (default: build/bin)
  --out DIR       where the runs go (default: scan_zoo_out)
  --table         print the table of what is in --out, run nothing
  -h, --help      this help
Anything after -- goes to every d3d-fuse run (default: --bin 2 --every 2).
EOF
}

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
styles="full-arch,buccal-first,lingual-first,second-pass,fast,lifts,quadrants,incisors-first,tooth,glare"
seeds="1,2,3" full_seeds="1,2,3,4,5,6,7,8,9,10" arches="" jobs=2 bin="$root/build/bin" out="scan_zoo_out" table_only=0
extra=(--bin 2 --every 2)
while [ $# -gt 0 ]; do
  case "$1" in
    --styles) styles=$2; shift 2 ;;
    --seeds) seeds=$2; shift 2 ;;
    --full-seeds) full_seeds=$2; shift 2 ;;
    --arches) arches=$2; shift 2 ;;
    --quick) styles="full-arch,lifts"; full_seeds="1,2,3"; seeds="1"; arches="typodont"; shift ;;
    --jobs) jobs=$2; shift 2 ;;
    --bin) bin=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    --table) table_only=1; shift ;;
    -h|--help) usage; exit 0 ;;
    --) shift; extra=("$@"); break ;;
    *) echo "scan_zoo: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
done
real="$root/../shared/data/dental/upper_arch_0189MCMV.ply"
if [ -z "$arches" ]; then
  arches="typodont"
  if [ -f "$real" ]; then arches+=",$real"; else echo "scan_zoo: $real absent: typodont only" >&2; fi
fi
[[ "$jobs" =~ ^[1-9][0-9]*$ ]] || { echo "scan_zoo: --jobs must be a positive whole number" >&2; exit 2; }
mkdir -p "$out"

# One line per run: ARCH STYLE SEED. A --table of the same folder while runs go writes its own list
# (a shared one was read by the runs after the table had rewritten it with other styles).
if ((table_only)); then
  list=$(mktemp)
  trap 'rm -f "$list"' EXIT
else
  list="$out/runs.txt"
fi
: >"$list"
IFS=, read -ra arch_list <<<"$arches"
IFS=, read -ra style_list <<<"$styles"
for a in "${arch_list[@]}"; do
  for st in "${style_list[@]}"; do
    s_list=$seeds
    [ "$st" = full-arch ] && s_list=$full_seeds
    IFS=, read -ra ss <<<"$s_list"
    for s in "${ss[@]}"; do echo "$a $st $s" >>"$list"; done
  done
done

run_one() {  # run_one ARCH STYLE SEED
  local a=$1 st=$2 s=$3 name dir
  name=$(basename "$a"); name=${name%.*}
  dir="$ZOO_OUT/$name/${st}_s$s"
  [ -f "$dir/report.json" ] && return 0
  mkdir -p "$dir"
  if "$ZOO_BIN/d3d-fuse" --sim "$a" --trajectory "$st" --seed "$s" --out "$dir" --quiet --json "${ZOO_EXTRA[@]}" \
      >"$dir/stdout.json" 2>"$dir/log.txt"; then
    echo "scan_zoo: $name $st seed $s done" >&2
  else
    echo "scan_zoo: $name $st seed $s FAILED (exit $?; $dir/log.txt)" >&2
  fi
}
if ((!table_only)); then
  [ -x "$bin/d3d-fuse" ] || { echo "scan_zoo: no d3d-fuse in $bin (build first)" >&2; exit 2; }
  export -f run_one
  export ZOO_OUT="$out" ZOO_BIN="$bin"
  # Arrays do not cross export: the extra options go through a file of lines.
  printf '%s\n' "${extra[@]}" >"$out/extra.txt"
  echo "scan_zoo: $(wc -l <"$list") runs, $jobs at a time, into $out" >&2
  xargs -P "$jobs" -L 1 bash -c 'mapfile -t ZOO_EXTRA <"$ZOO_OUT/extra.txt"; run_one "$@"' _ <"$list"
fi

python3 - "$out" "$list" <<'PY'
import json, os, statistics, sys
out, lst = sys.argv[1], sys.argv[2]
rows, fails = [], []
print(f"{'arch':<22} {'style':<14} {'seed':>4} {'in model':>9} {'RMS um':>7} {'p95 um':>7} {'cov %':>6} {'open %':>6} {'ATE mm':>7}"
      f" {'max mm':>7} {'max deg':>7} {'foot mm':>7} {'wrong':>6} {'centre':>6} {'reloc':>5} {'seg/join':<7} {'apart':>5}")
for line in open(lst):
    a, st, s = line.split()
    name = os.path.splitext(os.path.basename(a))[0]
    p = os.path.join(out, name, f"{st}_s{s}", "report.json")
    if not os.path.exists(p):
        print(f"{name:<22} {st:<14} {s:>4} (not run)")
        continue
    j = json.load(open(p))
    g = lambda k: j.get(k, float('nan'))
    why = []
    if g("wrong_fusions") != 0: why.append(f"{g('wrong_fusions')} wrong fusions")
    if j.get("views_apart", 0): why.append(f"{j['views_apart']} views in segments apart (not joined)")
    if st != "tooth" and g("trueness_rms_um") > 15: why.append("trueness > 15 um")
    if st != "tooth" and g("coverage_pct") < 95: why.append("coverage < 95 %")
    rows.append((name, st, j))
    if why: fails.append(f"{name} {st} seed {s}: " + ", ".join(why))
    print(f"{name:<22} {st:<14} {s:>4} {j.get('views_in_model', j['fused']):>4}/{j['bursts']:<4} {g('trueness_rms_um'):7.2f} {g('trueness_p95_um'):7.2f}"
          f" {g('coverage_pct'):6.2f} {g('coverage_open_pct'):6.2f} {g('ate_mm'):7.3f} {g('ate_max_mm'):7.3f} {g('ate_max_deg'):7.3f} {g('footprint_max_mm'):7.3f}"
          f" {g('wrong_fusions'):>6} {g('wrong_fusions_by_camera_centre'):>6}"
          f" {g('relocalised'):>5} {j.get('segments_started', 0):>3}/{j.get('segments_joined', 0):<3} {j.get('views_apart', 0):>5}")
for name in sorted({r[0] for r in rows}):
    full = [r[2]["trueness_rms_um"] for r in rows if r[0] == name and r[1] == "full-arch" and "trueness_rms_um" in r[2]]
    if full:
        print(f"{name}: full-arch trueness RMS median {statistics.median(full):.2f} um over {len(full)} seeds (max {max(full):.2f})")
wrong = sum(r[2].get("wrong_fusions", 0) for r in rows)
print(f"runs: {len(rows)}, wrong fusions in all: {wrong}, runs failing what must hold: {len(fails)}")
for f in fails: print("  " + f)
PY
exit
}
