//! One evaluation of one estimated trajectory: ATE, optional RPE and optional tracking rate
//! (against reference frame stamps, inside the ground-truth time span), gathered into a
//! serialisable report. This is what `dynapix eval --json` prints.

use crate::ate::{AteParams, AteResult, ate};
use crate::error::{EvalError, Result};
use crate::rpe::{RpeParams, RpeResult, rpe};
use crate::tracking::{TrackingParams, TrackingResult, tracking_rate};
use dynapix_geometry::Se3;
use serde::Serialize;

/// Everything one evaluation needs to know. `Default` = reference `eval.py` behaviour, ATE
/// only.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EvalParams {
    /// ATE (association, alignment).
    pub ate: AteParams,
    /// RPE, if wanted.
    pub rpe: Option<RpeParams>,
    /// Tracking rate (used when reference stamps are given). Its window is intersected with
    /// the ground-truth time span and with `ate.assoc.window`.
    pub tracking: TrackingParams,
}

/// Result of [`evaluate`].
#[derive(Debug, Clone)]
pub struct Evaluation {
    /// ATE with per-pair details.
    pub ate: AteResult,
    /// RPE, when requested.
    pub rpe: Option<RpeResult>,
    /// Tracking rate, when reference stamps were given.
    pub tracking: Option<TrackingResult>,
    /// Whether the alignment estimated a scale (Sim3).
    pub sim3: bool,
}

/// Flat, serialisable summary of an [`Evaluation`] (the `--json` contract: at least
/// `ate_rmse_m`, `pairs` and `motionless_floor_m`, plus `tracking_rate` and `missing_time_s`
/// with a reference).
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// ATE RMSE, metres.
    pub ate_rmse_m: f64,
    /// ATE mean, metres.
    pub ate_mean_m: f64,
    /// ATE median, metres.
    pub ate_median_m: f64,
    /// ATE standard deviation, metres.
    pub ate_std_m: f64,
    /// Smallest per-pair error, metres.
    pub ate_min_m: f64,
    /// Largest per-pair error, metres.
    pub ate_max_m: f64,
    /// Matched pose pairs.
    pub pairs: usize,
    /// ATE RMSE of a motionless camera on the same pairs after the same alignment, metres
    /// ([`crate::ate::motionless_floor`]).
    pub motionless_floor_m: f64,
    /// `"se3"` or `"sim3"`.
    pub alignment: &'static str,
    /// Alignment scale (1 for SE3).
    pub alignment_scale: f64,
    /// Alignment rotation as quaternion `[qx, qy, qz, qw]`.
    pub alignment_rotation_xyzw: [f64; 4],
    /// Alignment translation, metres.
    pub alignment_translation_m: [f64; 3],
    /// RPE translation RMSE, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rpe_trans_rmse_m: Option<f64>,
    /// RPE rotation RMSE, degrees.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rpe_rot_rmse_deg: Option<f64>,
    /// RPE full statistics.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rpe: Option<RpeResult>,
    /// Tracking rate in [0, 1].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tracking_rate: Option<f64>,
    /// Missing time, seconds.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub missing_time_s: Option<f64>,
    /// Duration of the reference frames in the window, seconds.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub duration_s: Option<f64>,
    /// Reference frames in the window.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference_frames: Option<usize>,
    /// Reference frames without a pose.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub missing_frames: Option<usize>,
}

impl Evaluation {
    /// ATE RMSE a motionless camera would score on the same pairs (metres).
    pub fn motionless_floor(&self) -> f64 {
        self.ate.motionless_floor
    }

    /// The flat report.
    pub fn report(&self) -> Report {
        let s = &self.ate.stats;
        let tr = &self.ate.alignment.transform;
        let q = tr.isometry.rotation.quaternion();
        let t = tr.isometry.translation.vector;
        let scale = self.ate.alignment.scale();
        Report {
            ate_rmse_m: s.rmse,
            ate_mean_m: s.mean,
            ate_median_m: s.median,
            ate_std_m: s.std,
            ate_min_m: s.min,
            ate_max_m: s.max,
            pairs: s.count,
            motionless_floor_m: self.ate.motionless_floor,
            alignment: if self.sim3 { "sim3" } else { "se3" },
            alignment_scale: scale,
            alignment_rotation_xyzw: [q.i, q.j, q.k, q.w],
            alignment_translation_m: [t.x, t.y, t.z],
            rpe_trans_rmse_m: self.rpe.as_ref().map(|r| r.translation.rmse),
            rpe_rot_rmse_deg: self.rpe.as_ref().map(|r| r.rotation_deg.rmse),
            rpe: self.rpe.clone(),
            tracking_rate: self.tracking.map(|t| t.tracking_rate),
            missing_time_s: self.tracking.map(|t| t.missing_time_s),
            duration_s: self.tracking.map(|t| t.duration_s),
            reference_frames: self.tracking.map(|t| t.frames),
            missing_frames: self.tracking.map(|t| t.missing_frames),
        }
    }
}

/// The tracking-rate window: ground-truth span ∩ user window ∩ `tracking.window`.
pub fn tracking_window(gt: &[(f64, Se3)], params: &EvalParams) -> Option<(f64, f64)> {
    let (first, last) = (gt.first()?.0, gt.last()?.0);
    let mut w = (first, last);
    for extra in [params.ate.assoc.window, params.tracking.window]
        .into_iter()
        .flatten()
    {
        w = (w.0.max(extra.0), w.1.min(extra.1));
    }
    Some(w)
}

/// Evaluates `est` against `gt`; `reference` (frame stamps of the sequence) enables the
/// tracking rate.
pub fn evaluate(
    gt: &[(f64, Se3)],
    est: &[(f64, Se3)],
    reference: Option<&[f64]>,
    params: &EvalParams,
) -> Result<Evaluation> {
    for (name, traj) in [("ground-truth", gt), ("estimated", est)] {
        if let Some((t, _)) = traj
            .iter()
            .find(|(t, p)| !t.is_finite() || p.to_homogeneous().iter().any(|v| !v.is_finite()))
        {
            return Err(EvalError::NonFinite(format!("the {name} pose at t = {t}")));
        }
        // Said before association, so a short sequence is not blamed on the clocks.
        if traj.len() < params.ate.min_pairs {
            return Err(EvalError::TooFewPoses {
                which: name,
                got: traj.len(),
                needed: params.ate.min_pairs,
            });
        }
    }
    let ate_result = ate(gt, est, &params.ate)?;
    if !ate_result.stats.rmse.is_finite() {
        return Err(EvalError::NonFinite(format!(
            "the ATE RMSE is {} (poses too large to square: check the units of the trajectory)",
            ate_result.stats.rmse
        )));
    }
    let rpe_result = match &params.rpe {
        Some(p) => Some(rpe(gt, est, p)?),
        None => None,
    };
    let tracking = match reference {
        Some(r) => {
            let est_t: Vec<f64> = est.iter().map(|p| p.0).collect();
            let tp = TrackingParams {
                window: tracking_window(gt, params),
                ..params.tracking.clone()
            };
            Some(tracking_rate(r, &est_t, &tp)?)
        }
        None => None,
    };
    Ok(Evaluation {
        ate: ate_result,
        rpe: rpe_result,
        tracking,
        sim3: params.ate.sim3,
    })
}

#[cfg(test)]
mod non_finite_tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn traj(scale: f64) -> Vec<(f64, Se3)> {
        (0..20)
            .map(|i| {
                let t = i as f64 * 0.1;
                let p = Se3::from_parts(
                    Translation3::new(scale * t, 0.1 * (t * 3.0).sin(), 0.0),
                    UnitQuaternion::from_euler_angles(0.0, 0.05 * t, 0.0),
                );
                (t, p)
            })
            .collect()
    }

    #[test]
    fn non_finite_poses_and_results_are_errors_not_nan() {
        let gt = traj(1.0);
        let p = EvalParams::default();
        assert!(evaluate(&gt, &traj(1.0), None, &p).is_ok());
        // A pose whose square overflows: the RMSE would be infinite or NaN.
        let mut huge = traj(1.0);
        huge[5].1.translation.vector.x = 1e200;
        let e = evaluate(&gt, &huge, None, &p).unwrap_err();
        assert!(matches!(e, EvalError::NonFinite(_)), "{e}");
        // A NaN pose is named by its time.
        let mut nan = traj(1.0);
        nan[3].1.translation.vector.y = f64::NAN;
        let e = evaluate(&gt, &nan, None, &p).unwrap_err().to_string();
        assert!(e.contains("estimated pose at t = 0.3"), "{e}");
    }
}
