"""Shared fixtures: where the real data and the CLI binary are, and helpers to run the CLI."""

import os
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get("DYNAPIX_DATA", REPO.parent / "shared" / "data"))
BONN = DATA / "bonn" / "rgbd_bonn_crowd"
FR1 = DATA / "tum" / "rgbd_dataset_freiburg1_xyz"
BIN = Path(os.environ.get("DYNAPIX_BIN", REPO / "target" / "release" / "dynapix"))


def need(path: Path) -> Path:
    """Skips the test with a reason when the real-data folder ``path`` is absent."""
    if not path.is_dir():
        pytest.skip(f"real data {path} is absent")
    return path


def cli(*args: str) -> subprocess.CompletedProcess:
    """Runs the dynapix CLI (skips when it is not built); fails the test on a non-zero exit."""
    if not BIN.is_file():
        pytest.skip(f"the CLI {BIN} is not built (cargo build --release -p dynapix-cli)")
    r = subprocess.run([str(BIN), *args, "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, f"dynapix {' '.join(args)} failed:\n{r.stdout}\n{r.stderr}"
    return r


def read_tum(path: Path):
    """The rows of a TUM trajectory file as lists of floats."""
    rows = []
    for line in Path(path).read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            rows.append([float(x) for x in line.split()])
    return rows
