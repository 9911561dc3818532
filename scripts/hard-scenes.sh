#!/usr/bin/env bash
# The hard scenes of issue 33 for one binary, camera-only (no background/, depth_bg/, mask/ or
# instance/ at run time), 640×480: the presets person_tracking crowd moving_box placing_box
# balloon, fr1_xyz with 6 virtual objects, and the synth `static` regression row, seeds 0 1 2,
# DynaPix and ORB-SLAM2 mode, through scripts/evidence.sh (one seed of every preset at a time,
# so an interrupted run still has whole seeds). Writes OUT/hard-table.md (scripts/hard_table.py):
# per preset the medians over seeds, min tracking rate, frames lost, the motionless floor and
# the worst DynaPix/ORB-SLAM2 ratio over seeds, then every run.
#
#   scripts/hard-scenes.sh BIN OUT
#   SEQ_DIR=/work/hard-seq      rendered sequences (default OUT/seq; render once, share it)
#   SEEDS="0 1 2"  PRESETS="..."  AUGMENT="fr1_xyz+objects6 fr1_xyz+crowd4 ..." (empty: none)
#   REGRESSION=static (empty: none)
#   ABLATE="name:config.yaml ..."   extra DynaPix rows (`run --config`), run dir dynapix_<name>
#
# Finished runs (OUT/runs/<sequence>/<method>/run.json) are skipped, so the script resumes.
set -euo pipefail
BIN=${1:?usage: scripts/hard-scenes.sh BIN OUT}
OUT=${2:?usage: scripts/hard-scenes.sh BIN OUT}
here=$(cd "$(dirname "$0")/.." && pwd)
BIN=$(cd "$(dirname "$BIN")" && pwd)/$(basename "$BIN")
SEEDS=${SEEDS:-0 1 2}
PRESETS=${PRESETS-person_tracking crowd moving_box placing_box balloon}
AUGMENT=${AUGMENT-fr1_xyz+objects6}
REGRESSION=${REGRESSION-static}
ABLATE=${ABLATE:-}
export BIN SEQ_DIR=${SEQ_DIR:-$OUT/seq}
mkdir -p "$OUT"
for seed in $SEEDS; do
  # shellcheck disable=SC2086
  SEEDS=$seed PRESETS="$PRESETS $AUGMENT $REGRESSION" METHODS="orbslam2 dynapix" TAG="" EXTRA="" \
    "$here/scripts/evidence.sh" "$OUT" 640 | sed "/^|/d"
  for ab in $ABLATE; do
    name=${ab%%:*} cfg=${ab#*:}
    [ -f "$cfg" ] || { echo "ABLATE $ab: no file $cfg" >&2; exit 1; }
    cfg=$(cd "$(dirname "$cfg")" && pwd)/$(basename "$cfg")
    SEEDS=$seed PRESETS="$PRESETS $AUGMENT $REGRESSION" METHODS=dynapix TAG="_$name" EXTRA="--config $cfg" \
      "$here/scripts/evidence.sh" "$OUT" 640 | sed "/^|/d"
  done
done
python3 "$here/scripts/hard_table.py" "$OUT/runs" > "$OUT/hard-table.md"
cat "$OUT/hard-table.md"
