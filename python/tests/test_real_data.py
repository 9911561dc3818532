"""Real data (skipped with a reason when ../shared/data is absent): the Bonn window and
fr1_xyz offline from Python give the trajectory bytes of ``dynapix run``, the online mode
from numpy arrays gives the poses of ``dynapix run --online``, another Python thread runs
while the method computes (the GIL is released), progress reaches the callback."""

import threading
import time

import numpy as np
import pytest

import dynapix

from conftest import BONN, FR1, cli, need


def test_bonn_offline_same_bytes_as_the_cli_and_the_gil_is_released(tmp_path):
    seq = need(BONN)
    cli("run", str(seq), "--method", "dynapix", "--cache", str(tmp_path / "cli-cache"),
        "--out", str(tmp_path / "cli"))
    ticks = 0
    stop = threading.Event()

    def count():
        nonlocal ticks
        while not stop.is_set():
            ticks += 1
            time.sleep(0.001)

    events = []
    counter = threading.Thread(target=count)
    counter.start()
    t0 = time.monotonic()
    try:
        r = dynapix.run(seq, method="dynapix", cache=tmp_path / "py-cache",
                        progress=lambda kind, task, value: events.append((kind, task)))
    finally:
        stop.set()
        counter.join()
    wall = time.monotonic() - t0
    # With the GIL held for the run the counter would stand still; it ticks about once per
    # millisecond when it is free (leave a wide margin for a loaded machine).
    assert ticks > wall * 50, f"{ticks} ticks in {wall:.1f} s: the GIL was not released"
    r.save(tmp_path / "py.txt")
    assert (tmp_path / "py.txt").read_bytes() == (tmp_path / "cli" / "trajectory.txt").read_bytes()
    assert r.poses.shape == (len(r), 4, 4) and r.poses.dtype == np.float64
    assert len(r.status) == 150 and r.status.count("tracked") == r.tracked
    assert len(r.passes) == 2 and r.record["method"] == "dynapix"
    assert any(k == "begin" for k, _ in events) and any(k == "end" for k, _ in events)
    assert sum(1 for k, _ in events if k == "step") >= 300
    # The run's evaluation is the CLI's eval.json.
    import json

    cli_eval = json.loads((tmp_path / "cli" / "eval.json").read_text())
    ev = r.evaluate()
    assert ev["ate_rmse_m"] == pytest.approx(cli_eval["ate_rmse_m"], abs=1e-12)
    assert ev["tracking_rate"] == pytest.approx(cli_eval["tracking_rate"], abs=1e-12)
    assert ev["motionless_floor_m"] == pytest.approx(cli_eval["motionless_floor_m"], abs=1e-12)
    assert ev["ate_rmse_m"] < 0.1
    sim3 = r.evaluate(sim3=True, rpe_seconds=1.0)
    assert sim3["alignment"] == "sim3" and sim3["ate_rmse_m"] <= ev["ate_rmse_m"] + 1e-12
    # The motion maps P the final pass used.
    p = r.probability(10)
    assert p is not None and p.dtype == np.float32 and p.shape == (480, 640)
    assert 0.0 <= p.min() and p.max() <= 1.0 and p.max() > 0.5
    maps = list(dynapix.motion_maps(r))
    assert len(maps) == 150 and np.array_equal(maps[10], p)


def test_fr1_xyz_offline_same_bytes_as_the_cli(tmp_path):
    seq = need(FR1)
    cache = tmp_path / "cache"
    cli("run", str(seq), "--method", "dynapix", "--cache", str(cache), "--out", str(tmp_path / "cli"))
    # The CLI's cache (first pass, maps) is shared: the Python run reads it back, as a second
    # `dynapix run` would, and its weighted passes run in this process.
    r = dynapix.run(seq, cache=cache, progress=False)
    r.save(tmp_path / "py.txt")
    assert (tmp_path / "py.txt").read_bytes() == (tmp_path / "cli" / "trajectory.txt").read_bytes()


def test_bonn_online_from_numpy_same_poses_as_the_rust_runner(tmp_path):
    seq_dir = need(BONN)
    cli("run", str(seq_dir), "--method", "dynapix", "--online", "--out", str(tmp_path / "on"))
    seq = dynapix.Sequence(seq_dir)
    online = dynapix.Online(seq.camera)
    results = []
    for i in range(len(seq)):
        t, rgb, depth = seq.frame(i, raw_depth=True)  # uint16 as in the files
        assert rgb.dtype == np.uint8 and depth.dtype == np.uint16
        r = online.push(t, rgb, depth)
        if r is not None:
            results.append(r)
    results += online.finish()
    dynapix.save_trajectory(tmp_path / "py.txt", results)
    assert (tmp_path / "py.txt").read_bytes() == (tmp_path / "on" / "trajectory.txt").read_bytes()


def test_sequence_errors_raise_the_documented_exceptions(tmp_path):
    with pytest.raises(dynapix.IoError):
        dynapix.Sequence(tmp_path / "no-such-sequence")
    with pytest.raises(dynapix.IoError):
        dynapix.run(tmp_path / "no-such-sequence", progress=False)
    seq = need(BONN)
    with pytest.raises(dynapix.ConfigError, match="tum9"):
        dynapix.run(seq, camera="tum9", progress=False)
    with pytest.raises(dynapix.ConfigError, match="frobnicate"):
        dynapix.run(seq, frobnicate=1, progress=False)
    s = dynapix.Sequence(seq)
    with pytest.raises(IndexError):
        s.frame(len(s))
    gt = s.ground_truth()
    assert gt is not None and gt[1].shape[1:] == (4, 4)
    # A camera of another size than the frames: a data error naming the frame and the sizes.
    small = dynapix.Camera(300.0, 300.0, 160.0, 120.0, 320, 240)
    with pytest.raises(dynapix.DataError, match="320x240"):
        dynapix.Sequence(seq, camera=small).frame(0)
