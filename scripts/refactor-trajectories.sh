#!/usr/bin/env bash
# The refactor check: DynaPix offline (fresh cache) and online trajectories of the Bonn window,
# fr1_xyz and synth walking_xyz 640x480 seed 0 (300 frames, rendered once into SYNTH_DIR).
# Run it with the build before and after a refactor, then `cmp` the trajectory.txt files:
#   scripts/refactor-trajectories.sh BIN OUT [SYNTH_DIR]
#   for n in bonn-off bonn-on fr1-off fr1-on synth-off synth-on; do
#     cmp OUT_BEFORE/$n/trajectory.txt OUT_AFTER/$n/trajectory.txt && echo "same $n"; done
set -euo pipefail
BIN=$1; OUT=$2; SY=${3:-/tmp/dynapix-synth640}
DATA=$(cd "$(dirname "$0")/.." && pwd)/../shared/data
mkdir -p "$OUT"
if [ ! -f "$SY/groundtruth.txt" ]; then
  "$BIN" synth --preset walking_xyz --frames 300 --seed 0 --out "$SY" --quiet
fi
for pair in "bonn:$DATA/bonn/rgbd_bonn_crowd" "fr1:$DATA/tum/rgbd_dataset_freiburg1_xyz" "synth:$SY"; do
  n=${pair%%:*}; d=${pair#*:}
  c=$(mktemp -d)
  "$BIN" run "$d" --method dynapix --cache "$c" --out "$OUT/$n-off" --quiet > "$OUT/$n-off.log" 2>&1 || echo "$n offline: exit $?"
  "$BIN" run "$d" --method dynapix --online --out "$OUT/$n-on" --quiet > "$OUT/$n-on.log" 2>&1 || echo "$n online: exit $?"
  rm -rf "$c"
done
