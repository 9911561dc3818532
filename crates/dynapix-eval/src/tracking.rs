//! Tracking rate (spec §4.3, paper "TR"): the share of the sequence duration during which
//! the system had a pose. Against a list of reference frame stamps (the first column of
//! `rgb.txt` or of the association file), an interval between consecutive reference frames
//! counts as missing when either end frame has no pose in the trajectory; TR = 1 − missing
//! time / (t_last − t_first).
//!
//! Differences to the reference `eval.py`, both deliberate: a reference frame is "tracked"
//! when some trajectory stamp lies within `match_tol` (1 ms) instead of exact float equality
//! (so a reformatted trajectory still counts), and the reference list is first restricted to
//! the evaluation window, so the boundary intervals to frames outside the window never count.

use crate::error::{EvalError, Result};
use serde::Serialize;

/// Tracking-rate parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackingParams {
    /// A reference frame is tracked if a trajectory stamp is within this many seconds.
    pub match_tol: f64,
    /// Evaluation window `[start, end]` (inclusive); usually the ground-truth time span.
    pub window: Option<(f64, f64)>,
}

impl Default for TrackingParams {
    fn default() -> Self {
        Self {
            match_tol: 1e-3,
            window: None,
        }
    }
}

/// Result of a tracking-rate evaluation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TrackingResult {
    /// Tracking rate in [0, 1].
    pub tracking_rate: f64,
    /// Total missing time, seconds.
    pub missing_time_s: f64,
    /// Duration t_last − t_first of the reference frames inside the window, seconds.
    pub duration_s: f64,
    /// Reference frames inside the window.
    pub frames: usize,
    /// Reference frames without a pose.
    pub missing_frames: usize,
}

/// Computes the tracking rate of a trajectory with stamps `est` over reference stamps
/// `reference` (file order, expected increasing).
pub fn tracking_rate(
    reference: &[f64],
    est: &[f64],
    params: &TrackingParams,
) -> Result<TrackingResult> {
    if !(params.match_tol.is_finite() && params.match_tol >= 0.0) {
        return Err(EvalError::InvalidParameter {
            name: "match_tol",
            reason: format!("must be non-negative, got {}", params.match_tol),
        });
    }
    let refs: Vec<f64> = reference
        .iter()
        .copied()
        .filter(|t| match params.window {
            Some((s, e)) => *t >= s && *t <= e,
            None => t.is_finite(),
        })
        .collect();
    if refs.len() < 2 {
        return Err(EvalError::TooFewReferenceFrames { got: refs.len() });
    }
    let mut sorted_est: Vec<f64> = est.iter().copied().filter(|t| t.is_finite()).collect();
    sorted_est.sort_by(f64::total_cmp);
    let tracked = |t: f64| {
        let i = sorted_est.partition_point(|&e| e < t - params.match_tol);
        sorted_est
            .get(i)
            .is_some_and(|&e| (e - t).abs() <= params.match_tol)
    };
    let m = refs.len();
    let mut missing_interval = vec![false; m - 1];
    let mut missing_frames = 0;
    for (k, &t) in refs.iter().enumerate() {
        if tracked(t) {
            continue;
        }
        missing_frames += 1;
        if k > 0 {
            missing_interval[k - 1] = true;
        }
        if k < m - 1 {
            missing_interval[k] = true;
        }
    }
    let missing: f64 = refs
        .windows(2)
        .zip(&missing_interval)
        .filter(|(_, m)| **m)
        .map(|(w, _)| w[1] - w[0])
        .sum();
    let duration = refs[m - 1] - refs[0];
    if duration <= 0.0 {
        return Err(EvalError::InvalidParameter {
            name: "reference",
            reason: format!("reference stamps span {duration} s; they must increase"),
        });
    }
    Ok(TrackingResult {
        tracking_rate: 1.0 - missing / duration,
        missing_time_s: missing,
        duration_s: duration,
        frames: m,
        missing_frames,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interval_rule_at_start_middle_and_end() {
        let r = [0.0, 1.0, 3.0, 6.0, 10.0];
        let p = TrackingParams::default();
        // All tracked.
        let t = tracking_rate(&r, &r, &p).expect("tr");
        assert_eq!((t.missing_time_s, t.tracking_rate), (0.0, 1.0));
        // First frame missing: only the first interval [0,1].
        let t = tracking_rate(&r, &r[1..], &p).expect("tr");
        assert_eq!(t.missing_time_s, 1.0);
        // Middle frame (t = 3) missing: both neighbouring intervals, 2 + 3.
        let t = tracking_rate(&r, &[0.0, 1.0, 6.0, 10.0], &p).expect("tr");
        assert_eq!(t.missing_time_s, 5.0);
        assert_eq!(t.tracking_rate, 0.5);
        // Last frame missing: only the last interval.
        let t = tracking_rate(&r, &r[..4], &p).expect("tr");
        assert_eq!(t.missing_time_s, 4.0);
        assert_eq!(t.missing_frames, 1);
    }

    #[test]
    fn stamps_within_one_millisecond_match() {
        let r = [100.0, 100.5, 101.0];
        let est = [100.0004, 100.4996, 101.0011];
        let t = tracking_rate(&r, &est, &TrackingParams::default()).expect("tr");
        assert_eq!(t.missing_frames, 1);
        assert_eq!(t.missing_time_s, 0.5);
    }

    #[test]
    fn window_restricts_reference() {
        let r = [0.0, 1.0, 2.0, 3.0, 4.0];
        let p = TrackingParams {
            window: Some((1.0, 3.0)),
            ..TrackingParams::default()
        };
        let t = tracking_rate(&r, &[1.0, 2.0, 3.0], &p).expect("tr");
        assert_eq!((t.frames, t.missing_time_s, t.duration_s), (3, 0.0, 2.0));
        assert!(matches!(
            tracking_rate(&[1.0], &[1.0], &p),
            Err(EvalError::TooFewReferenceFrames { got: 1 })
        ));
    }
}
