#!/usr/bin/env python3
"""Measures the Python binding against the CLI on one sequence (default: the Bonn window),
alternating the two so that both see the same machine load:

- offline: wall time of `dynapix run SEQ --method dynapix` (fresh cache) against
  `dynapix.run(SEQ)` (fresh cache, no progress bars);
- online: frames/s of `dynapix bench SEQ --online` (frames decoded on a reader thread) against
  `Online.push(..., next=...)` over frames already in memory as numpy arrays (uint16 depth).

Run with the package installed (scripts/test-python.sh makes target/python-venv):

    target/python-venv/bin/python scripts/bench-python.py --repeat 2
"""

import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path

import dynapix

REPO = Path(__file__).resolve().parents[1]


def cli_offline(bin_: Path, seq: Path) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.monotonic()
        subprocess.run([str(bin_), "run", str(seq), "--method", "dynapix", "--cache", f"{tmp}/c",
                        "--out", f"{tmp}/out", "--quiet"], check=True, capture_output=True)
        return time.monotonic() - t0


def py_offline(seq: Path) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.monotonic()
        dynapix.run(seq, method="dynapix", cache=f"{tmp}/c", progress=False)
        return time.monotonic() - t0


def cli_online(bin_: Path, seq: Path) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([str(bin_), "bench", str(seq), "--method", "dynapix", "--online",
                        "--json", f"{tmp}/b.json", "--quiet"], check=True, capture_output=True)
        return json.loads(Path(f"{tmp}/b.json").read_text())["fps"]


def py_online(frames, camera) -> float:
    online = dynapix.Online(camera)
    t0 = time.monotonic()
    for i, f in enumerate(frames):
        online.push(*f, next=frames[i + 1] if i + 1 < len(frames) else None)
    online.finish()
    return len(frames) / (time.monotonic() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seq", type=Path, default=REPO.parent / "shared/data/bonn/rgbd_bonn_crowd")
    ap.add_argument("--bin", type=Path, default=REPO / "target/release/dynapix")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--skip-offline", action="store_true")
    args = ap.parse_args()
    seq = dynapix.Sequence(args.seq)
    frames = [seq.frame(i, raw_depth=True) for i in range(len(seq))]
    rows = []
    for k in range(args.repeat):
        order = ["cli", "py"] if k % 2 == 0 else ["py", "cli"]
        for who in order:
            if not args.skip_offline:
                w = cli_offline(args.bin, args.seq) if who == "cli" else py_offline(args.seq)
                rows.append((k, who, "offline wall s", w))
                print(f"run {k} {who} offline: {w:.1f} s", flush=True)
            fps = cli_online(args.bin, args.seq) if who == "cli" else py_online(frames, seq.camera)
            rows.append((k, who, "online frames/s", fps))
            print(f"run {k} {who} online: {fps:.2f} frames/s", flush=True)
    for what in ("offline wall s", "online frames/s"):
        c = [v for _, w, m, v in rows if w == "cli" and m == what]
        p = [v for _, w, m, v in rows if w == "py" and m == what]
        if c and p:
            print(f"{what}: CLI {sum(c) / len(c):.2f}, Python {sum(p) / len(p):.2f}, "
                  f"Python/CLI {sum(p) / sum(c):.3f}")


if __name__ == "__main__":
    main()
