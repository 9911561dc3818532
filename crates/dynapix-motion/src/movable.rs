//! Movable term D (paper §3.1 "Movable Region Estimation", Eq. 2-3; reference `get_movable`,
//! spec §1.3): where does the frame differ from its static background, blended from a fixed
//! clip of the per-pixel channel maximum (f1) and a robust min-max normalisation of the
//! channel mean (f2), weighted by λ = 0.5 + 1/(exp(0.04·hi) + 1).
//!
//! The robust extremes are the reference's: hi = mean of the largest 5 %, lo = mean of the
//! smallest 10 % after excluding near-zero differences. The reference has a defect when most
//! differences are excluded (lo ≥ hi makes the denominator negative and f2 ≈ 1); `Mode::Paper`
//! guards it (hi − lo < ε ⇒ f2 = 0, spec §7.6).

use image::RgbImage;
use serde::{Deserialize, Serialize};

use crate::{FloatImage, Mode, MotionError, Variant, check_size};

/// Which values the robust minimum ignores (they are replaced by a large substitute first).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MinExclusion {
    /// Ignore values ≤ the threshold (reference TUM script: ≤ 5).
    AtMost(f32),
    /// Ignore exact zeros (reference GRADE script).
    Zero,
}

/// Parameters of the movable term. `Default` = reference TUM constants, paper mode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct MovableParams {
    /// Lower bound of the f1 clip on the channel-max difference (grey levels).
    pub clip_lo: f32,
    /// Upper bound of the f1 clip on the channel-max difference (grey levels).
    pub clip_hi: f32,
    /// Pixels at or beyond this depth (metres) get f1 = f2 = 0.
    pub max_depth: f32,
    /// Fraction of pixels whose mean forms the robust maximum `hi`.
    pub robust_max_fraction: f64,
    /// Fraction of pixels whose mean forms the robust minimum `lo`.
    pub robust_min_fraction: f64,
    /// Which values the robust minimum ignores.
    pub min_exclusion: MinExclusion,
    /// Value that replaces ignored values before the robust minimum is taken.
    pub exclusion_substitute: f32,
    /// Slope of λ in `0.5 + 1/(exp(slope·hi) + 1)`.
    pub lambda_slope: f32,
    /// Added to the f2 denominator (reference 1e−6).
    pub denominator_eps: f32,
    /// Paper mode: if `hi − lo` is below this, f2 = 0 (the reference's robust-min defect).
    /// `None` reproduces the reference.
    pub range_guard: Option<f32>,
}

impl Default for MovableParams {
    fn default() -> Self {
        Self::new(Variant::Tum, Mode::Paper)
    }
}

impl MovableParams {
    /// Reference constants of `variant`, with the robust-min guard on in `Mode::Paper`.
    pub fn new(variant: Variant, mode: Mode) -> Self {
        Self {
            clip_lo: 15.0,
            clip_hi: 35.0,
            max_depth: 10.0,
            robust_max_fraction: 0.05,
            robust_min_fraction: 0.10,
            min_exclusion: match variant {
                Variant::Tum => MinExclusion::AtMost(5.0),
                Variant::Grade => MinExclusion::Zero,
            },
            exclusion_substitute: 100.0,
            lambda_slope: 0.04,
            denominator_eps: 1e-6,
            range_guard: match mode {
                Mode::Paper => Some(1.0),
                Mode::Reference => None,
            },
        }
    }
}

/// The movable term with the statistics that produced it.
#[derive(Clone, Debug)]
pub struct Movable {
    /// D ∈ [0, 1] per pixel.
    pub d: FloatImage,
    /// Robust maximum of the channel-mean difference.
    pub hi: f32,
    /// Robust minimum of the channel-mean difference (after exclusion).
    pub lo: f32,
    /// Blend factor λ between f1 and f2.
    pub lambda: f32,
    /// True when the paper-mode guard set f2 = 0.
    pub guarded: bool,
}

/// Mean of the `k` largest values (`k` ≥ 1, clamped to the length); reorders `values`.
fn mean_of_largest(values: &mut [f32], k: usize) -> f32 {
    let n = values.len();
    let k = k.clamp(1, n.max(1));
    if n == 0 {
        return 0.0;
    }
    let (_, _, upper) = values.select_nth_unstable_by(n - k, f32::total_cmp);
    // `upper` holds the k−1 values above the pivot; the pivot itself is at n−k.
    let sum: f64 = upper.iter().map(|&v| v as f64).sum::<f64>() + values[n - k] as f64;
    (sum / k as f64) as f32
}

/// Mean of the `k` smallest values (`k` ≥ 1, clamped to the length); reorders `values`.
fn mean_of_smallest(values: &mut [f32], k: usize) -> f32 {
    let n = values.len();
    let k = k.clamp(1, n.max(1));
    if n == 0 {
        return 0.0;
    }
    let (lower, pivot, _) = values.select_nth_unstable_by(k - 1, f32::total_cmp);
    let sum: f64 = lower.iter().map(|&v| v as f64).sum::<f64>() + *pivot as f64;
    (sum / k as f64) as f32
}

/// Computes the movable term D of `image` against its static `background`; `depth` is the
/// current frame's depth in metres (only used to cut pixels beyond `max_depth`).
pub fn movable(
    image: &RgbImage,
    background: &RgbImage,
    depth: &FloatImage,
    params: &MovableParams,
) -> Result<Movable, MotionError> {
    let size = image.dimensions();
    check_size("background image", size, background.dimensions())?;
    check_size("depth image", size, depth.dimensions())?;
    if params.clip_hi.partial_cmp(&params.clip_lo) != Some(std::cmp::Ordering::Greater) {
        return Err(MotionError::InvalidParam {
            name: "clip_hi",
            message: format!(
                "must exceed clip_lo ({} ≤ {})",
                params.clip_hi, params.clip_lo
            ),
        });
    }
    let n = size.0 as usize * size.1 as usize;
    let mut dmax = Vec::with_capacity(n);
    let mut dmean = Vec::with_capacity(n);
    for (a, b) in image.pixels().zip(background.pixels()) {
        let d = [
            a.0[0].abs_diff(b.0[0]),
            a.0[1].abs_diff(b.0[1]),
            a.0[2].abs_diff(b.0[2]),
        ];
        dmax.push(d[0].max(d[1]).max(d[2]) as f32);
        dmean.push((d[0] as f32 + d[1] as f32 + d[2] as f32) / 3.0);
    }

    let k_hi = (params.robust_max_fraction * n as f64) as usize;
    let k_lo = (params.robust_min_fraction * n as f64) as usize;
    let mut tmp = dmean.clone();
    let hi = mean_of_largest(&mut tmp, k_hi);
    for v in tmp.iter_mut() {
        let excluded = match params.min_exclusion {
            MinExclusion::AtMost(t) => *v <= t,
            MinExclusion::Zero => *v == 0.0,
        };
        if excluded {
            *v = params.exclusion_substitute;
        }
    }
    let lo = mean_of_smallest(&mut tmp, k_lo);
    let guarded = params.range_guard.is_some_and(|eps| hi - lo < eps);
    let lambda = 0.5 + 1.0 / ((params.lambda_slope * hi).exp() + 1.0);
    let denom = hi - lo + params.denominator_eps;
    let clip_range = params.clip_hi - params.clip_lo;

    let mut d = FloatImage::new(size.0, size.1);
    for (((out, &mx), &mn), z) in d.pixels_mut().zip(&dmax).zip(&dmean).zip(depth.pixels()) {
        if z.0[0] >= params.max_depth {
            out.0[0] = 0.0;
            continue;
        }
        let f1 = (mx.clamp(params.clip_lo, params.clip_hi) - params.clip_lo) / clip_range;
        let f2 = if guarded {
            0.0
        } else {
            ((mn - lo) / denom).clamp(0.0, 1.0)
        };
        out.0[0] = lambda * f1 + (1.0 - lambda) * f2;
    }
    Ok(Movable {
        d,
        hi,
        lo,
        lambda,
        guarded,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Rgb;

    /// 10×2 images: background grey 100, frame = background + per-pixel grey offsets.
    fn pair(offsets: &[u8; 20]) -> (RgbImage, RgbImage, FloatImage) {
        let bg = RgbImage::from_pixel(10, 2, Rgb([100, 100, 100]));
        let mut img = bg.clone();
        for (i, p) in img.pixels_mut().enumerate() {
            let v = 100 + offsets[i];
            *p = Rgb([v, v, v]);
        }
        (img, bg, FloatImage::from_pixel(10, 2, image::Luma([2.0])))
    }

    #[test]
    fn matches_hand_computed_values() {
        // 20 pixels: k_hi = int(0.05·20) = 1, k_lo = int(0.1·20) = 2.
        let mut off = [0u8; 20];
        off[..6].copy_from_slice(&[0, 3, 8, 10, 25, 60]);
        for o in off.iter_mut().skip(6) {
            *o = 12;
        }
        let (img, bg, z) = pair(&off);
        let m = movable(
            &img,
            &bg,
            &z,
            &MovableParams::new(Variant::Tum, Mode::Reference),
        )
        .unwrap();
        // hi = largest dmean = 60. TUM: values ≤ 5 (0, 3) → 100; two smallest = 8, 10 → lo = 9.
        assert_eq!(m.hi, 60.0);
        assert_eq!(m.lo, 9.0);
        // λ = 0.5 + 1/(e^{2.4} + 1) = 0.5 + 1/12.0231764 = 0.58317255
        assert!((m.lambda - 0.583_172_5).abs() < 1e-6, "{}", m.lambda);
        let den = 51.0 + 1e-6;
        let l = m.lambda;
        let expect = |f1: f32, f2: f32| l * f1 + (1.0 - l) * f2;
        // offset 0: f1 = 0, f2 = clamp(-9/51) = 0
        assert!((m.d.get_pixel(0, 0).0[0] - expect(0.0, 0.0)).abs() < 1e-6);
        // offset 10: f1 = 0 (below 15), f2 = 1/51
        assert!((m.d.get_pixel(3, 0).0[0] - expect(0.0, 1.0 / den)).abs() < 1e-6);
        // offset 25: f1 = (25-15)/20 = 0.5, f2 = 16/51
        assert!((m.d.get_pixel(4, 0).0[0] - expect(0.5, 16.0 / den)).abs() < 1e-6);
        // offset 60: f1 = 1, f2 = 51/51
        assert!((m.d.get_pixel(5, 0).0[0] - expect(1.0, 51.0 / den)).abs() < 1e-5);
        // GRADE excludes only zeros: two smallest of {3, 8, …} → lo = (3 + 8)/2 = 5.5
        let g = movable(
            &img,
            &bg,
            &z,
            &MovableParams::new(Variant::Grade, Mode::Reference),
        )
        .unwrap();
        assert_eq!(g.lo, 5.5);
    }

    #[test]
    fn uses_channel_max_for_f1_and_mean_for_f2() {
        let bg = RgbImage::from_pixel(10, 2, Rgb([100, 100, 100]));
        let mut img = bg.clone();
        img.put_pixel(0, 0, Rgb([130, 100, 100])); // max 30, mean 10
        let z = FloatImage::from_pixel(10, 2, image::Luma([1.0]));
        let m = movable(
            &img,
            &bg,
            &z,
            &MovableParams::new(Variant::Tum, Mode::Reference),
        )
        .unwrap();
        // f1 = (30 − 15)/20 = 0.75; hi = 10; all other values are zero, hence excluded (→ 100),
        // so lo = (10 + 100)/2 = 55 > hi: the reference defect, f2 = (10 − 55)/(−45) = 1.
        let l = m.lambda;
        assert!((m.d.get_pixel(0, 0).0[0] - (l * 0.75 + (1.0 - l) * 1.0)).abs() < 1e-5);
        // The defect also makes untouched pixels non-zero: (0 − 55)/(−45) > 1 → f2 = 1.
        assert!(m.d.get_pixel(5, 1).0[0] > 0.0);
        // Paper mode guards it: f2 = 0 everywhere, untouched pixels are 0.
        let p = movable(
            &img,
            &bg,
            &z,
            &MovableParams::new(Variant::Tum, Mode::Paper),
        )
        .unwrap();
        assert!(p.guarded);
        assert_eq!(p.d.get_pixel(5, 1).0[0], 0.0);
        assert!((p.d.get_pixel(0, 0).0[0] - p.lambda * 0.75).abs() < 1e-6);
    }

    #[test]
    fn far_depth_is_cut_and_sizes_checked() {
        let mut off = [40u8; 20];
        off[0] = 0;
        let (img, bg, mut z) = pair(&off);
        z.put_pixel(1, 0, image::Luma([10.0]));
        let m = movable(&img, &bg, &z, &MovableParams::default()).unwrap();
        assert_eq!(m.d.get_pixel(1, 0).0[0], 0.0);
        assert!(m.d.get_pixel(2, 0).0[0] > 0.5);
        let small = FloatImage::new(5, 2);
        assert!(matches!(
            movable(&img, &bg, &small, &MovableParams::default()),
            Err(MotionError::SizeMismatch { .. })
        ));
    }
}
