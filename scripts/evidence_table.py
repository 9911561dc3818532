#!/usr/bin/env python3
"""Table of every run.json under RUNS_DIR (RUNS_DIR/<sequence>/<method>/run.json):
ATE RMSE, tracking rate, motionless floor and ATE/floor, plus the ATE of each earlier pass."""
import json
import pathlib
import sys

root = pathlib.Path(sys.argv[1])
print("| sequence | method | ATE RMSE [m] | TR | motionless floor [m] | ATE/floor | earlier passes (ATE m) |")
print("|---|---|---:|---:|---:|---:|---|")
for run in sorted(root.glob("*/*/run.json")):
    r = json.loads(run.read_text())
    res = r["results"][0]
    ate, tr, floor = res.get("ate_rmse_m"), res.get("tracking_rate"), res.get("motionless_floor_m")
    ratio = f"{ate / floor:.2f}" if ate is not None and floor else "—"
    earlier = ", ".join(
        f"{p['pass']}: {p['ate_rmse_m']:.4f}" for p in r.get("earlier_passes", []) if p.get("ate_rmse_m") is not None
    )
    fmt = lambda v, f: "—" if v is None else format(v, f)
    print(
        f"| {run.parent.parent.name} | {run.parent.name} | {fmt(ate, '.4f')} | {fmt(tr, '.3f')} | "
        f"{fmt(floor, '.4f')} | {ratio} | {earlier} |"
    )
