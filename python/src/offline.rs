//! Sequences and the offline runner: `Sequence` (a folder's frames as numpy arrays),
//! `run(...)` (first pass → motion maps → weighted passes, in this process) and its
//! `RunResult` (poses, status, passes, the `run.json` record, the motion maps).

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use dynapix::{CameraChoice, Input, Progress, ProgressEvent};
use dynapix::{FrameStatus, Trajectory};
use dynapix::{OfflineRunner, RunOptions};
use numpy::{PyArray1, PyArray3};
use pyo3::prelude::*;
use serde_json::{Value, json};

use crate::arrays;
use crate::camera::{Camera, choice_arg};
use crate::config::{config_arg, to_python};
use crate::errors::{compute, data, guard};
use crate::evaluation::{self, EvalArgs};

/// Opens `seq_dir` for `config` with the camera argument (a `Camera` replaces the folder's).
pub fn open_input(
    py: Python<'_>,
    seq_dir: &Path,
    config: &dynapix::Config,
    camera: Option<&Bound<'_, PyAny>>,
    association: Option<&Path>,
) -> PyResult<Input> {
    let (choice, given) = choice_arg(camera)?;
    let choice = if given.is_some() {
        // Any camera opens the folder; the given one replaces it below.
        CameraChoice::Preset(dynapix::CameraPreset::Tum3)
    } else {
        choice
    };
    let seq = config.sequence.clone();
    let mut input = compute(py, || Input::open_with(seq_dir, &seq, &choice, association))?;
    if let Some(cam) = given {
        input.sequence.depth_factor = cam.settings.depth_map_factor;
        input.camera = cam;
    }
    Ok(input)
}

/// A sequence folder opened for reading: its frames as numpy arrays, stamps, camera and
/// ground truth (TUM, Bonn, GRADE layouts, or numbered ``rgb/``/``depth/`` images).
#[pyclass(name = "Sequence", module = "dynapix._dynapix", frozen)]
pub struct Sequence {
    input: Arc<Input>,
}

#[pymethods]
impl Sequence {
    /// Opens ``seq_dir``. ``config`` supplies the sequence options (``max_frames``,
    /// ``pairing``, ``max_diff``); ``camera`` is a ``Camera``, a preset name, a settings file
    /// or None for the folder's own; ``association`` an association file.
    #[new]
    #[pyo3(signature = (seq_dir, config=None, *, camera=None, association=None))]
    fn new(
        py: Python<'_>,
        seq_dir: PathBuf,
        config: Option<&Bound<'_, PyAny>>,
        camera: Option<&Bound<'_, PyAny>>,
        association: Option<PathBuf>,
    ) -> PyResult<Self> {
        let config = config_arg(config)?;
        let input = open_input(py, &seq_dir, &config, camera, association.as_deref())?;
        Ok(Self {
            input: Arc::new(input),
        })
    }

    fn __len__(&self) -> usize {
        self.input.len()
    }

    /// The sequence folder.
    #[getter]
    fn path(&self) -> PathBuf {
        self.input.sequence.dir.clone()
    }

    /// The camera the sequence is read with.
    #[getter]
    fn camera(&self) -> Camera {
        Camera {
            inner: self.input.camera.clone(),
        }
    }

    /// Frame times (s), float64 of length N.
    #[getter]
    fn timestamps<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        arrays::vec_array(py, self.input.timestamps())
    }

    /// ``(timestamps, poses)`` of ``groundtruth.txt`` as camera-to-world 4×4 poses (Bonn
    /// marker poses converted), or None without ground truth.
    fn ground_truth<'py>(&self, py: Python<'py>) -> PyResult<Option<arrays::Stamped<'py>>> {
        let Some(gt) = &self.input.sequence.groundtruth else {
            return Ok(None);
        };
        let t = gt.poses.iter().map(|p| p.t).collect();
        let poses = arrays::poses_array(py, gt.poses.iter().map(|p| p.pose))?;
        Ok(Some((arrays::vec_array(py, t), poses)))
    }

    /// Frame ``i`` as ``(t, rgb, depth)``: rgb H×W×3 uint8; depth H×W float32 metres, or
    /// the file's uint16 values with ``raw_depth=True``. Raises ``DataError`` for a frame
    /// whose files cannot be used.
    #[pyo3(signature = (i, *, raw_depth=false))]
    fn frame<'py>(
        &self,
        py: Python<'py>,
        i: usize,
        raw_depth: bool,
    ) -> PyResult<(f64, Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        if i >= self.input.len() {
            return Err(pyo3::exceptions::PyIndexError::new_err(format!(
                "frame {i} is out of range (the sequence has {} frames)",
                self.input.len()
            )));
        }
        let input = self.input.clone();
        let (rgb, depth) = compute(py, move || {
            let (rgb, depth) = input.load_rgbd(i)?;
            let raw = if raw_depth {
                Some(input.load_depth_raw(i)?)
            } else {
                None
            };
            Ok((rgb, (depth, raw)))
        })?;
        let (w, h) = rgb.dimensions();
        let rgb = arrays::image_array(py, rgb.into_raw(), w, h, 3)?;
        let depth = match depth {
            (_, Some(raw)) => arrays::image_array(py, raw.into_raw(), w, h, 0)?,
            (m, None) => arrays::image_array(py, m.into_raw(), w, h, 0)?,
        };
        Ok((self.input.sequence.frames[i].t, rgb, depth))
    }

    fn __repr__(&self) -> String {
        format!(
            "Sequence({:?}, {} frames, {}×{})",
            self.input.sequence.dir,
            self.input.len(),
            self.input.camera.settings.width,
            self.input.camera.settings.height
        )
    }
}

/// Progress events to a Python callable `callback(kind, task, value)`: ``("begin", task,
/// total)``, ``("step", task, message)``, ``("end", task, None)``. The first exception the
/// callback raises (or a pending KeyboardInterrupt) is raised when the run returns.
struct PyProgress {
    callback: Option<Py<PyAny>>,
    error: Mutex<Option<PyErr>>,
}

impl PyProgress {
    fn new(callback: Option<Py<PyAny>>) -> Self {
        Self {
            callback,
            error: Mutex::new(None),
        }
    }

    fn take_error(&self) -> Option<PyErr> {
        self.error.lock().ok().and_then(|mut e| e.take())
    }
}

impl Progress for PyProgress {
    fn event(&self, e: ProgressEvent<'_>) {
        let Some(cb) = &self.callback else {
            return;
        };
        Python::attach(|py| {
            let r = py.check_signals().and_then(|_| match e {
                ProgressEvent::Begin { task, total } => cb.call1(py, ("begin", task, total)),
                ProgressEvent::Step { task, message } => cb.call1(py, ("step", task, message)),
                ProgressEvent::End { task } => cb.call1(py, ("end", task, py.None())),
            });
            if let Err(err) = r
                && let Ok(mut slot) = self.error.lock()
                && slot.is_none()
            {
                *slot = Some(err);
            }
        });
    }
}

/// The result of an offline run: the final pass's trajectory, every frame's status, the
/// passes' statistics, the provenance record and the final motion maps.
#[pyclass(name = "RunResult", module = "dynapix._dynapix", frozen)]
pub struct RunResult {
    trajectory: Trajectory,
    status: Vec<(f64, FrameStatus)>,
    passes: Vec<Value>,
    first_pass: Option<Trajectory>,
    record: dynapix::RunRecord,
    maps_dir: Option<PathBuf>,
    map_paths: Vec<Option<PathBuf>>,
    frame_stamps: Vec<f64>,
    groundtruth: Option<PathBuf>,
}

/// The stamps and poses of a trajectory as arrays.
fn trajectory_arrays<'py>(py: Python<'py>, t: &Trajectory) -> PyResult<arrays::Stamped<'py>> {
    Ok((
        arrays::vec_array(py, t.poses.iter().map(|p| p.t).collect()),
        arrays::poses_array(py, t.poses.iter().map(|p| p.pose))?,
    ))
}

#[pymethods]
impl RunResult {
    /// Camera-to-world poses of the tracked frames, N×4×4 float64.
    #[getter]
    fn poses<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f64>>> {
        arrays::poses_array(py, self.trajectory.poses.iter().map(|p| p.pose))
    }

    /// Times (s) of the tracked frames, float64 of length N (the rows of ``poses``).
    #[getter]
    fn timestamps<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        arrays::vec_array(py, self.trajectory.poses.iter().map(|p| p.t).collect())
    }

    /// Times (s) of every frame of the sequence.
    #[getter]
    fn frame_timestamps<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        arrays::vec_array(py, self.frame_stamps.clone())
    }

    /// Per frame of the final pass: ``tracked``, ``lost`` or ``not_initialized``.
    #[getter]
    fn status(&self) -> Vec<&'static str> {
        self.status.iter().map(|s| s.1.as_str()).collect()
    }

    /// Number of tracked frames.
    #[getter]
    fn tracked(&self) -> usize {
        self.trajectory.poses.len()
    }

    /// Statistics of each SLAM pass (frames, tracked, keyframes, map points, loops, …), the
    /// final pass last.
    #[getter]
    fn passes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_python(py, &Value::Array(self.passes.clone()))
    }

    /// ``(timestamps, poses)`` of the first pass (the poses the first motion maps used),
    /// or None for a single-pass method.
    fn first_pass<'py>(&self, py: Python<'py>) -> PyResult<Option<arrays::Stamped<'py>>> {
        self.first_pass
            .as_ref()
            .map(|t| trajectory_arrays(py, t))
            .transpose()
    }

    /// The provenance record (what ``dynapix run`` writes to ``run.json``).
    #[getter]
    fn record<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let v = serde_json::to_value(&self.record)
            .map_err(|e| pyo3::exceptions::PyValueError::new_err(e.to_string()))?;
        to_python(py, &v)
    }

    /// Folder of the final pass's motion maps (None for a method without maps).
    #[getter]
    fn maps_dir(&self) -> Option<PathBuf> {
        self.maps_dir.clone()
    }

    /// The motion probability P of frame ``i`` used by the final pass, H×W float32 in
    /// [0, 1] (None when the method has no maps or the frame has none).
    fn probability<'py>(&self, py: Python<'py>, i: usize) -> PyResult<Option<Bound<'py, PyAny>>> {
        if self.maps_dir.is_none() {
            return Ok(None);
        }
        let Some(path) = self.map_paths.get(i).ok_or_else(|| {
            pyo3::exceptions::PyIndexError::new_err(format!(
                "frame {i} is out of range (the run has {} frames)",
                self.map_paths.len()
            ))
        })?
        else {
            return Ok(None);
        };
        if !path.is_file() {
            return Ok(None);
        }
        read_probability(py, path.clone()).map(Some)
    }

    /// Writes the trajectory in TUM format (``t tx ty tz qx qy qz qw``), the same bytes as
    /// ``dynapix run``'s ``trajectory.txt``.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let t = self.trajectory.clone();
        compute(py, move || Ok(t.write_tum(&path)?))
    }

    /// Evaluates the trajectory (as written to a file) against ground truth: the sequence's
    /// ``groundtruth.txt`` unless ``gt`` is given (a path, ``(timestamps, poses)`` or an
    /// N×8 TUM array). Returns the ``dynapix eval`` report as a dict (``ate_rmse_m``,
    /// ``motionless_floor_m``, ``tracking_rate`` over the sequence's frames, ``rpe_*`` with
    /// ``rpe_seconds``/``rpe_frames``, ``alignment`` ``se3`` or ``sim3``).
    #[pyo3(signature = (gt=None, *, sim3=false, rpe_seconds=None, rpe_frames=None, max_diff=0.02))]
    fn evaluate<'py>(
        &self,
        py: Python<'py>,
        gt: Option<&Bound<'py, PyAny>>,
        sim3: bool,
        rpe_seconds: Option<f64>,
        rpe_frames: Option<usize>,
        max_diff: f64,
    ) -> PyResult<Bound<'py, PyAny>> {
        let gt = match gt {
            Some(g) => evaluation::poses_arg(g, "gt", true)?,
            None => {
                let p = self
                    .groundtruth
                    .clone()
                    .ok_or_else(|| data("the sequence has no groundtruth.txt: pass gt=..."))?;
                compute(py, move || dynapix::evaluate::read_ground_truth(&p))?
            }
        };
        let written = guard(|| {
            Ok(dynapix::Trajectory::parse_tum(
                &self.trajectory.to_tum_string(),
                std::path::Path::new("<trajectory>"),
            )?)
        })?;
        let est: Vec<_> = written.poses.iter().map(|p| (p.t, p.pose)).collect();
        let args = EvalArgs::new(sim3, rpe_seconds, rpe_frames, max_diff)?;
        evaluation::report(py, gt, est, Some(self.frame_stamps.clone()), args)
    }

    fn __len__(&self) -> usize {
        self.trajectory.poses.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "RunResult({} of {} frames tracked, {} pass(es))",
            self.trajectory.poses.len(),
            self.frame_stamps.len(),
            self.passes.len()
        )
    }
}

/// Runs a method offline on the sequence folder ``seq_dir`` in this process (what
/// ``dynapix run`` does, without writing result files): for DynaPix the first pass, the
/// motion maps (cached in ``cache``, default ``SEQ_DIR/dynapix_cache`` or the user cache
/// when the folder is read-only) and the weighted passes. The GIL is released while it
/// computes. ``progress`` is a callable ``progress(kind, task, value)``.
#[pyfunction]
#[pyo3(signature = (seq_dir, config=None, *, camera=None, cache=None, masks=None, association=None, recompute_maps=false, allow_missing_maps=false, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn run(
    py: Python<'_>,
    seq_dir: PathBuf,
    config: Option<&Bound<'_, PyAny>>,
    camera: Option<&Bound<'_, PyAny>>,
    cache: Option<PathBuf>,
    masks: Option<PathBuf>,
    association: Option<PathBuf>,
    recompute_maps: bool,
    allow_missing_maps: bool,
    progress: Option<Py<PyAny>>,
) -> PyResult<RunResult> {
    let config = config_arg(config)?;
    let input = open_input(py, &seq_dir, &config, camera, association.as_deref())?;
    // As `dynapix run`: without a folder given, the sequence's own cache (or one under the
    // user cache directory when the sequence may not be written).
    let cache =
        cache.unwrap_or_else(|| dynapix::RunOptions::default_cache_dir(&input.sequence.dir));
    let options = RunOptions {
        cache_dir: Some(cache),
        recompute_maps,
        masks_dir: masks,
        allow_missing_maps,
        first_pass: None,
    };
    let progress = PyProgress::new(progress.filter(|p| !p.is_none(py)));
    let result = compute(py, || {
        let runner = OfflineRunner::new(&config, &input, options)?;
        let out = runner.run_with_seed(config.slam.seed, &progress)?;
        let last = out
            .final_pass()
            .ok_or_else(|| dynapix::Error::Input("the run produced no pass".into()))?;
        let mut record = out.record.clone();
        record.seed = Some(config.slam.seed);
        let maps = out.final_maps();
        Ok(RunResult {
            trajectory: last.trajectory.clone(),
            status: last.status.iter().map(|s| (s.t, s.status)).collect(),
            passes: out.passes.iter().map(|p| json!(p.stats)).collect(),
            first_pass: out.first_pass.as_ref().map(|f| f.trajectory.clone()),
            record,
            maps_dir: maps.and_then(|m| m.dir().map(Path::to_path_buf)),
            map_paths: (0..input.len())
                .map(|i| maps.and_then(|m| m.map_path(&input, i)))
                .collect(),
            frame_stamps: input.timestamps(),
            groundtruth: Some(input.sequence.dir.join("groundtruth.txt")).filter(|p| p.is_file()),
        })
    });
    if let Some(e) = progress.take_error() {
        return Err(e);
    }
    result
}

/// Reads a stored motion-probability map (16-bit PNG) as H×W float32 P in [0, 1].
#[pyfunction]
pub fn read_probability(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyAny>> {
    let p = compute(py, move || {
        Ok(dynapix::MotionProbability::read(&path)?.into_image())
    })?;
    let (w, h) = p.dimensions();
    arrays::image_array(py, p.into_raw(), w, h, 0)
}
