#!/usr/bin/env python3
"""The hard-scenes table of `scripts/hard-scenes.sh` (issue 33) from RUNS_DIR/<sequence>/<method>/run.json,
sequences named <preset>_<res>_s<seed> or <augmentation>_s<seed>:

1. per preset: seeds, median ATE over seeds of ORB-SLAM2 mode, DynaPix and every other DynaPix
   row (ablations, dynapix_<name>), the worst DynaPix/ORB-SLAM2 ratio over seeds (with its
   seed), min tracking rate, most frames lost in one run (ORB-SLAM2 / DynaPix), median floor;
2. every run (ATE, TR, frames lost, floor, wall seconds).

    hard_table.py RUNS_DIR
"""
import json
import pathlib
import re
import statistics
import sys
from collections import defaultdict

root = pathlib.Path(sys.argv[1])


def load(run_json):
    """ATE, TR, frames lost, floor and wall seconds of one run (None where missing)."""
    r = json.loads(run_json.read_text())
    res = (r.get("results") or [{}])[0]
    frames, tracked = res.get("frames"), res.get("tracked")
    lost = frames - tracked if frames is not None and tracked is not None else None
    wall = run_json.parent / "wall_seconds.txt"
    return {
        "ate": res.get("ate_rmse_m"),
        "tr": res.get("tracking_rate"),
        "floor": res.get("motionless_floor_m"),
        "lost": lost,
        "wall": int(wall.read_text()) if wall.is_file() else None,
    }


runs = defaultdict(lambda: defaultdict(dict))  # group -> method -> seed -> run
for run_json in sorted(root.glob("*/*/run.json")):
    m = re.match(r"(.+)_s(\d+)$", run_json.parent.parent.name)
    if not m:
        continue
    runs[m.group(1)][run_json.parent.name][int(m.group(2))] = load(run_json)

# The hard presets first (alphabetical), then the augmented real sequences, then `static`.
runs = dict(sorted(runs.items(), key=lambda kv: (kv[0].startswith("static"), "+" in kv[0], kv[0])))
fmt = lambda v, f: "—" if v is None else format(v, f)


def median(vals):
    vals = [v for v in vals if v is not None]
    return statistics.median(vals) if vals else None


def order(method):
    return (0, "") if method == "orbslam2" else (1, "") if method == "dynapix" else (2, method)


extra = sorted({m for g in runs.values() for m in g if m not in ("orbslam2", "dynapix")}, key=order)
head = ["preset", "seeds", "ORB-SLAM2 ATE [m]", "DynaPix ATE [m]"] + [f"{m} ATE [m]" for m in extra]
head += ["worst DynaPix/ORB-SLAM2 (seed)", "min TR ORB-SLAM2 / DynaPix", "most frames lost ORB-SLAM2 / DynaPix", "floor [m]"]
print("Medians over seeds (ATE RMSE in m).\n")
print("| " + " | ".join(head) + " |")
print("|---|---|" + "---:|" * (len(head) - 2))
for group, by_method in runs.items():
    orb, dpx = by_method.get("orbslam2", {}), by_method.get("dynapix", {})
    seeds = sorted(set(orb) | set(dpx))
    cells = [group, " ".join(map(str, seeds))]
    for m in ["orbslam2", "dynapix"] + extra:
        vals = [r["ate"] for r in by_method.get(m, {}).values()]
        n = len([v for v in vals if v is not None])
        cell = fmt(median(vals), ".4f")
        cells.append(cell if n == len(seeds) or n == 0 else f"{cell} ({n} seeds)")
    ratios = [
        (dpx[s]["ate"] / orb[s]["ate"], s)
        for s in seeds
        if s in orb and s in dpx and dpx[s]["ate"] is not None and orb[s]["ate"]
    ]
    cells.append(f"{max(ratios)[0]:.2f} (s{max(ratios)[1]})" if ratios else "—")
    min_tr = lambda d: min((r["tr"] for r in d.values() if r["tr"] is not None), default=None)
    max_lost = lambda d: max((r["lost"] for r in d.values() if r["lost"] is not None), default=None)
    cells.append(f"{fmt(min_tr(orb), '.3f')} / {fmt(min_tr(dpx), '.3f')}")
    cells.append(f"{fmt(max_lost(orb), 'd')} / {fmt(max_lost(dpx), 'd')}")
    cells.append(fmt(median([r["floor"] for d in (orb, dpx) for r in d.values()]), ".4f"))
    print("| " + " | ".join(cells) + " |")

print("\nEvery run:\n")
print("| sequence | seed | method | ATE [m] | TR | frames lost | floor [m] | wall [s] |")
print("|---|---:|---|---:|---:|---:|---:|---:|")
for group, by_method in runs.items():
    for seed in sorted({s for d in by_method.values() for s in d}):
        for m in sorted(by_method, key=order):
            r = by_method[m].get(seed)
            if r is None:
                continue
            print(
                f"| {group} | {seed} | {m} | {fmt(r['ate'], '.4f')} | {fmt(r['tr'], '.3f')} | "
                f"{fmt(r['lost'], 'd')} | {fmt(r['floor'], '.4f')} | {fmt(r['wall'], 'd')} |"
            )
