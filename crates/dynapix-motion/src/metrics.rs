//! Quality measures of probability maps against ground-truth masks: ROC-AUC (over scores
//! binned at the 1/1000 resolution of the probability files), IoU of the map thresholded at a
//! level, and PSNR of a reconstructed background inside a mask; [`MaskEvaluation`] gathers
//! them over a sequence (what `dynapix motion --eval-masks` reports).

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

/// Mask value of a moving object (the `mask/` convention: 0 static, other values movable
/// objects, 255 the moving ones).
pub const MOVING: u8 = 255;

/// Squared-error sums of the reconstructed background and of the frame itself against the
/// true background, and their pixel counts, inside one selection of mask pixels.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct PsnrSums {
    background: f64,
    frame: f64,
    pixels: f64,
}

impl PsnrSums {
    fn add(&mut self, o: &Self) {
        self.background += o.background;
        self.frame += o.frame;
        self.pixels += o.pixels;
    }

    /// PSNR of the background and of the frame, dB (`None` without pixels).
    fn psnr(&self) -> (Option<f64>, Option<f64>) {
        let db = |se: f64| {
            (self.pixels > 0.0).then(|| 10.0 * (255.0f64.powi(2) / (se / self.pixels)).log10())
        };
        (db(self.background), db(self.frame))
    }
}

/// The quality of a sequence's motion maps against its masks, gathered frame by frame (in
/// any order; [`MaskEvaluation::merge`] joins the parts): ROC-AUC and IoU of `P > 0.5` with
/// the moving pixels (mask 255) as positives, and, where a background was reconstructed and
/// the true one is known, the PSNR of the reconstruction (and of the frame itself) inside
/// all movers (mask > 0) and inside the moving ones.
#[derive(Clone, Debug)]
pub struct MaskEvaluation {
    roc: RocAccumulator,
    movers: PsnrSums,
    moving: PsnrSums,
}

impl Default for MaskEvaluation {
    fn default() -> Self {
        Self::new()
    }
}

impl MaskEvaluation {
    /// Nothing measured yet.
    pub fn new() -> Self {
        Self {
            roc: RocAccumulator::new(0.5),
            movers: PsnrSums::default(),
            moving: PsnrSums::default(),
        }
    }

    /// Adds one frame's map `p` (probability of motion per pixel) against its `mask` (same
    /// length).
    pub fn add_map(&mut self, p: &[f32], mask: &[u8]) {
        let pos: Vec<bool> = mask.iter().map(|&v| v == MOVING).collect();
        self.roc.add(p, &pos);
    }

    /// Adds one frame's reconstructed `background` and the `frame` itself against the
    /// `truth` background, inside the movers of `mask` (row-major, one value per pixel).
    pub fn add_background(
        &mut self,
        mask: &[u8],
        background: &RgbImage,
        frame: &RgbImage,
        truth: &RgbImage,
    ) {
        for (sums, least) in [(&mut self.movers, 1u8), (&mut self.moving, MOVING)] {
            let sel: Vec<bool> = mask.iter().map(|&v| v >= least).collect();
            let k = sel.iter().filter(|&&v| v).count() as f64;
            if k == 0.0 {
                continue;
            }
            // The mean squared error through the PSNR, as the figures were always computed.
            let mse = |a: &RgbImage| {
                psnr_masked(a, truth, &sel)
                    .map(|p| 255.0f64.powi(2) / 10f64.powf(p / 10.0))
                    .unwrap_or(0.0)
            };
            sums.add(&PsnrSums {
                background: mse(background) * k,
                frame: mse(frame) * k,
                pixels: k,
            });
        }
    }

    /// Adds what another part of the sequence measured.
    pub fn merge(&mut self, other: &Self) {
        self.roc.merge(&other.roc);
        self.movers.add(&other.movers);
        self.moving.add(&other.moving);
    }

    /// The scores so far.
    pub fn scores(&self) -> MaskScores {
        let best = self.roc.best_iou();
        let (background_psnr_in_movers_db, frame_psnr_in_movers_db) = self.movers.psnr();
        let (background_psnr_in_moving_db, frame_psnr_in_moving_db) = self.moving.psnr();
        MaskScores {
            roc_auc: self.roc.auc(),
            iou_p_gt_0_5: self.roc.iou(),
            best_iou: best.map(|b| b.1),
            best_iou_threshold: best.map(|b| b.0),
            moving_pixels: self.roc.positives(),
            other_pixels: self.roc.negatives(),
            background_psnr_in_movers_db,
            frame_psnr_in_movers_db,
            background_psnr_in_moving_db,
            frame_psnr_in_moving_db,
        }
    }
}

/// What [`MaskEvaluation`] measured (the `eval` record of `motion.json`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MaskScores {
    /// ROC-AUC of P with the moving pixels as positives.
    pub roc_auc: Option<f64>,
    /// IoU of `P > 0.5` with the moving pixels.
    pub iou_p_gt_0_5: Option<f64>,
    /// The best IoU over the thresholds.
    pub best_iou: Option<f64>,
    /// The threshold of [`Self::best_iou`].
    pub best_iou_threshold: Option<f32>,
    /// Moving pixels (mask 255).
    pub moving_pixels: u64,
    /// The other pixels.
    pub other_pixels: u64,
    /// PSNR of the reconstructed background inside all movers (mask > 0), dB.
    pub background_psnr_in_movers_db: Option<f64>,
    /// PSNR of the frame itself inside all movers, dB.
    pub frame_psnr_in_movers_db: Option<f64>,
    /// PSNR of the reconstructed background inside the moving movers (mask 255), dB.
    pub background_psnr_in_moving_db: Option<f64>,
    /// PSNR of the frame itself inside the moving movers, dB.
    pub frame_psnr_in_moving_db: Option<f64>,
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

    /// A generated 8×4 sequence: a mover in columns 4..8 (moving in rows 0..2, a parked
    /// object with mask 7 below), maps that see the moving part.
    #[test]
    fn mask_evaluation_of_generated_frames() {
        let (w, h) = (8u32, 4u32);
        let mask: Vec<u8> = (0..w * h)
            .map(|i| match (i % w >= 4, i / w < 2) {
                (true, true) => MOVING,
                (true, false) => 7,
                _ => 0,
            })
            .collect();
        // Frame 1: perfect; frame 2: P = 0.4 on the moving pixels (missed at 0.5).
        let perfect: Vec<f32> = mask
            .iter()
            .map(|&m| if m == MOVING { 0.9 } else { 0.1 })
            .collect();
        let weak: Vec<f32> = mask
            .iter()
            .map(|&m| if m == MOVING { 0.4 } else { 0.1 })
            .collect();
        let mut a = MaskEvaluation::new();
        a.add_map(&perfect, &mask);
        let mut b = MaskEvaluation::new();
        b.add_map(&weak, &mask);
        a.merge(&b);
        let s = a.scores();
        assert_eq!((s.moving_pixels, s.other_pixels), (16, 48));
        // Every moving score is above every other one: AUC 1; at P > 0.5 half are found.
        assert_eq!(s.roc_auc, Some(1.0));
        assert_eq!(s.iou_p_gt_0_5, Some(0.5));
        assert_eq!(s.best_iou, Some(1.0));
        assert!(
            s.best_iou_threshold
                .is_some_and(|t| (0.1..0.4).contains(&t))
        );
        assert!(
            s.background_psnr_in_movers_db.is_none(),
            "no background added"
        );
        // Backgrounds: the truth is grey 100; the reconstruction is off by 10 on every mover,
        // the frame (the mover itself) by 100 on the moving part and agrees on the parked one.
        let truth = RgbImage::from_pixel(w, h, image::Rgb([100, 100, 100]));
        let rec = RgbImage::from_pixel(w, h, image::Rgb([110, 110, 110]));
        let frame = RgbImage::from_fn(w, h, |x, y| {
            let v = if x >= 4 && y < 2 { 200 } else { 100 };
            image::Rgb([v, v, v])
        });
        let mut c = MaskEvaluation::new();
        c.add_background(&mask, &rec, &frame, &truth);
        let s = c.scores();
        let db = |mse: f64| 10.0 * (255.0f64 * 255.0 / mse).log10();
        let close = |a: Option<f64>, b: f64| a.is_some_and(|a| (a - b).abs() < 1e-9);
        assert!(close(s.background_psnr_in_movers_db, db(100.0)), "{s:?}");
        assert!(close(s.background_psnr_in_moving_db, db(100.0)), "{s:?}");
        // All movers: half the pixels off by 100 → MSE 5000; moving ones only → 10000.
        assert!(close(s.frame_psnr_in_movers_db, db(5000.0)), "{s:?}");
        assert!(close(s.frame_psnr_in_moving_db, db(10000.0)), "{s:?}");
        // A frame without movers adds nothing; an empty evaluation has no scores.
        let none = vec![0u8; (w * h) as usize];
        c.add_background(&none, &rec, &frame, &truth);
        assert_eq!(c.scores(), s);
        let e = MaskEvaluation::new().scores();
        assert!(e.roc_auc.is_none() && e.iou_p_gt_0_5.is_none() && e.moving_pixels == 0);
    }
}
