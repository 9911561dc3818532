//! Trajectory evaluation as `dynapix eval` and `dynapix run` compute it (ATE after Horn or
//! Umeyama alignment, RPE, tracking rate, motionless floor), from files or from poses in
//! memory, with the library's [`Error`]: the entry point of bindings that
//! should not reach into `dynapix-eval` themselves.

use std::path::Path;

use dynapix_eval::{EvalError, EvalParams, RpeParams};
use dynapix_geometry::Se3;

pub use dynapix_eval::{Evaluation, Report as EvalReport, RpeDelta, RunEvaluation, RunScore};
use dynapix_io::{Sequence, Trajectory};

use crate::{Error, Result};

/// What an evaluation computes beyond the ATE (defaults: SE(3) alignment, TUM association
/// within 0.02 s, no RPE), as `dynapix eval` flags choose it.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalOptions {
    /// Align with scale (Umeyama Sim(3)) instead of a rigid Horn alignment.
    pub sim3: bool,
    /// Relative pose error with this pair spacing, when wanted.
    pub rpe: Option<RpeDelta>,
    /// Largest time difference of an associated pair, seconds.
    pub max_diff: f64,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            sim3: false,
            rpe: None,
            max_diff: dynapix_eval::AssocParams::default().max_diff,
        }
    }
}

impl EvalOptions {
    /// The evaluation parameters of `dynapix-eval`.
    fn params(&self) -> EvalParams {
        let mut p = EvalParams::default();
        p.ate.sim3 = self.sim3;
        p.ate.assoc.max_diff = self.max_diff;
        p.rpe = self.rpe.map(|delta| RpeParams {
            delta,
            ..RpeParams::default()
        });
        p
    }
}

/// The library error of an evaluation error: file errors name the file, the rest are input
/// errors (too few pairs, a failed alignment, bad parameters).
fn eval_error(e: EvalError) -> Error {
    match e {
        EvalError::Io { path, source } => Error::file(path, source.to_string()),
        EvalError::Parse { path, line, reason } => {
            Error::file(path, format!("line {line}: {reason}"))
        }
        EvalError::File(e) => Error::Io(e),
        other => Error::Input(other.to_string()),
    }
}

/// Reads a TUM trajectory file (`timestamp tx ty tz qx qy qz qw`, camera-to-world).
pub fn read_trajectory(path: &Path) -> Result<Vec<(f64, Se3)>> {
    dynapix_eval::files::read_trajectory(path).map_err(eval_error)
}

/// Reads a sequence's `groundtruth.txt` as camera poses (Bonn marker poses are converted, as
/// the sequence reader and `dynapix run` do).
pub fn read_ground_truth(path: &Path) -> Result<Vec<(f64, Se3)>> {
    dynapix_eval::files::read_camera_ground_truth(path).map_err(eval_error)
}

/// Reads reference frame stamps: the first column of `rgb.txt`, an association file or a
/// trajectory.
pub fn read_reference_stamps(path: &Path) -> Result<Vec<f64>> {
    dynapix_eval::files::read_reference_stamps(path).map_err(eval_error)
}

/// Evaluates the estimate `est` against the ground truth `gt` (both camera-to-world, sorted
/// by time); with `reference` frame stamps also the tracking rate. The report is what
/// `dynapix eval --json` prints (ATE statistics, motionless floor, alignment, RPE, tracking).
pub fn evaluate(
    gt: &[(f64, Se3)],
    est: &[(f64, Se3)],
    reference: Option<&[f64]>,
    options: &EvalOptions,
) -> Result<EvalReport> {
    if !(options.max_diff.is_finite() && options.max_diff > 0.0) {
        return Err(Error::config(format!(
            "max_diff must be a positive number of seconds, got {}",
            options.max_diff
        )));
    }
    dynapix_eval::evaluate(gt, est, reference, &options.params())
        .map(|e| e.report())
        .map_err(eval_error)
}

/// What `dynapix run` writes to `eval.json` for the `trajectory` of a run on `sequence`,
/// from memory: scored against the sequence's ground truth (camera poses, read once when the
/// sequence was opened) with its frame stamps for the tracking rate, the trajectory taken
/// as its TUM file `source` reads back (so the figures are those of the file). `None`
/// without ground truth; an empty ground truth is an error, an ATE that cannot be computed
/// is recorded in the result.
pub fn score_run(
    sequence: &Sequence,
    trajectory: &Trajectory,
    source: &Path,
) -> Result<Option<RunScore>> {
    let Some(gt) = &sequence.groundtruth else {
        return Ok(None);
    };
    if gt.is_empty() {
        return Err(eval_error(EvalError::Empty {
            path: sequence
                .dir
                .join(dynapix_io::ground_truth::GROUNDTRUTH_FILE),
        }));
    }
    Ok(Some(dynapix_eval::run::score_written(
        &gt.pairs(),
        trajectory,
        source,
        Some(&sequence.timestamps()),
        &EvalParams::default(),
    )))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn track(n: usize, scale: f64) -> Vec<(f64, Se3)> {
        (0..n)
            .map(|i| {
                let t = i as f64 * 0.1;
                let p = Translation3::new(scale * t.sin(), scale * 0.5 * t, scale * t.cos());
                (t, Se3::from_parts(p, UnitQuaternion::identity()))
            })
            .collect()
    }

    #[test]
    fn sim3_recovers_a_scaled_estimate_and_se3_does_not() {
        let gt = track(50, 1.0);
        let est = track(50, 0.5);
        let se3 = evaluate(&gt, &est, None, &EvalOptions::default()).unwrap();
        let sim3 = EvalOptions {
            sim3: true,
            ..EvalOptions::default()
        };
        let sim = evaluate(&gt, &est, None, &sim3).unwrap();
        assert!(sim.ate_rmse_m < 1e-9, "{}", sim.ate_rmse_m);
        assert!(se3.ate_rmse_m > 0.05, "{}", se3.ate_rmse_m);
        assert!((sim.alignment_scale - 2.0).abs() < 1e-9);
        assert_eq!(sim.pairs, 50);
    }

    #[test]
    fn tracking_rate_and_errors() {
        let gt = track(50, 1.0);
        let est: Vec<_> = track(50, 1.0).into_iter().take(25).collect();
        let stamps: Vec<f64> = gt.iter().map(|p| p.0).collect();
        let r = evaluate(&gt, &est, Some(&stamps), &EvalOptions::default()).unwrap();
        let tr = r.tracking_rate.unwrap();
        assert!(tr > 0.4 && tr < 0.6, "{tr}");
        let none = evaluate(&gt, &[], None, &EvalOptions::default());
        assert!(matches!(none, Err(Error::Input(_))), "{none:?}");
        let bad = EvalOptions {
            max_diff: -1.0,
            ..EvalOptions::default()
        };
        assert!(matches!(
            evaluate(&gt, &est, None, &bad),
            Err(Error::Config { .. })
        ));
        let missing = read_trajectory(Path::new("/nonexistent/dynapix/traj.txt"));
        assert!(missing.is_err());
    }
}
