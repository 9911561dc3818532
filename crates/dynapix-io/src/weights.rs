//! The two per-pixel maps of DynaPix as distinct types, so one cannot be passed where the other
//! is expected (design §3): the motion probability P ∈ [0, 1] that the motion stage computes,
//! and the static weight w = 1 − P that the SLAM backend consumes (paper §3.2).
//!
//! Both go through one 16-bit codec, the reference format of `prob/*.png` (spec §1.8): the
//! stored value is `trunc((1 − P)·1000)` computed in `f32`, and the weight read back is
//! `stored / 1000`. [`MotionProbability::static_weights`] applies the same quantisation, so a
//! map used in memory gives the SLAM backend exactly the weights it would get from its file.

use image::{ImageBuffer, Luma};

use crate::images::{Gray16Image, PROB_PNG_SCALE, ProbMap};

/// A single-channel `f32` image holding static weights w ∈ [0, 1].
pub type WeightImage = ImageBuffer<Luma<f32>, Vec<f32>>;

/// Per-pixel motion probability P ∈ [0, 1] (0 = static, 1 = moving).
#[derive(Clone, Debug, PartialEq)]
pub struct MotionProbability(ProbMap);

/// Per-pixel static weight w = 1 − P ∈ [0, 1] (1 = static, 0 = moving).
#[derive(Clone, Debug, PartialEq)]
pub struct StaticWeights(WeightImage);

impl MotionProbability {
    /// Wraps a probability image (values are used as given; the codec clamps to [0, 1]).
    pub fn new(p: ProbMap) -> Self {
        Self(p)
    }

    /// The probability image.
    pub fn as_image(&self) -> &ProbMap {
        &self.0
    }

    /// The probability image, by value.
    pub fn into_image(self) -> ProbMap {
        self.0
    }

    /// `(width, height)`.
    pub fn dimensions(&self) -> (u32, u32) {
        self.0.dimensions()
    }

    /// The stored 16-bit form `trunc((1 − P)·1000)`, P clamped to [0, 1] (spec §1.8: P = 0.1
    /// stores 900, P = 0.1000001 stores 899).
    pub fn to_stored(&self) -> Gray16Image {
        stored_image(&self.0)
    }

    /// P = 1 − stored/1000 from the stored 16-bit form (values above 1000 clamp to P = 0).
    pub fn from_stored(stored: &Gray16Image) -> Self {
        Self(map_stored(stored, |v| {
            (1.0 - v as f32 / PROB_PNG_SCALE).max(0.0)
        }))
    }

    /// The static weights the SLAM backend gets for this map, quantised like the stored file
    /// (`w = trunc((1 − P)·1000)/1000`), so in-memory and on-disk maps weight identically.
    pub fn static_weights(&self) -> StaticWeights {
        StaticWeights(ImageBuffer::from_fn(
            self.0.width(),
            self.0.height(),
            |x, y| Luma([stored_of(self.0.get_pixel(x, y)[0]) as f32 / PROB_PNG_SCALE]),
        ))
    }
}

/// The stored 16-bit form of a probability image (the one codec; see
/// [`MotionProbability::to_stored`]).
pub(crate) fn stored_image(p: &ProbMap) -> Gray16Image {
    let raw: Vec<u16> = p.as_raw().iter().map(|&v| stored_of(v)).collect();
    ImageBuffer::from_raw(p.width(), p.height(), raw)
        .unwrap_or_else(|| ImageBuffer::new(p.width(), p.height()))
}

/// `f` of every stored value, as an `f32` image of the same size.
fn map_stored(stored: &Gray16Image, f: impl Fn(u16) -> f32) -> ImageBuffer<Luma<f32>, Vec<f32>> {
    let raw: Vec<f32> = stored.as_raw().iter().map(|&v| f(v)).collect();
    ImageBuffer::from_raw(stored.width(), stored.height(), raw)
        .unwrap_or_else(|| ImageBuffer::new(stored.width(), stored.height()))
}

/// `trunc((1 − P)·1000)` in `f32`, P clamped to [0, 1]; NaN counts as P = 1.
fn stored_of(p: f32) -> u16 {
    let p = if p.is_nan() { 1.0 } else { p.clamp(0.0, 1.0) };
    ((1.0 - p) * PROB_PNG_SCALE) as u16
}

impl StaticWeights {
    /// Wraps a weight image (values outside [0, 1] are clamped by the SLAM frame builder).
    pub fn new(w: WeightImage) -> Self {
        Self(w)
    }

    /// All weights 1 (a frame without motion).
    pub fn ones(width: u32, height: u32) -> Self {
        Self(WeightImage::from_pixel(width, height, Luma([1.0])))
    }

    /// w = stored/1000 from the stored 16-bit form of the reference files (how the reference
    /// SLAM reads them).
    pub fn from_stored(stored: &Gray16Image) -> Self {
        Self(map_stored(stored, |v| v as f32 / PROB_PNG_SCALE))
    }

    /// The threshold ablation of the paper's supplementary material: pixels with
    /// P = 1 − w > `gamma` get weight 0 (their keypoints are dropped), all others 1.
    pub fn thresholded(&self, gamma: f32) -> Self {
        Self(ImageBuffer::from_fn(
            self.0.width(),
            self.0.height(),
            |x, y| {
                let w = self.0.get_pixel(x, y)[0];
                Luma([if 1.0 - w > gamma { 0.0 } else { 1.0 }])
            },
        ))
    }

    /// The weight image.
    pub fn as_image(&self) -> &WeightImage {
        &self.0
    }

    /// `(width, height)`.
    pub fn dimensions(&self) -> (u32, u32) {
        self.0.dimensions()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codec_truncates_like_the_reference_and_weights_match_the_file() {
        let p = MotionProbability::new(
            ProbMap::from_raw(5, 1, vec![0.0, 0.1, 0.1000001, 1.0, 0.37]).unwrap(),
        );
        let stored = p.to_stored();
        assert_eq!(stored.as_raw(), &vec![1000, 900, 899, 0, 630]);
        let from_file = StaticWeights::from_stored(&stored);
        assert_eq!(p.static_weights(), from_file);
        let back = MotionProbability::from_stored(&stored);
        assert!((back.as_image().as_raw()[1] - 0.1).abs() < 1e-6);
        assert_eq!(back.to_stored(), stored);
    }

    #[test]
    fn threshold_drops_only_likely_movers() {
        let w = StaticWeights::new(WeightImage::from_raw(3, 1, vec![1.0, 0.96, 0.94]).unwrap());
        assert_eq!(
            w.thresholded(0.05).as_image().as_raw(),
            &vec![1.0, 1.0, 0.0]
        );
        assert_eq!(StaticWeights::ones(2, 2).as_image().as_raw(), &vec![1.0; 4]);
    }
}
