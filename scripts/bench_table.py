#!/usr/bin/env python3
"""Summary table of `scripts/bench.sh OUT`: one row per sequence and run (frames/s, wall and
CPU per frame, CPU relative to ORB-SLAM2 mode on the same frames, peak memory, ATE beside the
motionless floor), then the stage shares of each DynaPix run."""
import json
import pathlib
import sys

out = pathlib.Path(sys.argv[1])
runs = {}
for p in sorted(out.glob("*.json")):
    if p.stem.endswith("_orbslam2"):
        seq, run = p.stem[: -len("_orbslam2")], "orbslam2"
    elif p.stem.endswith("_dynapix_online"):
        seq, run = p.stem[: -len("_dynapix_online")], "dynapix online"
    elif p.stem.endswith("_dynapix"):
        seq, run = p.stem[: -len("_dynapix")], "dynapix"
    else:
        continue
    runs.setdefault(seq, {})[run] = json.loads(p.read_text())

print("| sequence | run | frames | frames/s | wall ms/frame | CPU ms/frame | CPU × ORB-SLAM2 | latency p95 ms | peak MiB | ATE m (floor) |")
print("|---|---|---:|---:|---:|---:|---:|---:|---:|---|")
for seq, by in runs.items():
    orb = by.get("orbslam2")
    for run in ["orbslam2", "dynapix", "dynapix online"]:
        r = by.get(run)
        if not r:
            continue
        n = r["frames"]
        cpu = r.get("cpu_seconds")
        ratio = f"{cpu / orb['cpu_seconds']:.1f}" if orb and cpu and orb.get("cpu_seconds") else ""
        lat = r.get("latency") or {}
        ate = r.get("ate_rmse_m")
        floor = r.get("motionless_floor_m")
        ate_s = f"{ate:.4f} ({floor:.4f})" if ate is not None and floor is not None else ""
        print(
            f"| {seq} | {run} | {n} | {r['fps']:.2f} | {r['wall_seconds'] * 1e3 / n:.0f} | "
            f"{(cpu or 0) * 1e3 / n:.0f} | {ratio} | "
            f"{lat.get('p95_ms', float('nan')):.0f} | {r.get('peak_rss_mib') or 0:.0f} | {ate_s} |".replace("| nan |", "| |")
        )
print()
for seq, by in runs.items():
    for run in ["dynapix", "dynapix online"]:
        r = by.get(run)
        if not r:
            continue
        n = r["frames"]
        rows = sorted(r["profile"]["stages"], key=lambda s: -s["seconds"])
        parts = ", ".join(f"{s['name']} {s['seconds'] * 1e3 / n:.0f}" for s in rows if s["seconds"] * 1e3 / n >= 1.0)
        print(f"- {seq}, {run} (ms/frame summed over threads): {parts}")
