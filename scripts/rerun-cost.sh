#!/usr/bin/env bash
# The logging cost of a Rerun recording (issue 35): `dynapix bench` of one sequence without and
# with `--rerun-save`, strictly alternated (off, on, off, on, …), N runs each, under
# /usr/bin/time. Prints every run (bench wall and CPU, process wall/user/system) and the
# medians; `uptime` before and after. BIN must be built with `--features viz`.
#
#   scripts/rerun-cost.sh BIN SEQ [N [OUT_DIR [extra bench flags…]]]
set -euo pipefail
BIN=$1; SEQ=$2; N=${3:-3}; OUT=${4:-$(mktemp -d)}; shift $(( $# < 4 ? $# : 4 ))
mkdir -p "$OUT"
echo "# $(date -u +%FT%TZ) $(uptime)"
echo "# $BIN bench $SEQ --method dynapix $* [--rerun-save $OUT/run.rrd]"
for k in $(seq "$N"); do
  for mode in off on; do
    flags=()
    if [ "$mode" = on ]; then flags=(--rerun-save "$OUT/run.rrd"); fi
    /usr/bin/time -f "%e %U %S" -o "$OUT/time-$mode-$k" \
      "$BIN" bench "$SEQ" --method dynapix --json "$OUT/bench-$mode-$k.json" --quiet "$@" \
      "${flags[@]}" > "$OUT/bench-$mode-$k.log" 2>&1
    python3 - "$OUT" "$mode" "$k" << 'PY'
import json, sys
out, mode, k = sys.argv[1:]
b = json.load(open(f"{out}/bench-{mode}-{k}.json"))
e, u, s = open(f"{out}/time-{mode}-{k}").read().split()[:3]
print(f"{mode} {k}: bench wall {b['wall_seconds']:.2f} s cpu {b['cpu_seconds']:.2f} s | "
      f"process wall {e} s user {u} s sys {s} s | ATE {b['ate_rmse_m'] or float('nan'):.4f} m")
PY
  done
done
echo "# $(date -u +%FT%TZ) $(uptime)"
python3 - "$OUT" "$N" << 'PY'
import json, statistics as st, sys
out, n = sys.argv[1], int(sys.argv[2])
med = {}
for mode in ("off", "on"):
    rows = []
    for k in range(1, n + 1):
        b = json.load(open(f"{out}/bench-{mode}-{k}.json"))
        e, u, s = map(float, open(f"{out}/time-{mode}-{k}").read().split()[:3])
        rows.append((b["wall_seconds"], b["cpu_seconds"], e, u, s))
    med[mode] = [st.median(c) for c in zip(*rows)]
    w, c, e, u, s = med[mode]
    print(f"median {mode}: bench wall {w:.2f} s, bench cpu {c:.2f} s, process wall {e:.2f} s, "
          f"user {u:.2f} s, sys {s:.2f} s")
names = ["bench wall", "bench cpu", "process wall", "user", "sys"]
print("on/off: " + ", ".join(f"{nm} {100 * (a / b - 1):+.1f} %"
                              for nm, a, b in zip(names, med["on"], med["off"]) if b > 0))
PY
