"""Online mode from numpy arrays on synthetic data: results, parity with the Rust online
runner (``dynapix run --online``), the errors of wrong inputs, and bounded memory."""

import os
from pathlib import Path

import numpy as np
import pytest

import dynapix
from dynapix import DataError, DynapixError, Online, SyntheticSequence

from conftest import cli, read_tum


@pytest.fixture(scope="module")
def synth320(tmp_path_factory):
    """A short 320×240 walking sequence rendered once, with its folder written."""
    seq = SyntheticSequence("walking_xyz", frames=40, seed=0, width=320)
    out = tmp_path_factory.mktemp("synth") / "walking_xyz"
    seq.write(out)
    return seq, out


def test_synthetic_frames_and_presets(synth320):
    seq, out = synth320
    assert "walking_xyz" in dynapix.synth_presets()
    assert len(seq) == 40
    f = seq.frame(3)
    assert f.rgb.shape == (240, 320, 3) and f.rgb.dtype == np.uint8
    assert f.depth.shape == (240, 320) and f.depth.dtype == np.uint16
    assert f.mask.shape == (240, 320) and f.pose.shape == (4, 4)
    assert (f.depth > 0).mean() > 0.5
    again = SyntheticSequence("walking_xyz", frames=40, seed=0, width=320).frame(3)
    assert np.array_equal(f.rgb, again.rgb)  # same preset and seed, same bytes
    with pytest.raises(dynapix.ConfigError, match="nope"):
        SyntheticSequence("nope", frames=2)
    with pytest.raises(DataError):
        seq.frame(40)
    s = dynapix.Sequence(out)
    assert len(s) == 40 and s.camera.width == 320
    t, rgb, depth = s.frame(3, raw_depth=True)
    assert np.array_equal(rgb, f.rgb) and np.array_equal(depth, f.depth)
    assert abs(t - f.t) < 1e-6


def test_online_from_numpy_gives_the_rust_runners_poses(synth320, tmp_path):
    seq, folder = synth320
    results = list(dynapix.stream(folder))
    assert [r.index for r in results] == list(range(40))
    tracked = [r for r in results if r.tracked]
    assert len(tracked) >= 30
    cli("run", str(folder), "--method", "dynapix", "--online", "--out", str(tmp_path / "on"))
    rust = read_tum(tmp_path / "on" / "trajectory.txt")
    assert len(rust) == len(tracked)
    t = np.array([r.t for r in tracked])
    poses = np.stack([r.pose for r in tracked])
    # Through the same TUM writer: the same bytes as the Rust runner's trajectory.txt.
    py_file = tmp_path / "py.txt"
    dynapix.save_trajectory(py_file, results)
    assert py_file.read_bytes() == (tmp_path / "on" / "trajectory.txt").read_bytes()
    rows = np.array(rust)
    assert np.allclose(rows[:, 1:4], poses[:, :3, 3], atol=1e-8)
    # Evaluation against the synthetic ground truth from arrays: a small error.
    gt_t = np.array([seq.frame(i).t for i in range(0, 40, 4)])
    gt_p = np.stack([seq.frame(i).pose for i in range(0, 40, 4)])
    rep = dynapix.evaluate((gt_t, gt_p), (t, poses))
    assert rep["ate_rmse_m"] < 0.05 and rep["pairs"] == 10
    assert rep["motionless_floor_m"] > rep["ate_rmse_m"]


def test_online_refuses_wrong_inputs(synth320):
    seq, _ = synth320
    f = seq.frame(0)
    on = Online(seq.camera)
    with pytest.raises(DataError, match="uint8"):
        on.push(0.0, f.rgb.astype(np.float32), f.depth)
    with pytest.raises(DataError, match="H×W×3"):
        on.push(0.0, f.rgb[:, :, :2], f.depth)
    with pytest.raises(DataError, match="320×240"):
        on.push(0.0, f.rgb[:200], f.depth[:200])
    with pytest.raises(DataError, match="int32"):
        on.push(0.0, f.rgb, f.depth.astype(np.int32))
    with pytest.raises(DataError, match="numpy array"):
        on.push(0.0, f.rgb.tolist(), f.depth)
    with pytest.raises(DataError, match="finite"):
        on.push(float("nan"), f.rgb, f.depth)
    assert on.push(f.t, f.rgb, f.depth) is not None
    with pytest.raises(DataError, match="not after"):
        on.push(f.t, f.rgb, f.depth)
    # Non-contiguous views are accepted (copied element by element).
    g = seq.frame(1)
    rgb_view = np.ascontiguousarray(g.rgb[:, ::-1])[:, ::-1]
    assert not rgb_view.flags["C_CONTIGUOUS"]
    assert on.push(g.t, rgb_view, g.depth.astype(np.float32) / 5000.0) is not None
    on.finish()
    with pytest.raises(DataError, match="finish"):
        on.push(g.t + 1, g.rgb, g.depth)
    with pytest.raises(dynapix.ConfigError):
        Online("tum9")
    with pytest.raises(DataError, match="mask"):
        Online(seq.camera, {"method": "dynapix+"}).push(f.t, f.rgb, f.depth)
    assert issubclass(DataError, DynapixError)


def test_evaluation_errors_and_sim3():
    t = np.arange(20, dtype=np.float64) * 0.1
    p = np.tile(np.eye(4), (20, 1, 1))
    p[:, 0, 3] = np.sin(t)
    p[:, 2, 3] = t
    half = p.copy()
    half[:, :3, 3] *= 0.5
    assert dynapix.evaluate((t, p), (t, half), sim3=True)["ate_rmse_m"] < 1e-9
    assert dynapix.evaluate((t, p), (t, half))["ate_rmse_m"] > 0.01
    rpe = dynapix.evaluate((t, p), (t, p), rpe_frames=1, reference=t)
    assert rpe["rpe_trans_rmse_m"] < 1e-9 and rpe["tracking_rate"] == 1.0
    with pytest.raises(DataError):
        dynapix.evaluate((t, p), (t[:2], p[:2]))
    with pytest.raises(DataError, match="N×4×4"):
        dynapix.evaluate((t, p), (t, p[:, :3]))
    bad = p.copy()
    bad[3, :3, :3] *= 2.0
    with pytest.raises(DataError, match="pose 3"):
        dynapix.evaluate((t, p), (t, bad))
    with pytest.raises(dynapix.ConfigError):
        dynapix.evaluate((t, p), (t, p), rpe_seconds=1.0, rpe_frames=2)
    with pytest.raises(dynapix.IoError, match="nonexistent"):
        dynapix.evaluate("/nonexistent/gt.txt", (t, p))


def _rss_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc (Linux)")
def test_2000_pushes_keep_memory_bounded():
    seq = SyntheticSequence("walking_static", frames=30, seed=1, width=320)
    frames = [seq.frame(i) for i in range(len(seq))]
    order = list(range(30)) + list(range(28, 0, -1))  # back and forth: continuous motion
    on = Online(seq.camera)
    dt = 1.0 / 30.0
    rss = {}
    for k in range(2000):
        f = frames[order[k % len(order)]]
        on.push(k * dt, f.rgb, f.depth)
        if k + 1 in (500, 2000):
            rss[k + 1] = _rss_mib()
    on.finish()
    growth = rss[2000] - rss[500]
    print(f"RSS after 500 pushes {rss[500]:.1f} MiB, after 2000 {rss[2000]:.1f} MiB")
    assert growth < 48.0, f"RSS grew by {growth:.1f} MiB from push 500 to 2000"
