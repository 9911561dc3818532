#!/usr/bin/env bash
# The logging cost of a Rerun recording (issue 35): `dynapix bench` of one sequence without and
# with `--rerun-save`, strictly alternated pair by pair (scripts/bench-ab.sh with one build),
# N runs each. BIN must be built with `--features viz`.
#
#   scripts/rerun-cost.sh BIN SEQ [N [OUT_DIR [extra bench flags…]]]
set -euo pipefail
BIN=$1; SEQ=$2; N=${3:-3}; OUT=${4:-$(mktemp -d)}; shift $(( $# < 4 ? $# : 4 ))
LABELS="off on" B_FLAGS="--rerun-save $OUT/run.rrd" \
  exec "$(dirname "$0")/bench-ab.sh" "$BIN" "$BIN" "$SEQ" "$N" "$OUT" "$@"
