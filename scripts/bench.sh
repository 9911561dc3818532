#!/usr/bin/env bash
# The speed tables of BENCHMARKS.md (issue 14): `dynapix bench` (a run from scratch, nothing
# from a cache) of ORB-SLAM2 mode and DynaPix on TUM fr1_xyz and the Bonn crowd window from
# ../shared/data, and on synthetic walking_xyz at 640×480 and 320×240 (seed 0, 300 frames,
# no background/ folder), offline and online.
#
#   scripts/bench.sh OUT          (JSON and Markdown per run in OUT, summary in OUT/table.md)
#   BIN=path/to/dynapix scripts/bench.sh OUT    (another build, e.g. the one before a change;
#                                                nothing is compiled then)
#
# Run it on a quiet machine: stage figures are wall time inside each stage.
set -euo pipefail
OUT=${1:?usage: scripts/bench.sh OUT}
here=$(cd "$(dirname "$0")/.." && pwd)
if [ -n "${BIN:-}" ]; then
  bin=$BIN
else
  bin="$here/target/release/dynapix"
  (cd "$here" && cargo build --release -q)
fi
data="$here/../shared/data"
mkdir -p "$OUT"
seqs=()
[ -d "$data/tum/rgbd_dataset_freiburg1_xyz" ] && seqs+=("fr1_xyz=$data/tum/rgbd_dataset_freiburg1_xyz")
[ -d "$data/bonn/rgbd_bonn_crowd" ] && seqs+=("bonn_crowd=$data/bonn/rgbd_bonn_crowd")
for res in 640 320; do
  s="$OUT/seq/walking_xyz_${res}_s0"
  if [ ! -f "$s/rgb.txt" ]; then
    "$bin" synth --preset walking_xyz --seed 0 --width "$res" --height $((res * 3 / 4)) --out "$s" -q >/dev/null
    rm -rf "$s/background" "$s/depth_bg" "$s/mask" "$s/instance"
  fi
  seqs+=("walking_xyz_${res}=$s")
done
for entry in "${seqs[@]}"; do
  name=${entry%%=*}
  seq=${entry#*=}
  for run in orbslam2 dynapix dynapix_online; do
    case $run in
      orbslam2) args=(--method orbslam2) ;;
      dynapix) args=(--method dynapix) ;;
      dynapix_online) args=(--method dynapix --online) ;;
    esac
    [ -f "$OUT/${name}_${run}.json" ] && continue
    echo "== $name $run"
    "$bin" bench "$seq" "${args[@]}" -q --json "$OUT/${name}_${run}.json" --markdown "$OUT/${name}_${run}.md" | tail -3
  done
done
python3 "$here/scripts/bench_table.py" "$OUT" > "$OUT/table.md"
cat "$OUT/table.md"
