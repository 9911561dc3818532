#!/usr/bin/env bash
# Two builds of `dynapix`, strictly alternated (old-new, then new-old, ...), `dynapix bench`
# on one sequence: the speed check of a refactor ("not slower"). Prints one line per run
# (pair, build, wall s, CPU s, ATE m) and the medians; keeps every report in OUT.
#   scripts/bench-ab.sh OLD_BIN NEW_BIN SEQ N OUT [bench flags, e.g. --online]
set -euo pipefail
OLD=$1; NEW=$2; SEQ=$3; N=$4; OUT=$5; shift 5
mkdir -p "$OUT"
for k in $(seq 1 "$N"); do
  if [ $((k % 2)) -eq 1 ]; then order="old new"; else order="new old"; fi
  for w in $order; do
    if [ "$w" = old ]; then B=$OLD; else B=$NEW; fi
    "$B" bench "$SEQ" --method dynapix -q "$@" --json "$OUT/$w-$k.json" > "$OUT/$w-$k.txt" 2>&1
    python3 -c "import json,sys; r=json.load(open(sys.argv[1])); print(sys.argv[2], sys.argv[3], r['wall_seconds'], r.get('cpu_seconds'), r.get('ate_rmse_m'))" \
      "$OUT/$w-$k.json" "$k" "$w"
  done
done | tee "$OUT/runs.txt"
python3 - "$OUT/runs.txt" <<'PY'
import statistics as st, sys
runs = [l.split() for l in open(sys.argv[1])]
for w in ("old", "new"):
    wall = [float(r[2]) for r in runs if r[1] == w]
    cpu = [float(r[3]) for r in runs if r[1] == w and r[3] != "None"]
    print(f"{w}: median wall {st.median(wall):.2f} s, median CPU {st.median(cpu):.2f} s ({len(wall)} runs)")
PY
