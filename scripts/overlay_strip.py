#!/usr/bin/env python3
"""Contact strip of motion probabilities over real frames (dev tool; needs numpy and Pillow).

    overlay_strip.py SEQ_DIR MAPS_DIR OUT.png [--frames 10,50,90,130] [--scale 0.5]

Top row: the frames (rgb/ of SEQ_DIR, in rgb.txt order); bottom row: P = 1 - stored/1000 of
the map of the same name in MAPS_DIR tinted red (alpha 0.7·P), like `dynapix motion --pictures`.
"""
import argparse
import pathlib

import numpy as np
from PIL import Image

ap = argparse.ArgumentParser()
ap.add_argument("seq")
ap.add_argument("maps")
ap.add_argument("out")
ap.add_argument("--frames", default="10,50,90,130")
ap.add_argument("--scale", type=float, default=0.5)
a = ap.parse_args()
seq = pathlib.Path(a.seq)
rgbs = [l.split()[1] for l in (seq / "rgb.txt").read_text().splitlines() if l and not l.startswith("#")]
cols = []
for i in (int(x) for x in a.frames.split(",")):
    rgb_path = seq / rgbs[i]
    img = np.asarray(Image.open(rgb_path).convert("RGB")).astype(np.float32)
    stored = np.asarray(Image.open(pathlib.Path(a.maps) / (pathlib.Path(rgbs[i]).stem + ".png"))).astype(np.float32)
    p = np.clip(1.0 - stored / 1000.0, 0.0, 1.0)[..., None]
    red = np.zeros_like(img)
    red[..., 0] = 255.0
    ov = (1.0 - 0.7 * p) * img + 0.7 * p * red
    col = np.concatenate([img, ov], axis=0).round().astype(np.uint8)
    im = Image.fromarray(col)
    if a.scale != 1.0:
        im = im.resize((int(im.width * a.scale), int(im.height * a.scale)), Image.BILINEAR)
    cols.append(np.asarray(im))
Image.fromarray(np.concatenate(cols, axis=1)).save(a.out, optimize=True)
print(a.out)
