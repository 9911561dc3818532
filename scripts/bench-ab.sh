#!/usr/bin/env bash
# `dynapix bench` of one sequence by two sides A and B, strictly alternated pair by pair
# (A-B, then B-A, ...), each run under /usr/bin/time: the speed check of a refactor (two
# builds) and the cost of an option (one build, flags on side B only, see
# scripts/rerun-cost.sh). Prints every run (bench wall and CPU, process wall/user/system, ATE),
# the medians and B against A; `uptime` before and after. Keeps every report in OUT.
#
#   scripts/bench-ab.sh A_BIN B_BIN SEQ N OUT [bench flags for both, e.g. --online]
#   env: LABELS="old new" (names of A and B), A_FLAGS / B_FLAGS (extra flags of one side)
set -euo pipefail
A=$1; B=$2; SEQ=$3; N=$4; OUT=$5; shift 5
read -r LA LB <<< "${LABELS:-old new}"
read -r -a FA <<< "${A_FLAGS:-}"
read -r -a FB <<< "${B_FLAGS:-}"
mkdir -p "$OUT"
echo "# $(date -u +%FT%TZ) $(uptime)"
echo "# $LA: $A bench $SEQ --method dynapix $* ${FA[*]}"
echo "# $LB: $B bench $SEQ --method dynapix $* ${FB[*]}"
for k in $(seq "$N"); do
  if [ $((k % 2)) -eq 1 ]; then order="$LA $LB"; else order="$LB $LA"; fi
  for side in $order; do
    if [ "$side" = "$LA" ]; then bin=$A; flags=("${FA[@]}"); else bin=$B; flags=("${FB[@]}"); fi
    /usr/bin/time -f "%e %U %S" -o "$OUT/time-$side-$k" \
      "$bin" bench "$SEQ" --method dynapix --json "$OUT/bench-$side-$k.json" --quiet "$@" \
      "${flags[@]}" > "$OUT/bench-$side-$k.log" 2>&1
    python3 - "$OUT" "$side" "$k" << 'PY'
import json, sys
out, side, k = sys.argv[1:]
b = json.load(open(f"{out}/bench-{side}-{k}.json"))
e, u, s = open(f"{out}/time-{side}-{k}").read().split()[:3]
print(f"{side} {k}: bench wall {b['wall_seconds']:.2f} s cpu {b['cpu_seconds']:.2f} s | "
      f"process wall {e} s user {u} s sys {s} s | ATE {b['ate_rmse_m'] or float('nan'):.4f} m")
PY
  done
done
echo "# $(date -u +%FT%TZ) $(uptime)"
python3 - "$OUT" "$N" "$LA" "$LB" << 'PY'
import json, statistics as st, sys
out, n, la, lb = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
med = {}
for side in (la, lb):
    rows = []
    for k in range(1, n + 1):
        b = json.load(open(f"{out}/bench-{side}-{k}.json"))
        e, u, s = map(float, open(f"{out}/time-{side}-{k}").read().split()[:3])
        rows.append((b["wall_seconds"], b["cpu_seconds"], e, u, s))
    med[side] = [st.median(c) for c in zip(*rows)]
    w, c, e, u, s = med[side]
    print(f"median {side}: bench wall {w:.2f} s, bench cpu {c:.2f} s, process wall {e:.2f} s, "
          f"user {u:.2f} s, sys {s:.2f} s")
names = ["bench wall", "bench cpu", "process wall", "user", "sys"]
print(f"{lb}/{la}: " + ", ".join(f"{nm} {100 * (b / a - 1):+.1f} %"
                                 for nm, b, a in zip(names, med[lb], med[la]) if a > 0))
PY
