"""Type stubs of the extension module ``dynapix._dynapix`` (see the package docstring)."""

import os
from typing import Any, Callable, Optional, Sequence as _Seq, Tuple, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, os.PathLike[str]]
_Poses = Union[_Path, Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]], npt.NDArray[np.float64]]
_Progress = Callable[[str, str, Any], None]

__version__: str

class DynapixError(Exception):
    """Base class of every error raised by dynapix."""

class ConfigError(DynapixError):
    """A configuration value, key, preset or parameter is not valid."""

class DataError(DynapixError):
    """Input data that cannot be used (dtype, shape, size, order, too few poses)."""

class IoError(DynapixError):
    """Reading or writing a file failed."""

class Config:
    """The configuration of a DynaPix run (paper defaults)."""

    def __init__(self, values: Union[dict, _Path, "Config", None] = None, /, **overrides: Any) -> None: ...
    @staticmethod
    def from_file(path: _Path, /, **overrides: Any) -> "Config": ...
    @staticmethod
    def from_dict(values: dict, /, **overrides: Any) -> "Config": ...
    @staticmethod
    def from_json(text: str) -> "Config": ...
    @staticmethod
    def from_yaml(text: str) -> "Config": ...
    def replace(self, **overrides: Any) -> "Config": ...
    def to_dict(self) -> dict: ...
    def to_json(self, indent: Optional[int] = None) -> str: ...
    @property
    def method(self) -> str: ...
    @property
    def mode(self) -> str: ...
    @property
    def seed(self) -> int: ...

class Camera:
    """An RGB-D camera (intrinsics, distortion, depth factor, ORB settings)."""

    def __init__(
        self,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        width: int,
        height: int,
        *,
        dist: Optional[_Seq[float]] = None,
        depth_factor: float = 5000.0,
        fps: float = 30.0,
        bf: float = 40.0,
        th_depth: float = 40.0,
        n_features: int = 1000,
    ) -> None: ...
    @staticmethod
    def preset(name: str) -> "Camera": ...
    @staticmethod
    def from_settings(path: _Path) -> "Camera": ...
    @staticmethod
    def from_sequence(seq_dir: _Path) -> "Camera": ...
    @property
    def fx(self) -> float: ...
    @property
    def fy(self) -> float: ...
    @property
    def cx(self) -> float: ...
    @property
    def cy(self) -> float: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def dist(self) -> Tuple[float, float, float, float, float]: ...
    @property
    def depth_factor(self) -> float: ...
    @property
    def fps(self) -> float: ...
    @property
    def bf(self) -> float: ...
    @property
    def th_depth(self) -> float: ...
    def to_dict(self) -> dict: ...
    def to_yaml(self) -> str: ...

class Sequence:
    """A sequence folder opened for reading."""

    def __init__(
        self,
        seq_dir: _Path,
        config: Union[Config, dict, _Path, None] = None,
        *,
        camera: Union[Camera, str, _Path, None] = None,
        association: Optional[_Path] = None,
    ) -> None: ...
    def __len__(self) -> int: ...
    @property
    def path(self) -> str: ...
    @property
    def camera(self) -> Camera: ...
    @property
    def timestamps(self) -> npt.NDArray[np.float64]: ...
    def ground_truth(self) -> Optional[Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]]: ...
    def frame(
        self, i: int, *, raw_depth: bool = False
    ) -> Tuple[float, npt.NDArray[np.uint8], Union[npt.NDArray[np.float32], npt.NDArray[np.uint16]]]: ...

class RunResult:
    """The result of an offline run."""

    @property
    def poses(self) -> npt.NDArray[np.float64]: ...
    @property
    def timestamps(self) -> npt.NDArray[np.float64]: ...
    @property
    def frame_timestamps(self) -> npt.NDArray[np.float64]: ...
    @property
    def status(self) -> list[str]: ...
    @property
    def tracked(self) -> int: ...
    @property
    def passes(self) -> list[dict]: ...
    @property
    def record(self) -> dict: ...
    @property
    def maps_dir(self) -> Optional[str]: ...
    def first_pass(self) -> Optional[Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]]: ...
    def probability(self, i: int) -> Optional[npt.NDArray[np.float32]]: ...
    def save(self, path: _Path) -> None: ...
    def evaluate(
        self,
        gt: Optional[_Poses] = None,
        *,
        sim3: bool = False,
        rpe_seconds: Optional[float] = None,
        rpe_frames: Optional[int] = None,
        max_diff: float = 0.02,
    ) -> dict: ...
    def __len__(self) -> int: ...

def run(
    seq_dir: _Path,
    config: Union[Config, dict, _Path, None] = None,
    *,
    camera: Union[Camera, str, _Path, None] = None,
    cache: Optional[_Path] = None,
    masks: Optional[_Path] = None,
    association: Optional[_Path] = None,
    recompute_maps: bool = False,
    allow_missing_maps: bool = False,
    progress: Optional[_Progress] = None,
) -> RunResult: ...
def read_probability(path: _Path) -> npt.NDArray[np.float32]: ...

class FrameResult:
    """The result of one frame of the online mode."""

    index: int
    t: float
    status: str
    keyframe: bool
    latency_frames: int
    mean_probability: float
    motion_ms: float
    slam_ms: float
    @property
    def pose(self) -> Optional[npt.NDArray[np.float64]]: ...
    @property
    def tracked(self) -> bool: ...

class Online:
    """DynaPix online: numpy frames pushed one at a time."""

    def __init__(
        self,
        camera: Union[Camera, str, _Path],
        config: Union[Config, dict, _Path, None] = None,
        *,
        lookahead: Optional[int] = None,
    ) -> None: ...
    def push(
        self,
        t: float,
        rgb: npt.NDArray[np.uint8],
        depth: Union[npt.NDArray[np.uint16], npt.NDArray[np.float32]],
        mask: Optional[npt.NDArray[np.uint8]] = None,
        *,
        next: Optional[Tuple[Any, ...]] = None,
    ) -> Optional[FrameResult]: ...
    def finish(self) -> list[FrameResult]: ...
    def refined_trajectory(self) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...
    @property
    def camera(self) -> Camera: ...
    @property
    def frames_pushed(self) -> int: ...
    @property
    def keyframes(self) -> int: ...
    @property
    def map_points(self) -> int: ...
    @property
    def lookahead(self) -> int: ...

def evaluate(
    gt: _Poses,
    est: _Poses,
    *,
    reference: Union[_Path, npt.NDArray[np.float64], None] = None,
    sim3: bool = False,
    rpe_seconds: Optional[float] = None,
    rpe_frames: Optional[int] = None,
    max_diff: float = 0.02,
) -> dict: ...
def read_trajectory(path: _Path) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...
def save_trajectory(path: _Path, timestamps: Any, poses: Optional[npt.NDArray[np.float64]] = None) -> None: ...
def read_ground_truth(path: _Path) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...

class SyntheticFrame:
    """One rendered synthetic frame."""

    index: int
    t: float
    rgb: npt.NDArray[np.uint8]
    depth: npt.NDArray[np.uint16]
    mask: npt.NDArray[np.uint8]
    pose: npt.NDArray[np.float64]

class SyntheticSequence:
    """A synthetic dynamic RGB-D sequence rendered on demand."""

    def __init__(
        self,
        preset: str = "walking_xyz",
        *,
        frames: int = 300,
        seed: int = 0,
        width: Optional[int] = None,
        height: Optional[int] = None,
        realism: str = "kinect",
    ) -> None: ...
    def __len__(self) -> int: ...
    @property
    def camera(self) -> Camera: ...
    @property
    def depth_factor(self) -> float: ...
    def frame(self, i: int) -> SyntheticFrame: ...
    def write(self, out_dir: _Path) -> str: ...

def synth_presets() -> list[str]: ...
def augment(
    seq_dir: _Path, out_dir: _Path, *, seed: int = 0, objects: int = 3, max_frames: Optional[int] = None
) -> int: ...
