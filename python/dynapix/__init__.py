"""DynaPix dynamic RGB-D SLAM (Xu, Bonetto, Ahmad, GCPR 2024) for Python.

The method runs in Rust (the ``dynapix`` crate); this package binds it with numpy arrays in
and out:

- :class:`Config`: the one configuration (paper defaults; dict, JSON/YAML file, keyword
  overrides such as ``Config(method="orbslam2", slam__seed=3)``).
- :class:`Camera`: presets (``tum1 tum2 tum3 grade bonn``), ORB-SLAM2 settings files, a
  sequence folder's own camera, or values.
- :func:`run`: a method offline on a sequence folder → :class:`RunResult` (``poses``
  N×4×4, ``timestamps``, ``status``, ``passes``, ``record``, ``save()``, ``evaluate()``,
  motion maps ``probability(i)``).
- :class:`Online`: ``push(t, rgb, depth)`` numpy frames one at a time → :class:`FrameResult`;
  :func:`stream` feeds it a sequence folder.
- :func:`evaluate`: ATE / RPE / tracking rate / motionless floor (SE(3) or Sim(3)) from
  files or arrays; :func:`to_evo` converts to ``evo``'s trajectory type when it is installed.
- :class:`SyntheticSequence` and :func:`augment`: the synthetic data generator.

Errors raise :class:`DynapixError` subclasses: :class:`ConfigError`, :class:`DataError`,
:class:`IoError`, with the library's message.
"""

from __future__ import annotations

import os
from typing import Any, Callable, Iterator, Optional, Union

from . import _dynapix
from ._dynapix import (
    Camera,
    Config,
    ConfigError,
    DataError,
    DynapixError,
    FrameResult,
    IoError,
    Online,
    RunResult,
    Sequence,
    SyntheticFrame,
    SyntheticSequence,
    augment,
    evaluate,
    read_ground_truth,
    read_probability,
    read_trajectory,
    save_trajectory,
    synth_presets,
)

__version__: str = _dynapix.__version__

__all__ = [
    "Camera",
    "Config",
    "ConfigError",
    "DataError",
    "DynapixError",
    "FrameResult",
    "IoError",
    "Online",
    "RunResult",
    "Sequence",
    "SyntheticFrame",
    "SyntheticSequence",
    "augment",
    "evaluate",
    "motion_maps",
    "read_ground_truth",
    "read_probability",
    "read_trajectory",
    "run",
    "save_trajectory",
    "stream",
    "synth_presets",
    "to_evo",
    "__version__",
]

PathLike = Union[str, "os.PathLike[str]"]
ProgressCallback = Callable[[str, str, Any], None]


class _TqdmProgress:
    """Progress events shown as one tqdm bar per task (a SLAM pass, the motion maps)."""

    def __init__(self, tqdm: Any) -> None:
        self._tqdm = tqdm
        self._bars: dict = {}

    def __call__(self, kind: str, task: str, value: Any) -> None:
        if kind == "begin":
            self._bars[task] = self._tqdm(total=int(value), desc=task, leave=False)
        elif kind == "step":
            bar = self._bars.get(task)
            if bar is not None:
                if value:
                    bar.set_postfix_str(str(value), refresh=False)
                bar.update(1)
        elif kind == "end":
            bar = self._bars.pop(task, None)
            if bar is not None:
                bar.close()


def _progress(progress: Union[bool, ProgressCallback, None]) -> Optional[ProgressCallback]:
    """The callback for ``progress``: a callable as given, True → tqdm bars when tqdm is
    installed (else nothing), False/None → nothing."""
    if callable(progress):
        return progress
    if progress:
        try:
            from tqdm.auto import tqdm
        except ImportError:
            return None
        return _TqdmProgress(tqdm)
    return None


def run(
    seq_dir: PathLike,
    method: Optional[str] = None,
    config: Union[Config, dict, PathLike, None] = None,
    cache: Optional[PathLike] = None,
    progress: Union[bool, ProgressCallback, None] = True,
    *,
    camera: Union[Camera, str, PathLike, None] = None,
    masks: Optional[PathLike] = None,
    association: Optional[PathLike] = None,
    recompute_maps: bool = False,
    allow_missing_maps: bool = False,
    **overrides: Any,
) -> RunResult:
    """Runs ``method`` (``dynapix``, ``dynapix+``, ``orbslam2``, …; default the
    configuration's, ``dynapix``) offline on the sequence folder ``seq_dir``, in this process,
    with the same trajectory as ``dynapix run``.

    ``config`` is a :class:`Config`, a dict or a JSON/YAML file; keyword ``overrides`` change
    it (``slam__seed=3``). ``cache`` is the motion-map cache folder (default
    ``SEQ_DIR/dynapix_cache``, or one under the user cache directory when the folder is
    read-only). ``progress``: True shows tqdm bars when tqdm is installed, or a callable
    ``progress(kind, task, value)`` with kind ``begin`` (value = total), ``step`` (value =
    message) or ``end``. The GIL is released while the method computes.

    Example::

        r = dynapix.run("rgbd_bonn_crowd")
        r.save("trajectory.txt")
        print(r.evaluate()["ate_rmse_m"])
    """
    cfg = Config(config, **overrides) if (overrides or not isinstance(config, Config)) else config
    if method is not None:
        cfg = cfg.replace(method=method)
    return _dynapix.run(
        os.fspath(seq_dir),
        cfg,
        camera=camera,
        cache=None if cache is None else os.fspath(cache),
        masks=None if masks is None else os.fspath(masks),
        association=None if association is None else os.fspath(association),
        recompute_maps=recompute_maps,
        allow_missing_maps=allow_missing_maps,
        progress=_progress(progress),
    )


def motion_maps(result: RunResult) -> Iterator[Any]:
    """The motion probability P (H×W float32 in [0, 1], or None for a frame without a map) of
    every frame of a DynaPix :class:`RunResult`, in frame order, read one at a time."""
    for i in range(len(result.frame_timestamps)):
        yield result.probability(i)


def stream(
    seq: Union[Sequence, PathLike],
    online: Optional[Online] = None,
    config: Union[Config, dict, PathLike, None] = None,
    *,
    lookahead: Optional[int] = None,
    raw_depth: bool = True,
) -> Iterator[FrameResult]:
    """Streams a sequence folder through the online mode: reads each frame as numpy arrays,
    pushes it and yields every :class:`FrameResult` as it is known (the frames waiting for
    their lookahead at the end too). ``online`` defaults to ``Online(seq.camera, config)``.
    Depth is pushed as the file's uint16 values (``raw_depth=True``) or float32 metres."""
    if not isinstance(seq, Sequence):
        seq = Sequence(os.fspath(seq), config)
    if online is None:
        online = Online(seq.camera, config, lookahead=lookahead)
    # Each frame is pushed with the next one (read ahead), as `dynapix run --online` does:
    # the next frame's pose-free motion cue is computed beside this frame's tracking.
    n = len(seq)
    nxt = seq.frame(0, raw_depth=raw_depth) if n else None
    for i in range(n):
        cur = nxt
        nxt = seq.frame(i + 1, raw_depth=raw_depth) if i + 1 < n else None
        r = online.push(*cur, next=nxt)
        if r is not None:
            yield r
    yield from online.finish()


def to_evo(timestamps: Any, poses: Any) -> Any:
    """Converts ``(timestamps, poses)`` (N and N×4×4 camera-to-world) to
    ``evo.core.trajectory.PoseTrajectory3D``; raises ImportError naming the package when
    ``evo`` is not installed. ``to_evo(*result.first_pass())`` and
    ``to_evo(result.timestamps, result.poses)`` both work."""
    try:
        from evo.core.trajectory import PoseTrajectory3D
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("to_evo needs the 'evo' package: pip install evo") from e
    import numpy as np

    return PoseTrajectory3D(
        poses_se3=[np.asarray(p, dtype=np.float64) for p in poses],
        timestamps=np.asarray(timestamps, dtype=np.float64),
    )
