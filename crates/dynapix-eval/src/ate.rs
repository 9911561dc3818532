//! Absolute trajectory error (spec §4.2): associate ground truth and estimate by timestamp,
//! align the estimated positions onto the ground truth in closed form (Horn, rotation and
//! translation; Umeyama with scale on request), then take statistics of the per-pair
//! position errors ‖R·p_est·s + t − p_gt‖. Lost frames are absent from the estimate and do
//! not contribute (their cost shows in the tracking rate instead).
//!
//! Every result carries the **motionless floor**: the ATE RMSE that a camera which never moves
//! (one constant pose for every pair) scores on the same pairs after the same alignment. An
//! estimate at or above it is no better than standing still. With rigid (Horn) alignment a
//! constant estimate is best placed at the ground-truth centroid, so the floor is the RMS
//! distance of the matched ground-truth positions from their centroid ([`motionless_floor`]).
//! With Sim(3) alignment the number is the same: `s·R·p + t` maps one point to one point
//! whatever the scale, so the best placement is again the centroid (Umeyama itself is
//! undefined for a source without spread, which is why the floor is computed in closed form).
//! Under Sim(3) the floor is a weaker yardstick, though: an estimate that barely moves can be
//! scaled up to follow the ground truth, so only scores well below it mean anything.

use crate::associate::{AssocParams, associate};
use crate::error::{EvalError, Result};
use crate::stats::ErrorStats;
use dynapix_geometry::Se3;
use dynapix_geometry::align::{Alignment, align_se3, align_sim3};
use nalgebra::Point3;
use serde::Serialize;

/// ATE parameters. `Default` = the TUM tool and `eval.py` defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct AteParams {
    /// Timestamp association.
    pub assoc: AssocParams,
    /// Align with scale (Umeyama Sim3) instead of rigid Horn alignment.
    pub sim3: bool,
    /// Factor applied to the estimated positions before alignment (TUM `--scale`).
    pub scale: f64,
    /// Minimum number of matched pairs (`eval.py` requires 2; alignment needs 3).
    pub min_pairs: usize,
}

impl Default for AteParams {
    fn default() -> Self {
        Self {
            assoc: AssocParams::default(),
            sim3: false,
            scale: 1.0,
            min_pairs: 3,
        }
    }
}

/// One matched pose pair after alignment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AtePair {
    /// Ground-truth timestamp, seconds.
    pub t_gt: f64,
    /// Estimate timestamp, seconds.
    pub t_est: f64,
    /// Ground-truth position.
    pub gt: [f64; 3],
    /// Aligned estimated position.
    pub est_aligned: [f64; 3],
    /// Position error, metres.
    pub error: f64,
}

/// Result of an ATE evaluation.
#[derive(Debug, Clone)]
pub struct AteResult {
    /// Statistics of the translational errors (metres); `count` = number of pairs.
    pub stats: ErrorStats,
    /// The alignment estimate → ground truth.
    pub alignment: Alignment,
    /// Per-pair details in ground-truth time order.
    pub pairs: Vec<AtePair>,
    /// ATE RMSE (metres) of a motionless camera on the same pairs after the same kind of
    /// alignment ([`motionless_floor`]; see the module doc).
    pub motionless_floor: f64,
}

/// The ATE RMSE of one constant pose against the ground-truth positions `gt` after optimal
/// alignment (rigid or with scale: the same value, see the module doc): the RMS distance of
/// the positions from their centroid. `None` for an empty slice.
pub fn motionless_floor(gt: &[Point3<f64>]) -> Option<f64> {
    if gt.is_empty() {
        return None;
    }
    let n = gt.len() as f64;
    let centroid = gt
        .iter()
        .fold(nalgebra::Vector3::zeros(), |a, p| a + p.coords)
        / n;
    let sum_sq: f64 = gt
        .iter()
        .map(|p| (p.coords - centroid).norm_squared())
        .sum();
    Some((sum_sq / n).sqrt())
}

/// Computes the ATE of `est` against `gt` (both `(timestamp, camera-to-world pose)`).
pub fn ate(gt: &[(f64, Se3)], est: &[(f64, Se3)], params: &AteParams) -> Result<AteResult> {
    if !(params.scale.is_finite() && params.scale > 0.0) {
        return Err(EvalError::InvalidParameter {
            name: "scale",
            reason: format!("must be positive and finite, got {}", params.scale),
        });
    }
    let gt_t: Vec<f64> = gt.iter().map(|p| p.0).collect();
    let est_t: Vec<f64> = est.iter().map(|p| p.0).collect();
    let matches = associate(&gt_t, &est_t, &params.assoc);
    let needed = params.min_pairs.max(3);
    if matches.len() < needed {
        return Err(EvalError::TooFewPairs {
            pairs: matches.len(),
            needed,
            max_diff: params.assoc.max_diff,
        });
    }
    let mut src = Vec::with_capacity(matches.len());
    let mut dst = Vec::with_capacity(matches.len());
    for &(i, j) in &matches {
        let g = gt[i].1.translation.vector;
        let e = est[j].1.translation.vector * params.scale;
        dst.push(Point3::from(g));
        src.push(Point3::from(e));
    }
    let alignment = if params.sim3 {
        align_sim3(&src, &dst)?
    } else {
        align_se3(&src, &dst)?
    };
    let mut pairs = Vec::with_capacity(matches.len());
    let mut errors = Vec::with_capacity(matches.len());
    for (k, &(i, j)) in matches.iter().enumerate() {
        let a = alignment.apply(&src[k]);
        let err = (a - dst[k]).norm();
        errors.push(err);
        pairs.push(AtePair {
            t_gt: gt[i].0,
            t_est: est[j].0,
            gt: [dst[k].x, dst[k].y, dst[k].z],
            est_aligned: [a.x, a.y, a.z],
            error: err,
        });
    }
    let stats = ErrorStats::from_values(&errors).ok_or(EvalError::TooFewPairs {
        pairs: 0,
        needed,
        max_diff: params.assoc.max_diff,
    })?;
    let motionless_floor = motionless_floor(&dst).unwrap_or(0.0);
    Ok(AteResult {
        stats,
        alignment,
        pairs,
        motionless_floor,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynapix_geometry::se3;
    use nalgebra::Vector6;

    /// A wavy ground-truth path at 100 Hz.
    fn gt_path(n: usize) -> Vec<(f64, Se3)> {
        (0..n)
            .map(|k| {
                let t = k as f64 * 0.01;
                let xi = Vector6::new(0.1 * t.sin(), 0.2 * t, 0.0, t.cos(), 0.5 * t, 0.1 * t * t);
                (1000.0 + t, se3::exp(&xi))
            })
            .collect()
    }

    #[test]
    fn rigidly_moved_copy_has_zero_error() {
        let gt = gt_path(500);
        let world = se3::exp(&Vector6::new(0.3, -0.4, 1.0, 5.0, -2.0, 1.0));
        // Estimate at 30 Hz-ish stamps, shifted by 3 ms, expressed in another world frame.
        let est: Vec<_> = gt
            .iter()
            .step_by(3)
            .map(|(t, p)| (t + 0.003, world * p))
            .collect();
        let r = ate(&gt, &est, &AteParams::default()).expect("ate");
        assert_eq!(r.stats.count, est.len());
        assert!(r.stats.rmse < 1e-9, "{}", r.stats.rmse);
    }

    #[test]
    fn known_offset_error_and_sim3_scale() {
        let gt = gt_path(300);
        // Scaled copy: SE3 alignment leaves an error, Sim3 removes it and finds the scale.
        let est: Vec<_> = gt
            .iter()
            .map(|(t, p)| {
                let mut q = *p;
                q.translation.vector *= 0.5;
                (*t, q)
            })
            .collect();
        let rigid = ate(&gt, &est, &AteParams::default()).expect("ate");
        assert!(rigid.stats.rmse > 0.01);
        let p = AteParams {
            sim3: true,
            ..AteParams::default()
        };
        let sim = ate(&gt, &est, &p).expect("ate");
        assert!(sim.stats.rmse < 1e-9);
        assert!((sim.alignment.scale() - 2.0).abs() < 1e-9);
    }

    #[test]
    fn motionless_floor_by_hand() {
        // Square of side 2 around (1, 1, 0): every corner is √2 from the centroid.
        let sq = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(2.0, 0.0, 0.0),
            Point3::new(0.0, 2.0, 0.0),
            Point3::new(2.0, 2.0, 0.0),
        ];
        assert!((motionless_floor(&sq).unwrap() - 2f64.sqrt()).abs() < 1e-15);
        // 0, 1, 5 on a line: centroid 2, squared distances 4, 1, 9 → √(14/3).
        let line = [
            Point3::new(0.0, 0.0, 3.0),
            Point3::new(1.0, 0.0, 3.0),
            Point3::new(5.0, 0.0, 3.0),
        ];
        assert!((motionless_floor(&line).unwrap() - (14.0f64 / 3.0).sqrt()).abs() < 1e-15);
        assert_eq!(motionless_floor(&[Point3::new(4.0, 5.0, 6.0)]), Some(0.0));
        assert_eq!(motionless_floor(&[]), None);
    }

    #[test]
    fn a_constant_estimate_scores_exactly_the_floor() {
        let gt = gt_path(300);
        let still = se3::exp(&Vector6::new(0.2, 0.1, -0.3, 4.0, 1.0, -2.0));
        let est: Vec<_> = gt.iter().step_by(2).map(|(t, _)| (*t, still)).collect();
        let r = ate(&gt, &est, &AteParams::default()).expect("ate");
        assert!(r.motionless_floor > 0.1);
        assert!((r.stats.rmse - r.motionless_floor).abs() < 1e-9);
        // A perfect estimate is far below it, on the same pairs.
        let good: Vec<_> = gt.iter().step_by(2).copied().collect();
        let g = ate(&gt, &good, &AteParams::default()).expect("ate");
        assert!((g.motionless_floor - r.motionless_floor).abs() < 1e-12);
        // Sim3 cannot spread a single point: the floor is the same number.
        let p = AteParams {
            sim3: true,
            ..AteParams::default()
        };
        let s = ate(&gt, &good, &p).expect("ate");
        assert!((s.motionless_floor - r.motionless_floor).abs() < 1e-12);
    }

    #[test]
    fn no_overlap_is_an_error() {
        let gt = gt_path(100);
        let est: Vec<_> = gt.iter().map(|(t, p)| (t + 100.0, *p)).collect();
        assert!(matches!(
            ate(&gt, &est, &AteParams::default()),
            Err(EvalError::TooFewPairs { pairs: 0, .. })
        ));
    }
}
