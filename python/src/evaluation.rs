//! Evaluation as `dynapix eval` computes it: ATE (SE(3) or Sim(3) alignment), RPE,
//! tracking rate and the motionless floor, from files or arrays.

use std::path::PathBuf;

use dynapix::evaluate::{EvalOptions, RpeDelta};
use dynapix_geometry::Se3;
use pyo3::prelude::*;
use pyo3::types::PyString;

use crate::arrays;
use crate::config::to_python;
use crate::errors::{compute, config};

/// The evaluation options of the keyword arguments.
pub struct EvalArgs(EvalOptions);

impl EvalArgs {
    /// Options from `sim3`, the RPE spacing (seconds or frames, not both) and `max_diff`.
    pub fn new(
        sim3: bool,
        rpe_seconds: Option<f64>,
        rpe_frames: Option<usize>,
        max_diff: f64,
    ) -> PyResult<Self> {
        let rpe = match (rpe_seconds, rpe_frames) {
            (Some(_), Some(_)) => return Err(config("give rpe_seconds or rpe_frames, not both")),
            (Some(s), None) if !(s.is_finite() && s > 0.0) => {
                return Err(config(format!("rpe_seconds must be positive, got {s}")));
            }
            (Some(s), None) => Some(RpeDelta::Seconds(s)),
            (None, Some(0)) => return Err(config("rpe_frames must be at least 1")),
            (None, Some(k)) => Some(RpeDelta::Frames(k)),
            (None, None) => None,
        };
        Ok(Self(EvalOptions {
            sim3,
            rpe,
            max_diff,
        }))
    }
}

/// Stamped poses of an argument: a file path (TUM trajectory, or ground truth when `gt`),
/// `(timestamps, poses)` or an N×8 TUM array.
pub fn poses_arg(obj: &Bound<'_, PyAny>, what: &str, gt: bool) -> PyResult<Vec<(f64, Se3)>> {
    if obj.is_instance_of::<PyString>() || obj.hasattr("__fspath__")? {
        let p: PathBuf = obj.extract()?;
        return compute(obj.py(), move || {
            if gt {
                dynapix::evaluate::read_ground_truth(&p)
            } else {
                dynapix::evaluate::read_trajectory(&p)
            }
        });
    }
    arrays::stamped_poses(obj, what)
}

/// The report of `est` against `gt` as a dict.
pub fn report<'py>(
    py: Python<'py>,
    gt: Vec<(f64, Se3)>,
    est: Vec<(f64, Se3)>,
    reference: Option<Vec<f64>>,
    args: EvalArgs,
) -> PyResult<Bound<'py, PyAny>> {
    let r = compute(py, move || {
        dynapix::evaluate::evaluate(&gt, &est, reference.as_deref(), &args.0)
    })?;
    let v = serde_json::to_value(&r).map_err(|e| config(e.to_string()))?;
    to_python(py, &v)
}

/// Evaluates an estimated trajectory against ground truth like ``dynapix eval``.
///
/// ``gt`` and ``est`` are file paths (``gt`` read as camera poses, Bonn marker poses
/// converted), ``(timestamps, poses)`` pairs (N and N×4×4 float64, camera-to-world) or N×8
/// TUM arrays. ``reference`` (frame stamps: a path to ``rgb.txt``/an association file, or a
/// float64 array) adds the tracking rate. ``sim3=True`` aligns with scale (Umeyama).
/// Returns a dict: ``ate_rmse_m``, ``ate_mean_m``, …, ``pairs``, ``motionless_floor_m``,
/// ``alignment``, ``alignment_scale``, ``rpe_trans_rmse_m``/``rpe_rot_rmse_deg`` (with
/// ``rpe_seconds`` or ``rpe_frames``), ``tracking_rate``/``missing_time_s`` (with
/// ``reference``). Raises ``DataError`` when too few poses match.
#[pyfunction]
#[pyo3(signature = (gt, est, *, reference=None, sim3=false, rpe_seconds=None, rpe_frames=None, max_diff=0.02))]
#[allow(clippy::too_many_arguments)]
pub fn evaluate<'py>(
    py: Python<'py>,
    gt: &Bound<'py, PyAny>,
    est: &Bound<'py, PyAny>,
    reference: Option<&Bound<'py, PyAny>>,
    sim3: bool,
    rpe_seconds: Option<f64>,
    rpe_frames: Option<usize>,
    max_diff: f64,
) -> PyResult<Bound<'py, PyAny>> {
    let args = EvalArgs::new(sim3, rpe_seconds, rpe_frames, max_diff)?;
    let gt = poses_arg(gt, "gt", true)?;
    let est = poses_arg(est, "est", false)?;
    let reference = match reference {
        None => None,
        Some(r) if r.is_none() => None,
        Some(r) if r.is_instance_of::<PyString>() || r.hasattr("__fspath__")? => {
            let p: PathBuf = r.extract()?;
            Some(compute(py, move || {
                dynapix::evaluate::read_reference_stamps(&p)
            })?)
        }
        Some(r) => Some(arrays::stamps(r, "reference")?),
    };
    report(py, gt, est, reference, args)
}

/// Reads a TUM trajectory file as ``(timestamps, poses)`` (N and N×4×4 float64).
#[pyfunction]
pub fn read_trajectory(py: Python<'_>, path: PathBuf) -> PyResult<arrays::Stamped<'_>> {
    let v = compute(py, move || dynapix::evaluate::read_trajectory(&path))?;
    split(py, v)
}

/// Reads a ground-truth file as camera poses ``(timestamps, poses)`` (Bonn marker poses
/// converted to the camera, as ``dynapix run`` evaluates).
#[pyfunction]
pub fn read_ground_truth(py: Python<'_>, path: PathBuf) -> PyResult<arrays::Stamped<'_>> {
    let v = compute(py, move || dynapix::evaluate::read_ground_truth(&path))?;
    split(py, v)
}

fn split(py: Python<'_>, v: Vec<(f64, Se3)>) -> PyResult<arrays::Stamped<'_>> {
    let t = v.iter().map(|p| p.0).collect();
    Ok((
        arrays::vec_array(py, t),
        arrays::poses_array(py, v.into_iter().map(|p| p.1))?,
    ))
}

/// Writes ``(timestamps, poses)`` (N and N×4×4 camera-to-world, or an N×8 TUM array), or
/// a list of online ``FrameResult`` (their poses exactly as reported, untracked frames left
/// out), as a TUM trajectory file (``t tx ty tz qx qy qz qw``) with the writer
/// ``dynapix run`` uses, atomically: frame results give the bytes of
/// ``dynapix run --online``.
#[pyfunction]
#[pyo3(signature = (path, timestamps, poses=None))]
pub fn save_trajectory(
    py: Python<'_>,
    path: PathBuf,
    timestamps: &Bound<'_, PyAny>,
    poses: Option<&Bound<'_, PyAny>>,
) -> PyResult<()> {
    let results: Option<Vec<(f64, Se3)>> =
        if poses.is_none() && timestamps.is_instance_of::<pyo3::types::PyList>() {
            let list = timestamps.cast::<pyo3::types::PyList>()?;
            let mut v = Vec::new();
            let mut all = true;
            for item in list.iter() {
                match item.cast::<crate::online::FrameResult>() {
                    Ok(r) => v.extend(r.get().pose_wc.map(|p| (r.get().t, p))),
                    Err(_) => all = false,
                }
            }
            all.then_some(v)
        } else {
            None
        };
    let v = match (results, poses) {
        (Some(v), _) => v,
        (None, Some(p)) => {
            let pair = pyo3::types::PyTuple::new(py, [timestamps, p])?;
            arrays::stamped_poses(pair.as_any(), "trajectory")?
        }
        (None, None) => arrays::stamped_poses(timestamps, "trajectory")?,
    };
    let t = dynapix::Trajectory::new(
        v.into_iter()
            .map(|(t, p)| dynapix::StampedPose::new(t, p))
            .collect(),
    );
    compute(py, move || Ok(t.write_tum(&path)?))
}
