#!/usr/bin/env python3
"""Seed tables of `scripts/evidence.sh` runs: for each resolution, one row per preset with
ORB-SLAM2 / DynaPix ATE per seed, the means, DynaPix/ORB-SLAM2 and the motionless floor; the
last row is the mean over the walking presets' runs.

    evidence_synth_table.py RUNS_DIR [METHOD_A METHOD_B]   (default orbslam2 dynapix)
"""
import json
import pathlib
import re
import sys
from collections import defaultdict

root = pathlib.Path(sys.argv[1])
ma, mb = (sys.argv[2], sys.argv[3]) if len(sys.argv) > 3 else ("orbslam2", "dynapix")
runs = defaultdict(dict)
for d in sorted(root.iterdir()):
    m = re.match(r"(.+)_(\d+)_s(\d+)$", d.name)
    if not m:
        continue
    preset, res, seed = m.group(1), int(m.group(2)), int(m.group(3))
    for meth in (ma, mb):
        f = d / meth / "run.json"
        if f.is_file():
            r = json.loads(f.read_text())["results"][0]
            runs[(res, preset)][(seed, meth)] = r
for res in sorted({k[0] for k in runs}):
    presets = [p for (r, p) in runs if r == res]
    seeds = sorted({s for p in presets for (s, _) in runs[(res, p)]})
    print(f"**{res}×{res * 3 // 4}** ({ma} / {mb}, ATE m)\n")
    print("| preset | " + " | ".join(f"seed {s}" for s in seeds) + f" | mean | {mb}/{ma} | floor (mean) |")
    print("|---|" + "---:|" * (len(seeds) + 3))
    all_a, all_b = [], []
    for p in presets:
        cells, a_v, b_v, fl = [], [], [], []
        for s in seeds:
            ra, rb = runs[(res, p)].get((s, ma)), runs[(res, p)].get((s, mb))
            if ra is None or rb is None or ra.get("ate_rmse_m") is None or rb.get("ate_rmse_m") is None:
                cells.append("—")
                continue
            a, b = ra["ate_rmse_m"], rb["ate_rmse_m"]
            tr = rb.get("tracking_rate") or 0
            cells.append(f"{a:.4f} / {b:.4f}" + ("" if tr > 0.995 else f" (TR {tr:.2f})"))
            a_v.append(a), b_v.append(b), fl.append(rb.get("motionless_floor_m") or float("nan"))
        if p.startswith("walking"):
            all_a += a_v
            all_b += b_v
        if a_v:
            ma_, mb_ = sum(a_v) / len(a_v), sum(b_v) / len(b_v)
            print(f"| {p} | " + " | ".join(cells) + f" | {ma_:.4f} / {mb_:.4f} | {mb_ / ma_:.2f} | {sum(fl) / len(fl):.4f} |")
    if all_a:
        A, B = sum(all_a) / len(all_a), sum(all_b) / len(all_b)
        print(f"| **walking presets ({len(all_a)} runs)** | " + " | ".join("" for _ in seeds) + f" | **{A:.4f} / {B:.4f}** | **{B / A:.2f}** | |")
    print()
