//! Relative pose error with a fixed delta, like the TUM `evaluate_rpe.py --fixed_delta`
//! (spec §4.4): for every estimated pose i, pair it with the estimated pose j closest to
//! `t_i + Δt` (time delta) or `i + N` (frame delta); look up the ground-truth poses closest
//! to both stamps (rejecting the pair if either is further than twice the median
//! ground-truth interval); the error is `(E_i⁻¹E_j)·(G_i⁻¹G_j)⁻¹`, reported as translation
//! (metres) and rotation angle (degrees).
//!
//! Difference to the TUM tool: all pairs are used (the tool samples 10 000 at random when
//! there are more), so the result is deterministic.

use crate::error::{EvalError, Result};
use crate::stats::ErrorStats;
use dynapix_geometry::Se3;
use serde::Serialize;

/// The spacing of the compared pose pairs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RpeDelta {
    /// Pairs about this many seconds apart (TUM default 1 s).
    Seconds(f64),
    /// Pairs this many estimated frames apart.
    Frames(usize),
}

/// RPE parameters. `Default` = 1 s delta, no offset, scale 1.
#[derive(Debug, Clone, PartialEq)]
pub struct RpeParams {
    /// Pair spacing.
    pub delta: RpeDelta,
    /// Added to estimate stamps before looking up ground truth, seconds.
    pub offset: f64,
    /// Factor applied to estimated relative translations.
    pub scale: f64,
}

impl Default for RpeParams {
    fn default() -> Self {
        Self {
            delta: RpeDelta::Seconds(1.0),
            offset: 0.0,
            scale: 1.0,
        }
    }
}

/// Result of an RPE evaluation.
#[derive(Debug, Clone, Serialize)]
pub struct RpeResult {
    /// Translational error statistics, metres.
    pub translation: ErrorStats,
    /// Rotational error statistics, degrees.
    pub rotation_deg: ErrorStats,
    /// Number of pose pairs compared.
    pub pairs: usize,
}

/// Index of the element of sorted `v` closest to `x` (the earlier one on a tie, like the TUM
/// `find_closest_index`). `v` must be non-empty.
fn closest_index(v: &[f64], x: f64) -> usize {
    let i = v.partition_point(|&s| s < x);
    if i == 0 {
        return 0;
    }
    if i >= v.len() {
        return v.len() - 1;
    }
    if (v[i] - x).abs() < (x - v[i - 1]).abs() {
        i
    } else {
        i - 1
    }
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    dynapix_geometry::stats::median(&mut v)
}

/// Computes the RPE of `est` against `gt`; both must be sorted by timestamp.
pub fn rpe(gt: &[(f64, Se3)], est: &[(f64, Se3)], params: &RpeParams) -> Result<RpeResult> {
    let describe = || format!("{:?}", params.delta);
    match params.delta {
        RpeDelta::Seconds(d) if !(d.is_finite() && d > 0.0) => {
            return Err(EvalError::InvalidParameter {
                name: "rpe delta",
                reason: format!("must be positive, got {d} s"),
            });
        }
        RpeDelta::Frames(0) => {
            return Err(EvalError::InvalidParameter {
                name: "rpe delta",
                reason: "must be at least 1 frame".into(),
            });
        }
        _ => {}
    }
    if est.len() < 2 || gt.len() < 2 {
        return Err(EvalError::NoRpePairs(describe()));
    }
    let gt_t: Vec<f64> = gt.iter().map(|p| p.0).collect();
    let est_t: Vec<f64> = est.iter().map(|p| p.0).collect();
    let gt_interval = median(gt_t.windows(2).map(|w| w[1] - w[0]).collect())
        .ok_or_else(|| EvalError::NoRpePairs(describe()))?;
    let max_gt_diff = 2.0 * gt_interval;

    let last = est.len() - 1;
    let mut trans = Vec::new();
    let mut rot = Vec::new();
    for i in 0..est.len() {
        let j = match params.delta {
            RpeDelta::Seconds(d) => closest_index(&est_t, est_t[i] + d),
            RpeDelta::Frames(n) => (i + n).min(last),
        };
        // The TUM tool drops pairs whose partner is the last pose: it is where every stamp
        // beyond the end lands.
        if j == last || j == i {
            continue;
        }
        let t0 = est_t[i] + params.offset;
        let t1 = est_t[j] + params.offset;
        let g0 = closest_index(&gt_t, t0);
        let g1 = closest_index(&gt_t, t1);
        if (gt_t[g0] - t0).abs() > max_gt_diff || (gt_t[g1] - t1).abs() > max_gt_diff {
            continue;
        }
        let mut est_rel = est[i].1.inverse() * est[j].1;
        est_rel.translation.vector *= params.scale;
        let gt_rel = gt[g0].1.inverse() * gt[g1].1;
        // TUM: ominus(ominus(E_j, E_i), ominus(G_j, G_i)) with ominus(a, b) = a⁻¹·b, i.e.
        // (E_i⁻¹E_j)·(G_i⁻¹G_j)⁻¹. The rotation angle is the same either way round, the
        // translation is not, so the tool's order is kept.
        let err = est_rel * gt_rel.inverse();
        trans.push(err.translation.vector.norm());
        // Same angle as TUM's arccos((trace(R) − 1)/2), but from the quaternion with atan2,
        // which stays accurate near zero where arccos loses half the digits.
        let q = err.rotation.quaternion();
        let angle = 2.0 * q.imag().norm().atan2(q.w.abs());
        rot.push(angle.to_degrees());
    }
    let (Some(t), Some(r)) = (
        ErrorStats::from_values(&trans),
        ErrorStats::from_values(&rot),
    ) else {
        return Err(EvalError::NoRpePairs(describe()));
    };
    Ok(RpeResult {
        translation: t,
        rotation_deg: r,
        pairs: trans.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynapix_geometry::se3;
    use nalgebra::Vector6;

    fn path(n: usize, dt: f64) -> Vec<(f64, Se3)> {
        (0..n)
            .map(|k| {
                let t = k as f64 * dt;
                (
                    t,
                    se3::exp(&Vector6::new(0.0, 0.0, 0.3 * t, t, 0.2 * t * t, 0.0)),
                )
            })
            .collect()
    }

    #[test]
    fn exact_copy_in_another_frame_has_zero_rpe() {
        let gt = path(1000, 0.01);
        let w = se3::exp(&Vector6::new(0.5, 0.1, -0.3, 3.0, 2.0, 1.0));
        let est: Vec<_> = gt.iter().step_by(3).map(|(t, p)| (*t, w * p)).collect();
        let r = rpe(&gt, &est, &RpeParams::default()).expect("rpe");
        assert!(r.pairs > 200);
        assert!(r.translation.max < 1e-9 && r.rotation_deg.max < 1e-6);
    }

    #[test]
    fn constant_drift_per_step_is_measured() {
        // Each frame-to-frame step of the estimate is longer by 1 cm along x of the camera:
        // with a 1-frame delta every pair shows exactly that error.
        let gt: Vec<_> = (0..100)
            .map(|k| {
                (
                    k as f64,
                    se3::exp(&Vector6::new(0.0, 0.0, 0.0, k as f64, 0.0, 0.0)),
                )
            })
            .collect();
        let est: Vec<_> = (0..100)
            .map(|k| {
                let x = k as f64 * 1.01;
                (
                    k as f64,
                    se3::exp(&Vector6::new(0.0, 0.0, 0.0, x, 0.0, 0.0)),
                )
            })
            .collect();
        let p = RpeParams {
            delta: RpeDelta::Frames(1),
            ..RpeParams::default()
        };
        let r = rpe(&gt, &est, &p).expect("rpe");
        assert_eq!(r.pairs, 98);
        assert!((r.translation.mean - 0.01).abs() < 1e-12);
        assert!((r.translation.std).abs() < 1e-12);
    }

    #[test]
    fn bad_delta_is_rejected() {
        let gt = path(10, 0.1);
        let p = RpeParams {
            delta: RpeDelta::Seconds(-1.0),
            ..RpeParams::default()
        };
        assert!(matches!(
            rpe(&gt, &gt, &p),
            Err(EvalError::InvalidParameter { .. })
        ));
    }
}
