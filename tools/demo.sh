#!/usr/bin/env bash
# The main job, at this stage of the project: the virtual probe scans the built-in procedural
# typodont (or --model PATH) along a hand-held full-arch trajectory and writes the bursts, their
# ground truth, the calibration and a preview picture.
#   tools/demo.sh [--model typodont|PATH] [--out DIR] [--frames N]
set -euo pipefail
source "$(dirname "$0")/lib/setup.sh"
model=typodont
out="$D3D_ROOT/demo_out"
frames=30
while (($#)); do
  case "$1" in
    --model) model="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --frames) frames="$2"; shift 2 ;;
    -h|--help) sed -n '2,5p' "$0"; exit 0 ;;
    *) echo "demo.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
d3d_install_deps
d3d_build
rm -rf "$out"
# One second of the scan, starting 10 s in (over the molars and premolars).
"$D3D_ROOT/build/bin/d3d-sim" --model "$model" --trajectory full-arch --index 300 --frames "$frames" --seed 1 \
  --out "$out" --quiet
echo
echo "demo: bursts      $out/bursts/ (frame_0..3.png, burst.json, truth_ref/ ground truth at mid-burst)"
echo "demo: calibration $out/calibration.json"
echo "demo: trajectory  $out/trajectory.tum (true poses)"
echo "demo: preview     $out/preview.png"
echo "demo: summary     $out/summary.json"
