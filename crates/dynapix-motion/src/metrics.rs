//! Quality measures of probability maps against ground-truth masks: ROC-AUC (over scores
//! binned at the 1/1000 resolution of the probability files), IoU of the map thresholded at a
//! level, and PSNR of a reconstructed background inside a mask.

use image::RgbImage;
use serde::{Deserialize, Serialize};

/// Number of score bins (P quantised to 1/1000, like the 16-bit files).
const BINS: usize = 1001;

/// Accumulates scores of positive and negative pixels over many frames.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RocAccumulator {
    pos: Vec<u64>,
    neg: Vec<u64>,
    threshold: f32,
    tp: u64,
    fp: u64,
    fn_: u64,
}

impl RocAccumulator {
    /// An empty accumulator; IoU is measured for `P > threshold`.
    pub fn new(threshold: f32) -> Self {
        Self {
            pos: vec![0; BINS],
            neg: vec![0; BINS],
            threshold,
            tp: 0,
            fp: 0,
            fn_: 0,
        }
    }

    /// Adds one frame: scores `p` and ground truth `positive` (same length).
    pub fn add(&mut self, p: &[f32], positive: &[bool]) {
        for (&s, &gt) in p.iter().zip(positive) {
            let bin = ((s.clamp(0.0, 1.0) * 1000.0).round() as usize).min(BINS - 1);
            let above = s > self.threshold;
            if gt {
                self.pos[bin] += 1;
                if above {
                    self.tp += 1;
                } else {
                    self.fn_ += 1;
                }
            } else {
                self.neg[bin] += 1;
                if above {
                    self.fp += 1;
                }
            }
        }
    }

    /// Adds the counts of another accumulator (same threshold assumed).
    pub fn merge(&mut self, other: &Self) {
        for (a, b) in self.pos.iter_mut().zip(&other.pos) {
            *a += b;
        }
        for (a, b) in self.neg.iter_mut().zip(&other.neg) {
            *a += b;
        }
        self.tp += other.tp;
        self.fp += other.fp;
        self.fn_ += other.fn_;
    }

    /// Number of positive pixels seen.
    pub fn positives(&self) -> u64 {
        self.pos.iter().sum()
    }

    /// Number of negative pixels seen.
    pub fn negatives(&self) -> u64 {
        self.neg.iter().sum()
    }

    /// Area under the ROC curve: probability that a positive scores above a negative, ties
    /// counting one half. `None` without positives or negatives.
    pub fn auc(&self) -> Option<f64> {
        let (np, nn) = (self.positives(), self.negatives());
        if np == 0 || nn == 0 {
            return None;
        }
        let mut below = 0u64;
        let mut acc = 0.0f64;
        for (p, n) in self.pos.iter().zip(&self.neg) {
            acc += *p as f64 * (below as f64 + 0.5 * *n as f64);
            below += n;
        }
        Some(acc / (np as f64 * nn as f64))
    }

    /// The best IoU over thresholds on the 1/1000 grid (`P > k/1000`), with its threshold:
    /// how good the map is once its scale is calibrated. `None` without positives.
    pub fn best_iou(&self) -> Option<(f32, f64)> {
        let np = self.positives();
        if np == 0 {
            return None;
        }
        // Counts strictly above bin k: suffix sums.
        let (mut pos_above, mut neg_above) = (0u64, 0u64);
        let mut best: Option<(f32, f64)> = None;
        for k in (0..BINS).rev() {
            let iou = pos_above as f64 / (np + neg_above) as f64;
            if best.is_none_or(|(_, b)| iou > b) {
                best = Some((k as f32 / 1000.0, iou));
            }
            pos_above += self.pos[k];
            neg_above += self.neg[k];
        }
        best
    }

    /// Intersection over union of `P > threshold` with the positives. `None` when both are
    /// empty.
    pub fn iou(&self) -> Option<f64> {
        let den = self.tp + self.fp + self.fn_;
        (den > 0).then(|| self.tp as f64 / den as f64)
    }
}

/// PSNR (dB, peak 255) between two colour images over the pixels where `mask` is true.
/// `None` when the mask is empty; infinite when the images agree there.
pub fn psnr_masked(a: &RgbImage, b: &RgbImage, mask: &[bool]) -> Option<f64> {
    let mut se = 0.0f64;
    let mut n = 0u64;
    for ((pa, pb), &m) in a.pixels().zip(b.pixels()).zip(mask) {
        if m {
            for c in 0..3 {
                let d = pa.0[c] as f64 - pb.0[c] as f64;
                se += d * d;
            }
            n += 3;
        }
    }
    if n == 0 {
        return None;
    }
    let mse = se / n as f64;
    Some(if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auc_and_iou_on_known_cases() {
        let mut r = RocAccumulator::new(0.5);
        // Perfect separation.
        r.add(&[0.9, 0.8, 0.1, 0.2], &[true, true, false, false]);
        assert_eq!(r.auc(), Some(1.0));
        assert_eq!(r.iou(), Some(1.0));
        // One positive below one negative: 3 of 4 ordered pairs in the new frame.
        let mut s = RocAccumulator::new(0.5);
        s.add(&[0.9, 0.3, 0.4, 0.2], &[true, true, false, false]);
        assert_eq!(s.auc(), Some(0.75));
        // P > 0.5: tp 1, fn 1, fp 0.
        assert_eq!(s.iou(), Some(0.5));
        // Ties count one half; constant scores give 0.5.
        let mut t = RocAccumulator::new(0.5);
        t.add(&[0.3; 4], &[true, false, true, false]);
        assert_eq!(t.auc(), Some(0.5));
        // Best threshold on the second frame: P > 0.2 keeps 0.9, 0.3 and the 0.4 negative
        // (2/3); P > 0.4 keeps only 0.9 (1/2).
        let (th, best) = s.best_iou().unwrap();
        assert!(
            (best - 2.0 / 3.0).abs() < 1e-12 && (0.2..0.3).contains(&th),
            "{th} {best}"
        );
        r.merge(&s);
        assert_eq!(r.positives(), 4);
        assert!(RocAccumulator::new(0.5).auc().is_none());
    }

    #[test]
    fn psnr_inside_mask() {
        let a = RgbImage::from_pixel(2, 1, image::Rgb([10, 10, 10]));
        let mut b = a.clone();
        b.put_pixel(1, 0, image::Rgb([20, 20, 20]));
        assert_eq!(psnr_masked(&a, &b, &[true, false]), Some(f64::INFINITY));
        let p = psnr_masked(&a, &b, &[false, true]).unwrap();
        assert!((p - 20.0 * (255.0f64 / 10.0).log10()).abs() < 1e-9);
        assert!(psnr_masked(&a, &b, &[false, false]).is_none());
    }
}
