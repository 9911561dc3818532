#!/usr/bin/env python3
"""Runs DynaPix on a sequence folder from Python and plots the trajectory against the ground
truth (top view), with the ATE; offline by default, online (numpy frames pushed one at a
time) with --online.

    pip install ./python matplotlib tqdm
    python examples/python/run_sequence.py ../shared/data/bonn/rgbd_bonn_crowd --out bonn.png
"""

import argparse
import sys
import tempfile

import numpy as np

import dynapix


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("seq_dir", help="sequence folder (TUM, Bonn, GRADE or synthetic layout)")
    ap.add_argument("--method", default="dynapix", help="dynapix (default), dynapix+ or orbslam2")
    ap.add_argument("--online", action="store_true", help="push the frames one at a time")
    ap.add_argument("--cache", help="motion-map cache folder (default: a temporary one)")
    ap.add_argument("--out", default="trajectory.png", help="plot file (PNG or SVG)")
    args = ap.parse_args()

    config = dynapix.Config(method=args.method)
    if args.online:
        results = list(dynapix.stream(args.seq_dir, config=config))
        tracked = [r for r in results if r.tracked]
        t = np.array([r.t for r in tracked])
        poses = np.stack([r.pose for r in tracked])
        print(f"online: {len(tracked)} of {len(results)} frames tracked")
    else:
        with tempfile.TemporaryDirectory() as tmp:
            r = dynapix.run(args.seq_dir, config=config, cache=args.cache or tmp)
        t, poses = r.timestamps, r.poses
        print(f"offline: {r.tracked} of {len(r.status)} frames tracked, {len(r.passes)} pass(es)")

    seq = dynapix.Sequence(args.seq_dir)
    gt = seq.ground_truth()
    if gt is None:
        print("no groundtruth.txt: nothing to compare with")
        return 0
    report = dynapix.evaluate(gt, (t, poses), reference=seq.timestamps)
    print(f"ATE RMSE {report['ate_rmse_m']:.4f} m, tracking rate {report['tracking_rate'] * 100:.1f} %, "
          f"motionless floor {report['motionless_floor_m']:.4f} m")

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed: no plot (pip install matplotlib)")
        return 0
    # The estimate in the ground truth's frame (the alignment the ATE used).
    q = report["alignment_rotation_xyzw"]
    x, y, z, w = q
    rot = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
    est = report["alignment_scale"] * poses[:, :3, 3] @ rot.T + np.array(report["alignment_translation_m"])
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(gt[1][:, 0, 3], gt[1][:, 1, 3], "k--", label="ground truth")
    ax.plot(est[:, 0], est[:, 1], "C0", label=f"{args.method} (ATE {report['ate_rmse_m'] * 100:.1f} cm)")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend()
    ax.set_title(seq.path)
    fig.savefig(args.out, dpi=120, bbox_inches="tight")
    print(f"plot: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
