#!/usr/bin/env bash
# Evidence runs for the README/BENCHMARKS tables (issue 15): synthetic walking presets over
# seeds at 320×240 and 640×480 as a camera would give them (no background/, depth_bg/,
# mask/ or instance/ folder), each with ORB-SLAM2 mode and DynaPix (own poses), plus the
# real sequences when ../shared/data is present. Every row carries the motionless floor.
#
#   scripts/evidence.sh OUT [RES...]        (default RES: 320 640)
#   SEEDS="0 1 2" PRESETS="walking_xyz ..." EXTRA="--cues paper,geometric,rigidity" TAG=x
#   BIN=path/to/dynapix (default: this checkout's release build)
#   SEQ_DIR=DIR (rendered sequences, default OUT/seq; share it between binaries: render once)
#   RENDER_ONLY=1 (render the sequences, run nothing)
#
# A preset `fr1_xyz+objects6` (or `+crowd4`, `+boxes2`, `+balls2`, joined: `fr1_xyz+crowd4+balls1`)
# is the real TUM fr1_xyz (DATA=../shared/data) with virtual movers inserted
# (`dynapix synth --augment`, no flying objects unless `objectsN` is named); it keeps the real
# resolution, so its name carries no RES: `fr1_xyz+objects6_s0`.
#
# Writes OUT/table.md (one row per sequence and method) from every run.json under OUT/runs;
# each run's wall time goes to its wall_seconds.txt.
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
bin=${BIN:-$here/target/release/dynapix}
[ -x "$bin" ] || (cd "$here" && cargo build --release -q)
SEQ_DIR=${SEQ_DIR:-$OUT/seq}
DATA=${DATA:-$here/../shared/data}
mkdir -p "$SEQ_DIR" "$OUT/runs" "$OUT/cache"
# The `dynapix synth` arguments of an augmentation preset (fr1_xyz+crowd4 -> --augment ... --crowd 4).
augment_args() {
  local spec=${1#*+} objects=0 extra=()
  local IFS=+
  for part in $spec; do
    case $part in
      objects*) objects=${part#objects} ;;
      crowd* | boxes* | balls*) n=${part//[a-z]/}; extra+=("--${part%"$n"}" "$n") ;;
      *) echo "unknown augmentation '$part' in $1" >&2; return 1 ;;
    esac
  done
  echo --augment "$DATA/tum/rgbd_dataset_freiburg1_xyz" --objects "$objects" "${extra[@]}"
}
for res in $RES; do
  h=$((res * 3 / 4))
  for preset in $PRESETS; do
    for seed in $SEEDS; do
      case $preset in
        *+*) name="${preset}_s${seed}"; render=$(augment_args "$preset") ;;
        *) name="${preset}_${res}_s${seed}"; render="--preset $preset --width $res --height $h" ;;
      esac
      seq="$SEQ_DIR/$name"
      # Render into a temporary folder first, so an interrupted render is never reused; the lock
      # lets another invocation render ahead into the same SEQ_DIR (RENDER_ONLY=1).
      (
        flock 9
        if [ ! -f "$seq/rgb.txt" ]; then
          rm -rf "$seq.part"
          # shellcheck disable=SC2086
          "$bin" synth $render --seed "$seed" --out "$seq.part" -q >/dev/null
          rm -rf "$seq.part/background" "$seq.part/depth_bg" "$seq.part/mask" "$seq.part/instance"
          mv "$seq.part" "$seq"
        fi
      ) 9>"$seq.lock"
      [ -n "${RENDER_ONLY:-}" ] && continue
      for m in $METHODS; do
        dir="$OUT/runs/$name/$m$TAG"
        [ -f "$dir/run.json" ] && continue
        start=$(date +%s)
        # shellcheck disable=SC2086
        "$bin" run "$seq" --method "$m" $EXTRA --out "$dir" --cache "$OUT/cache/$name" -q | grep 'ATE' | sed "s|^|$name $m$TAG |"
        echo "$(($(date +%s) - start))" > "$dir/wall_seconds.txt"
      done
    done
  done
done
python3 "$here/scripts/evidence_table.py" "$OUT/runs" > "$OUT/table.md"
cat "$OUT/table.md"
