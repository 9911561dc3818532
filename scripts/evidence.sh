#!/usr/bin/env bash
# Evidence runs for the README/BENCHMARKS tables (issue 15): synthetic walking presets over
# seeds at 320×240 and 640×480 as a camera would give them (no background/, depth_bg/,
# mask/ or instance/ folder), each with ORB-SLAM2 mode and DynaPix (own poses), plus the
# real sequences when ../shared/data is present. Every row carries the motionless floor.
#
#   scripts/evidence.sh OUT [RES...]        (default RES: 320 640)
#   SEEDS="0 1 2" PRESETS="walking_xyz ..." EXTRA="--cues paper,geometric,rigidity" TAG=x
#
# Writes OUT/table.md (one row per sequence and method) from every run.json under OUT/runs.
set -euo pipefail
OUT=${1:?usage: scripts/evidence.sh OUT [RES...]}
shift || true
RES=${*:-320 640}
SEEDS=${SEEDS:-0 1 2}
PRESETS=${PRESETS:-walking_xyz walking_static walking_rpy walking_halfsphere}
METHODS=${METHODS:-orbslam2 dynapix}
TAG=${TAG:-}
EXTRA=${EXTRA:-}
here=$(cd "$(dirname "$0")/.." && pwd)
bin="$here/target/release/dynapix"
[ -x "$bin" ] || (cd "$here" && cargo build --release -q)
mkdir -p "$OUT/seq" "$OUT/runs" "$OUT/cache"
for res in $RES; do
  h=$((res * 3 / 4))
  for preset in $PRESETS; do
    for seed in $SEEDS; do
      name="${preset}_${res}_s${seed}"
      seq="$OUT/seq/$name"
      if [ ! -f "$seq/rgb.txt" ]; then
        "$bin" synth --preset "$preset" --seed "$seed" --width "$res" --height "$h" --out "$seq" -q >/dev/null
        rm -rf "$seq/background" "$seq/depth_bg" "$seq/mask" "$seq/instance"
      fi
      for m in $METHODS; do
        dir="$OUT/runs/$name/$m$TAG"
        [ -f "$dir/run.json" ] && continue
        # shellcheck disable=SC2086
        "$bin" run "$seq" --method "$m" $EXTRA --out "$dir" --cache "$OUT/cache/$name" -q | grep 'ATE' | sed "s|^|$name |"
      done
    done
  done
done
python3 "$here/scripts/evidence_table.py" "$OUT/runs" > "$OUT/table.md"
cat "$OUT/table.md"
