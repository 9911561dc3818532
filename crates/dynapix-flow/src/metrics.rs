//! Flow accuracy statistics against a ground truth: average end-point error (EPE) and the
//! share of pixels whose end-point error exceeds 1 px and 3 px (the usual benchmark figures).

use crate::{FlowError, FlowField};

/// Error statistics of an estimated flow.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FlowErrorStats {
    /// Mean end-point error in pixels.
    pub epe: f64,
    /// Share (0..1) of pixels with an end-point error above 1 px.
    pub over_1px: f64,
    /// Share (0..1) of pixels with an end-point error above 3 px.
    pub over_3px: f64,
    /// Number of evaluated pixels.
    pub count: usize,
}

/// Compares `est` with `gt` on the pixels where `valid` is true (`None`: all pixels).
/// Pixels with a non-finite ground truth are skipped.
pub fn flow_error(
    est: &FlowField,
    gt: &FlowField,
    valid: Option<&[bool]>,
) -> Result<FlowErrorStats, FlowError> {
    if (est.width, est.height) != (gt.width, gt.height) || est.data.len() != gt.data.len() {
        return Err(FlowError::SizeMismatch {
            a: (est.width, est.height),
            b: (gt.width, gt.height),
        });
    }
    if let Some(m) = valid.filter(|m| m.len() != gt.data.len()) {
        return Err(FlowError::Other(format!(
            "mask has {} entries, flow has {}",
            m.len(),
            gt.data.len()
        )));
    }
    let (mut sum, mut n1, mut n3, mut count) = (0.0f64, 0usize, 0usize, 0usize);
    for (i, (e, g)) in est.data.iter().zip(&gt.data).enumerate() {
        if valid.is_some_and(|m| !m[i]) || !g[0].is_finite() || !g[1].is_finite() {
            continue;
        }
        let du = f64::from(e[0]) - f64::from(g[0]);
        let dv = f64::from(e[1]) - f64::from(g[1]);
        // A non-finite estimate counts as an infinite error.
        let d = (du * du + dv * dv).sqrt();
        let d = if d.is_finite() { d } else { f64::INFINITY };
        sum += d;
        n1 += usize::from(d > 1.0);
        n3 += usize::from(d > 3.0);
        count += 1;
    }
    let c = count.max(1) as f64;
    Ok(FlowErrorStats {
        epe: sum / c,
        over_1px: n1 as f64 / c,
        over_3px: n3 as f64 / c,
        count,
    })
}

/// Mask of the pixels at least `border` pixels from the image edge whose ground-truth target
/// `x + f(x)` lies inside the image (so the match is visible in B).
pub fn visible_mask(gt: &FlowField, border: u32) -> Vec<bool> {
    let (w, h) = (gt.width as f32, gt.height as f32);
    let b = border as f32;
    gt.data
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let x = (i % gt.width as usize) as f32;
            let y = (i / gt.width as usize) as f32;
            let (tx, ty) = (x + f[0], y + f[1]);
            x >= b
                && y >= b
                && x < w - b
                && y < h - b
                && tx >= 0.0
                && ty >= 0.0
                && tx <= w - 1.0
                && ty <= h - 1.0
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_errors() {
        let gt = FlowField::zeros(2, 2);
        let mut est = FlowField::zeros(2, 2);
        est.data[1] = [2.0, 0.0];
        est.data[2] = [3.0, 4.0];
        let s = flow_error(&est, &gt, None).unwrap();
        assert!((s.epe - 7.0 / 4.0).abs() < 1e-12);
        assert_eq!((s.over_1px, s.over_3px, s.count), (0.5, 0.25, 4));
        let s = flow_error(&est, &gt, Some(&[true, true, false, true])).unwrap();
        assert_eq!(s.count, 3);
        assert!(flow_error(&est, &FlowField::zeros(1, 2), None).is_err());
    }

    #[test]
    fn visible_mask_excludes_border_and_targets_outside() {
        let gt = FlowField::constant(5, 5, [2.5, 0.0]);
        let m = visible_mask(&gt, 1);
        assert!(m[5 + 1]);
        assert!(!m[5 + 3]); // 3 + 2.5 > 4
        assert!(!m[0]);
    }
}
