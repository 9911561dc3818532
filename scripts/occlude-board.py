#!/usr/bin/env python3
"""scripts/occlude-board.py SRC DST START FULL (issue 33, a full-view occlusion to reason with):
copies the DynaPix-layout sequence SRC to DST and covers frames START.. with a textured board
at 0.5 m that slides in from the left over 6 frames, fills the whole view for FULL frames and
slides out to the right over 6 frames (its texture moves 3 px per frame). Needs numpy and
Pillow."""
import shutil, sys, pathlib
import numpy as np
from PIL import Image
src, dst, start, full = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
if dst.exists(): shutil.rmtree(dst)
shutil.copytree(src, dst)
lines = [l.split() for l in (dst / "association.txt").read_text().splitlines() if l.strip() and not l.startswith("#")]
rng = np.random.default_rng(7)
h, w = np.array(Image.open(dst / lines[0][1])).shape[:2]
tex = np.kron(rng.integers(0, 256, size=(h // 8 + 1, (3 * w) // 8 + 1, 3)), np.ones((8, 8, 1)))[:h].astype(np.uint8)
ramp = 6
for k in range(2 * ramp + full):
    i = start + k
    if i >= len(lines): break
    if k < ramp: x0, x1 = 0, int(w * (k + 1) / (ramp + 1))
    elif k < ramp + full: x0, x1 = 0, w
    else: x0, x1 = int(w * (k - ramp - full + 1) / (ramp + 1)), w
    rgb = np.array(Image.open(dst / lines[i][1]).convert("RGB"))
    dep = np.array(Image.open(dst / lines[i][3]))
    off = 3 * k
    rgb[:, x0:x1] = tex[:, off + x0: off + x1]
    dep[:, x0:x1] = int(0.5 * 5000)
    Image.fromarray(rgb).save(dst / lines[i][1])
    Image.fromarray(dep).save(dst / lines[i][3])
print("occluded", start, "to", start + 2 * ramp + full - 1)
