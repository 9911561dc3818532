//! The evaluation of one run from poses in memory: what `dynapix run` records in `eval.json`
//! (ATE RMSE, pairs, tracking rate, missing time, motionless floor), with an evaluation that
//! fails recorded in the result instead of returned. [`crate::files::evaluate_run`] is the
//! same for a trajectory file.

use std::path::Path;

use crate::aggregate::RunResult;
use crate::error::EvalError;
use crate::report::{EvalParams, Evaluation, evaluate};
use dynapix_geometry::Se3;

/// A run's result with the motionless floor on its pairs. Serialises as the [`RunResult`]
/// fields plus `motionless_floor_m` (what `eval.json` of a run should hold).
#[derive(Debug, Clone, serde::Serialize)]
pub struct RunEvaluation {
    /// The run's figures.
    #[serde(flatten)]
    pub result: RunResult,
    /// ATE RMSE of a motionless camera on the run's pairs, metres (`None` when the ATE could
    /// not be computed).
    pub motionless_floor_m: Option<f64>,
}

/// A [`RunEvaluation`] and, when the ATE could be computed, the full evaluation behind it
/// (per-pair errors for the plots).
#[derive(Debug, Clone)]
pub struct RunScore {
    /// What `eval.json` holds.
    pub run: RunEvaluation,
    /// The evaluation (`None` when it failed; the error is in `run.result.error`).
    pub evaluation: Option<Evaluation>,
}

/// A failed run's result: the error, and the tracking rate when it is still meaningful.
fn failed(name: &str, e: &EvalError, tr: Option<(f64, f64)>) -> RunScore {
    RunScore {
        run: RunEvaluation {
            result: RunResult {
                name: name.to_string(),
                ate_rmse_m: None,
                pairs: 0,
                tracking_rate: tr.map(|x| x.0),
                missing_time_s: tr.map(|x| x.1),
                error: Some(e.to_string()),
            },
            motionless_floor_m: None,
        },
        evaluation: None,
    }
}

/// Evaluates the estimate `est` of one run against the ground truth `gt` (both
/// camera-to-world, sorted by time); `reference` frame stamps give the tracking rate.
/// `source` names the estimate (its file name is the result's `name`, the whole path is
/// used in the message of an empty estimate). Errors are recorded, not returned.
pub fn score_run(
    gt: &[(f64, Se3)],
    est: &[(f64, Se3)],
    source: &Path,
    reference: Option<&[f64]>,
    params: &EvalParams,
) -> RunScore {
    let name = source
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    if est.is_empty() {
        let e = EvalError::Empty {
            path: source.to_path_buf(),
        };
        return failed(&name, &e, None);
    }
    match evaluate(gt, est, reference, params) {
        Ok(ev) => RunScore {
            run: RunEvaluation {
                result: RunResult {
                    name,
                    ate_rmse_m: Some(ev.ate.stats.rmse),
                    pairs: ev.ate.stats.count,
                    tracking_rate: ev.tracking.map(|t| t.tracking_rate),
                    missing_time_s: ev.tracking.map(|t| t.missing_time_s),
                    error: None,
                },
                motionless_floor_m: Some(ev.motionless_floor()),
            },
            evaluation: Some(ev),
        },
        Err(e) => {
            // ATE failed (e.g. no overlapping stamps): the tracking rate is still meaningful.
            let tr = reference.and_then(|r| {
                let est_t: Vec<f64> = est.iter().map(|p| p.0).collect();
                let tp = crate::tracking::TrackingParams {
                    window: crate::report::tracking_window(gt, params),
                    ..params.tracking.clone()
                };
                crate::tracking::tracking_rate(r, &est_t, &tp)
                    .ok()
                    .map(|t| (t.tracking_rate, t.missing_time_s))
            });
            failed(&name, &e, tr)
        }
    }
}

/// [`score_run`] of the trajectory `est` as it reads back from the TUM file it is written to
/// (`source`: 6 decimals for the stamp, 9 for the pose, read strictly like
/// [`crate::files::read_trajectory`]), so that a run scored in memory gets the figures of
/// its `trajectory.txt` to the last digit.
pub fn score_written(
    gt: &[(f64, Se3)],
    est: &dynapix_io::Trajectory,
    source: &Path,
    reference: Option<&[f64]>,
    params: &EvalParams,
) -> RunScore {
    match dynapix_io::Trajectory::parse_tum_strict(&est.to_tum_string(), source) {
        Ok(written) => score_run(gt, &written.pairs(), source, reference, params),
        Err(e) => {
            let name = source
                .file_name()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            failed(&name, &EvalError::File(e), None)
        }
    }
}

/// [`score_run`] without the evaluation behind it.
pub fn evaluate_run_poses(
    gt: &[(f64, Se3)],
    est: &[(f64, Se3)],
    source: &Path,
    reference: Option<&[f64]>,
    params: &EvalParams,
) -> RunEvaluation {
    score_run(gt, est, source, reference, params).run
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(n: usize, dt: f64, speed: f64) -> Vec<(f64, Se3)> {
        (0..n)
            .map(|k| {
                let t = k as f64 * dt;
                (t, Se3::translation(speed * t, 0.0, 0.0))
            })
            .collect()
    }

    #[test]
    fn a_still_estimate_scores_its_floor_and_keeps_the_evaluation() {
        // Ground truth along x at 1 m/s for 2 s; a motionless estimate at 10 Hz.
        let gt = line(201, 0.01, 1.0);
        let est = line(21, 0.1, 0.0);
        let stamps: Vec<f64> = est.iter().map(|p| p.0).collect();
        let s = score_run(
            &gt,
            &est,
            Path::new("out/trajectory.txt"),
            Some(&stamps),
            &EvalParams::default(),
        );
        let floor = s.run.motionless_floor_m.expect("floor");
        assert!(
            (floor - (0.11f64 * 10.0 / 3.0).sqrt()).abs() < 1e-9,
            "{floor}"
        );
        assert_eq!(s.run.result.name, "trajectory.txt");
        assert_eq!(s.run.result.pairs, 21);
        assert_eq!(s.run.result.tracking_rate, Some(1.0));
        let ev = s.evaluation.expect("evaluation");
        assert_eq!(ev.ate.stats.rmse, s.run.result.ate_rmse_m.expect("ate"));
    }

    #[test]
    fn failures_are_recorded_with_the_tracking_rate_when_it_means_something() {
        let gt = line(201, 0.01, 1.0);
        // No pose: the message names the source.
        let s = score_run(
            &gt,
            &[],
            Path::new("d/trajectory.txt"),
            None,
            &EvalParams::default(),
        );
        let e = s.run.result.error.expect("error");
        assert!(
            e.contains("d/trajectory.txt") && e.contains("no poses"),
            "{e}"
        );
        assert!(s.evaluation.is_none() && s.run.motionless_floor_m.is_none());
        // Two poses: too few for an ATE, but they tracked a tenth of the reference frames.
        let est = line(2, 0.01, 1.0);
        let stamps: Vec<f64> = (0..21).map(|k| k as f64 * 0.1).collect();
        let s = score_run(
            &gt,
            &est,
            Path::new("trajectory.txt"),
            Some(&stamps),
            &EvalParams::default(),
        );
        assert!(s.run.result.ate_rmse_m.is_none());
        let tr = s.run.result.tracking_rate.expect("tracking rate");
        assert!(tr < 0.2, "{tr}");
        assert!(s.run.result.error.expect("error").contains("2 pose(s)"));
    }

    #[test]
    fn a_trajectory_scored_as_written_matches_its_file() {
        let dir = tempfile::tempdir().expect("tmp");
        let gt = line(201, 0.01, 1.0);
        // An estimate with digits beyond what the TUM text keeps, and a small drift.
        let est = dynapix_io::Trajectory::new(
            (0..21)
                .map(|k| {
                    let t = k as f64 * 0.1 + 1.234e-8;
                    let pose = Se3::translation(1.01 * t + 3.3e-11 * k as f64, 1e-10, 0.0);
                    dynapix_io::StampedPose::new(t, pose)
                })
                .collect(),
        );
        let path = dir.path().join("trajectory.txt");
        est.write_tum(&path).expect("write");
        let stamps: Vec<f64> = (0..21).map(|k| k as f64 * 0.1).collect();
        let params = EvalParams::default();
        let from_file = crate::files::evaluate_run(&gt, &path, Some(&stamps), &params);
        let from_memory = score_written(&gt, &est, &path, Some(&stamps), &params);
        assert_eq!(
            serde_json::to_string(&from_file).expect("json"),
            serde_json::to_string(&from_memory.run).expect("json")
        );
        assert!(from_memory.run.result.ate_rmse_m.expect("ate") > 1e-3);
    }
}
