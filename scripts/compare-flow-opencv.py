#!/usr/bin/env python3
"""Compare dynapix's DIS optical flow with OpenCV's DIS at the same preset.

Pairs with known flow are made from real TUM frames (../shared/data) by the Rust example
`flow_eval`, which also runs our DIS and records its timings; this script runs OpenCV's
`DISOpticalFlow` (PyPI `opencv-python-headless`) on the same pairs and prints, per pair and
preset, the average end-point error (EPE), the share of pixels with error > 1 px and > 3 px
(pixels whose ground-truth match lies inside the image) and the best / median time of
`--repeat` runs, side by side, plus the CPU time per run (all threads; process CPU time, which
is far less disturbed by other processes than wall time on a shared machine). `--threads N`
runs both with N threads (RAYON_NUM_THREADS / cv2.setNumThreads); `--threads 1` compares the
work done.

Setup (once):
    python3 -m venv /tmp/flowvenv && /tmp/flowvenv/bin/pip install opencv-python-headless numpy
Run from the workspace root:
    /tmp/flowvenv/bin/python scripts/compare-flow-opencv.py [--repeat 10] [--out DIR] [--markdown]
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import cv2
import numpy as np

PRESETS = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
           "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
           "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}


def read_flo(path):
    with open(path, "rb") as f:
        magic = np.fromfile(f, np.float32, 1)
        if magic.size != 1 or magic[0] != 202021.25:
            raise ValueError(f"{path}: not a .flo file")
        w, h = np.fromfile(f, np.int32, 2)
        data = np.fromfile(f, np.float32, 2 * w * h)
    if data.size != 2 * w * h:
        raise ValueError(f"{path}: truncated")
    return data.reshape(h, w, 2)


def visible_mask(gt):
    h, w = gt.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w]
    tx, ty = xs + gt[..., 0], ys + gt[..., 1]
    return (tx >= 0) & (ty >= 0) & (tx <= w - 1) & (ty <= h - 1)


def stats(flow, gt, mask):
    e = np.linalg.norm(flow - gt, axis=2)[mask]
    return e.mean(), 100.0 * (e > 1).mean(), 100.0 * (e > 3).mean()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=10, help="timed runs per pair and method")
    ap.add_argument("--out", help="folder for the pairs and flows (default: a temporary folder)")
    ap.add_argument("--presets", default="ultrafast,fast,medium")
    ap.add_argument("--markdown", action="store_true", help="print a Markdown table")
    ap.add_argument("--threads", type=int, default=0, help="threads for both (0: their defaults)")
    ap.add_argument("--synth", metavar="SEQ_DIR",
                    help="instead: evaluate consecutive frames of a `dynapix synth --flow 1` sequence "
                         "(rgb/<ts>.png, flow/<ts>.flo) through the `dynapix flow` CLI")
    ap.add_argument("--timing-only", action="store_true",
                    help="only time every preset on the first two real frames (640x480), both methods")
    args = ap.parse_args()

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    if args.timing_only:
        time_real_pair(root, args)
        return
    if args.synth:
        eval_synth(root, args)
        return
    out = args.out or tempfile.mkdtemp(prefix="dynapix-flow-")
    presets = args.presets.split(",")
    cmd = ["cargo", "run", "--quiet", "--release", "-p", "dynapix-flow", "--example", "flow_eval",
           "--", out, *presets, "--repeat", str(args.repeat)]
    env = dict(os.environ)
    if args.threads > 0:
        env["RAYON_NUM_THREADS"] = str(args.threads)
        cv2.setNumThreads(args.threads)
    print("running:", " ".join(cmd), file=sys.stderr)
    subprocess.run(cmd, cwd=root, check=True, stdout=subprocess.DEVNULL, env=env)
    with open(os.path.join(out, "ours.json")) as f:
        ours = json.load(f)

    print(f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads; pairs in {out}", file=sys.stderr)
    rows = []
    for case in ours:
        d = os.path.join(out, case)
        a = cv2.imread(os.path.join(d, "a.png"), cv2.IMREAD_GRAYSCALE)
        b = cv2.imread(os.path.join(d, "b.png"), cv2.IMREAD_GRAYSCALE)
        gt = read_flo(os.path.join(d, "gt.flo"))
        mask = visible_mask(gt)
        for p in presets:
            dis = cv2.DISOpticalFlow_create(PRESETS[p])
            times = []
            flow = None
            cpu0 = time.process_time()
            for _ in range(max(1, args.repeat)):
                t = time.perf_counter()
                flow = dis.calc(a, b, None)
                times.append(1e3 * (time.perf_counter() - t))
            cpu = 1e3 * (time.process_time() - cpu0) / max(1, args.repeat)
            times.sort()
            cv_s = stats(flow, gt, mask)
            our_flow = read_flo(os.path.join(d, f"ours_{p}.flo"))
            our_s = stats(our_flow, gt, mask)
            o = ours[case][p]
            our_cpu = o.get("cpu_ms")
            rows.append((case, p, our_s, (o["best_ms"], o["median_ms"], our_cpu if our_cpu is not None else float("nan")),
                         cv_s, (times[0], times[len(times) // 2], cpu)))

    if args.markdown:
        print("| pair | preset | EPE ours | EPE OpenCV | >1px ours | >1px OpenCV | >3px ours | >3px OpenCV "
              "| best/median ms ours | best/median ms OpenCV | CPU ms ours | CPU ms OpenCV |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for case, p, s, t, c, ct in rows:
            print(f"| {case} | {p} | {s[0]:.3f} | {c[0]:.3f} | {s[1]:.2f} % | {c[1]:.2f} % | {s[2]:.2f} % "
                  f"| {c[2]:.2f} % | {t[0]:.1f} / {t[1]:.1f} | {ct[0]:.1f} / {ct[1]:.1f} | {t[2]:.1f} | {ct[2]:.1f} |")
    else:
        hdr = (f"{'pair':18} {'preset':9} | {'EPE':>6} {'>1px%':>6} {'>3px%':>6} {'best':>6} {'med':>6} {'cpu':>6} "
               f"| {'EPE':>6} {'>1px%':>6} {'>3px%':>6} {'best':>6} {'med':>6} {'cpu':>6}")
        print(f"{'':28} | {'dynapix DIS':^45} | {'OpenCV DIS':^45}")
        print(hdr)
        for case, p, s, t, c, ct in rows:
            print(f"{case:18} {p:9} | {s[0]:6.3f} {s[1]:6.2f} {s[2]:6.2f} {t[0]:6.1f} {t[1]:6.1f} {t[2]:6.1f} "
                  f"| {c[0]:6.3f} {c[1]:6.2f} {c[2]:6.2f} {ct[0]:6.1f} {ct[1]:6.1f} {ct[2]:6.1f}")


def eval_synth(root, args):
    """EPE on a synthetic sequence with ground-truth flow, ours through the CLI contract."""
    subprocess.run(["cargo", "build", "--quiet", "--release", "-p", "dynapix-cli"], cwd=root, check=True)
    exe = os.path.join(root, "target", "release", "dynapix")
    seq = args.synth
    frames = sorted(f for f in os.listdir(os.path.join(seq, "rgb")) if f.endswith(".png"))
    presets = args.presets.split(",")
    acc = {}
    tmp = tempfile.mkdtemp(prefix="dynapix-flow-synth-")
    for i, fa in enumerate(frames[:-1]):
        gt_path = os.path.join(seq, "flow", fa[:-4] + ".flo")
        if not os.path.exists(gt_path):
            continue
        pa, pb = os.path.join(seq, "rgb", fa), os.path.join(seq, "rgb", frames[i + 1])
        gt = read_flo(gt_path)
        mask = visible_mask(gt) & np.isfinite(gt).all(axis=2)
        a, b = (cv2.imread(p, cv2.IMREAD_GRAYSCALE) for p in (pa, pb))
        for p in presets:
            out = os.path.join(tmp, f"{p}.flo")
            subprocess.run([exe, "flow", pa, pb, "--out", out, "--preset", p], check=True)
            for name, flow in (("dynapix", read_flo(out)),
                               ("OpenCV", cv2.DISOpticalFlow_create(PRESETS[p]).calc(a, b, None))):
                e = np.linalg.norm(flow - gt, axis=2)[mask]
                acc.setdefault((p, name), []).append((e.sum(), (e > 1).sum(), (e > 3).sum(), e.size))
    print(f"{'preset':9} {'method':8} {'EPE':>6} {'>1px%':>6} {'>3px%':>6} pairs")
    for p in presets:
        for name in ("dynapix", "OpenCV"):
            r = np.array(acc.get((p, name), [(0, 0, 0, 1)]), dtype=np.float64)
            n = r[:, 3].sum()
            print(f"{p:9} {name:8} {r[:, 0].sum() / n:6.3f} {100 * r[:, 1].sum() / n:6.2f} "
                  f"{100 * r[:, 2].sum() / n:6.2f} {len(r)}")


def time_real_pair(root, args):
    """Best / median / mean wall time and CPU time per run on two consecutive real frames."""
    env = dict(os.environ)
    if args.threads > 0:
        env["RAYON_NUM_THREADS"] = str(args.threads)
        cv2.setNumThreads(args.threads)
    rgb = os.path.join(root, "..", "shared", "data", "tum", "rgbd_dataset_freiburg1_xyz", "rgb")
    frames = sorted(f for f in os.listdir(rgb) if f.endswith(".png"))[:2]
    paths = [os.path.join(rgb, f) for f in frames]
    cmd = ["cargo", "run", "--quiet", "--release", "-p", "dynapix-flow", "--example", "dis_time", "--",
           *paths, "--repeat", str(args.repeat)]
    subprocess.run(cmd, cwd=root, check=True, env=env)
    a, b = (cv2.imread(p, cv2.IMREAD_GRAYSCALE) for p in paths)
    for name in ["medium", "fast", "ultrafast"]:
        dis = cv2.DISOpticalFlow_create(PRESETS[name])
        dis.calc(a, b, None)
        ts = []
        c0 = time.process_time()
        for _ in range(max(1, args.repeat)):
            t = time.perf_counter()
            dis.calc(a, b, None)
            ts.append(1e3 * (time.perf_counter() - t))
        cpu = 1e3 * (time.process_time() - c0) / len(ts)
        ts.sort()
        print(f"opencv {name}: best {ts[0]:.1f} median {ts[len(ts) // 2]:.1f} mean {sum(ts) / len(ts):.1f} "
              f"cpu/run {cpu:.1f} ms ({len(ts)} runs, {cv2.getNumThreads()} threads)")


if __name__ == "__main__":
    main()
