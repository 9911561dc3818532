#!/usr/bin/env python3
"""Writes a long TUM-layout sequence folder for memory benchmarks without copying images.

The frames of a TUM sequence (default: ../shared/data/tum/rgbd_dataset_freiburg1_xyz) are
listed forward, then backward, then forward again ... ("ping-pong", so the camera motion stays
continuous) until N frames, with new increasing timestamps at the source's mean frame interval.
`rgb/` and `depth/` are symlinks to the source's folders, `rgb.txt`/`depth.txt` list the source
files under the new times (each depth keeps its offset to its rgb frame), and `groundtruth.txt`
holds the source's ground-truth pose of every listed frame (linear interpolation of the
position, normalised linear interpolation of the quaternion) at the frame's new time.

    scripts/pingpong-sequence.py N OUT_DIR [SRC_DIR]

OUT_DIR's name should start with `rgbd_dataset_freiburg1` so that the camera is known.
"""

import bisect
import math
import os
import sys


def read_list(path):
    rows = []
    with open(path) as f:
        for line in f:
            p = line.split()
            if not p or p[0].startswith("#"):
                continue
            rows.append((float(p[0]), p[1]))
    return rows


def read_gt(path):
    rows = []
    with open(path) as f:
        for line in f:
            p = line.split()
            if not p or p[0].startswith("#"):
                continue
            rows.append([float(v) for v in p[:8]])
    return rows


def gt_at(gt, times, t):
    j = bisect.bisect_left(times, t)
    if j == 0 or j >= len(gt):
        return None
    a, b = gt[j - 1], gt[j]
    w = (t - a[0]) / (b[0] - a[0])
    pos = [a[k] + w * (b[k] - a[k]) for k in range(1, 4)]
    qa, qb = a[4:8], b[4:8]
    if sum(x * y for x, y in zip(qa, qb)) < 0:
        qb = [-x for x in qb]
    q = [x + w * (y - x) for x, y in zip(qa, qb)]
    n = math.sqrt(sum(x * x for x in q))
    return pos + [x / n for x in q]


def main():
    if len(sys.argv) not in (3, 4):
        sys.exit(__doc__)
    n = int(sys.argv[1])
    out = sys.argv[2]
    here = os.path.dirname(os.path.abspath(__file__))
    src = os.path.abspath(
        sys.argv[3]
        if len(sys.argv) == 4
        else os.path.join(here, "../../shared/data/tum/rgbd_dataset_freiburg1_xyz")
    )
    rgb = read_list(os.path.join(src, "rgb.txt"))
    depth = read_list(os.path.join(src, "depth.txt"))
    gt = read_gt(os.path.join(src, "groundtruth.txt"))
    gt_times = [r[0] for r in gt]
    dts = [d[0] for d in depth]
    pairs = []
    for t, f in rgb:
        j = bisect.bisect_left(dts, t)
        best = min(
            (k for k in (j - 1, j) if 0 <= k < len(depth)), key=lambda k: abs(dts[k] - t)
        )
        if abs(dts[best] - t) <= 0.02:
            pairs.append((t, f, depth[best][0] - t, depth[best][1], gt_at(gt, gt_times, t)))
    if len(pairs) < 2:
        sys.exit("fewer than 2 associated frames in " + src)
    step = (pairs[-1][0] - pairs[0][0]) / (len(pairs) - 1)
    period = 2 * (len(pairs) - 1)
    os.makedirs(out, exist_ok=True)
    for sub in ("rgb", "depth"):
        link = os.path.join(out, sub)
        if not os.path.lexists(link):
            os.symlink(os.path.join(src, sub), link)
    t0 = pairs[0][0]
    with open(os.path.join(out, "rgb.txt"), "w") as fr, open(
        os.path.join(out, "depth.txt"), "w"
    ) as fd, open(os.path.join(out, "groundtruth.txt"), "w") as fg:
        fr.write("# ping-pong of %s\n# timestamp filename\n" % src)
        fd.write("# ping-pong of %s\n# timestamp filename\n" % src)
        fg.write("# ping-pong of %s\n# timestamp tx ty tz qx qy qz qw\n" % src)
        for k in range(n):
            m = k % period
            i = m if m < len(pairs) else period - m
            _, f, dd, df, pose = pairs[i]
            t = t0 + k * step
            fr.write("%.6f %s\n" % (t, f))
            fd.write("%.6f %s\n" % (t + dd, df))
            if pose is not None:
                fg.write("%.6f %s\n" % (t, " ".join("%.6f" % v for v in pose)))


if __name__ == "__main__":
    main()
