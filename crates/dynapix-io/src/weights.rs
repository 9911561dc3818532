//! The two per-pixel maps of DynaPix as distinct types, so one cannot be passed where the other
//! is expected (design §3): the motion probability P ∈ [0, 1] that the motion stage computes,
//! and the static weight w = 1 − P that the SLAM backend consumes (paper §3.2).
//!
//! Both go through one 16-bit codec, the reference format of `prob/*.png` (spec §1.8): the
//! stored value is `trunc((1 − P)·1000)` computed in `f32`, and the weight read back is
//! `stored / 1000`. [`MotionProbability::static_weights`] applies the same quantisation, so a
//! map used in memory gives the SLAM backend exactly the weights it would get from its file.
//!
//! The probability files live here too: the reference 16-bit PNG ([`write_prob_png`],
//! [`read_prob_png`], [`read_static_weights`], …) and the lossless PFM variant that stores P
//! itself ([`write_prob_pfm`], [`read_prob_pfm`]).

use std::path::Path;

use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{DynamicImage, ImageBuffer, Luma};

use crate::atomic::write_atomic_with;
use crate::error::{IoError, Result};
use crate::images::{self, Gray16Image, ProbMap, read_pfm, write_gray16, write_pfm};

/// Scale of the stored probability weight: `stored = trunc((1 − P)·1000)`.
pub const PROB_PNG_SCALE: f32 = 1000.0;

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

    /// Reads a reference probability PNG (P = 1 − stored/1000, [`read_motion_probability`]).
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        read_motion_probability(path)
    }

    /// Writes the map as a reference probability PNG, atomically
    /// ([`write_motion_probability`]).
    pub fn write(&self, path: impl AsRef<Path>) -> Result<()> {
        write_motion_probability(path, self)
    }

    /// Writes P losslessly as PFM ([`write_prob_pfm`]).
    pub fn write_pfm(&self, path: impl AsRef<Path>) -> Result<()> {
        write_prob_pfm(path, &self.0)
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
fn stored_image(p: &ProbMap) -> Gray16Image {
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

/// Reads a reference probability PNG without conversion: the stored static weight
/// `trunc((1 − P)·1000)` ∈ [0, 1000], as the reference SLAM consumes it (w = stored/1000).
pub fn read_prob_png_raw(path: impl AsRef<Path>) -> Result<Gray16Image> {
    let path = path.as_ref();
    let img = match images::decode(path)? {
        DynamicImage::ImageLuma16(img) => img,
        other => {
            return Err(IoError::invalid(
                path,
                format!(
                    "expected a 16-bit single-channel probability map, got {}",
                    images::describe(&other)
                ),
            ));
        }
    };
    if img.as_raw().iter().any(|&v| v > 1000)
        && let Some((x, y, p)) = img.enumerate_pixels().find(|(_, _, p)| p[0] > 1000)
    {
        return Err(IoError::invalid(
            path,
            format!("pixel ({x}, {y}) stores {} > 1000", p[0]),
        ));
    }
    Ok(img)
}

/// Reads a reference probability PNG as P = 1 − stored/1000 (see [`read_prob_png_raw`]).
pub fn read_prob_png(path: impl AsRef<Path>) -> Result<ProbMap> {
    Ok(read_motion_probability(path)?.into_image())
}

/// Reads a reference probability PNG as a typed [`MotionProbability`].
pub fn read_motion_probability(path: impl AsRef<Path>) -> Result<MotionProbability> {
    Ok(MotionProbability::from_stored(&read_prob_png_raw(path)?))
}

/// Reads a reference probability PNG as the [`StaticWeights`] the SLAM backend uses
/// (w = stored/1000, as the reference reads it).
pub fn read_static_weights(path: impl AsRef<Path>) -> Result<StaticWeights> {
    Ok(StaticWeights::from_stored(&read_prob_png_raw(path)?))
}

/// Writes P as a reference probability PNG (see [`MotionProbability::to_stored`]),
/// atomically.
/// A NaN probability is an error.
pub fn write_prob_png(path: impl AsRef<Path>, prob: &ProbMap) -> Result<()> {
    let path = path.as_ref();
    check_finite(path, prob)?;
    write_gray16(path, &stored_image(prob))
}

/// Writes a typed motion probability as a reference probability PNG, atomically (a NaN
/// probability is an error).
pub fn write_motion_probability(path: impl AsRef<Path>, prob: &MotionProbability) -> Result<()> {
    let path = path.as_ref();
    check_finite(path, prob.as_image())?;
    // Maps are written once per pass and read back at once: fast compression with the `Up`
    // row filter (lossless like any PNG). On a 640×480 map against the encoder's defaults:
    // write 2.3 → 2.0 ms, read 1.3 → 0.4 ms, 25 → 35 KB (no filter: 540 KB and slower).
    let stored = prob.to_stored();
    write_atomic_with(path, |w| {
        stored
            .write_with_encoder(PngEncoder::new_with_quality(
                w,
                CompressionType::Fast,
                FilterType::Up,
            ))
            .map_err(std::io::Error::other)
    })
}

fn check_finite(path: &Path, map: &ImageBuffer<Luma<f32>, Vec<f32>>) -> Result<()> {
    if !map.as_raw().iter().any(|p| p.is_nan()) {
        return Ok(());
    }
    match map.enumerate_pixels().find(|(_, _, p)| p[0].is_nan()) {
        Some((x, y, _)) => Err(IoError::invalid(
            path,
            format!("refusing to write: pixel ({x}, {y}) is NaN"),
        )),
        None => Ok(()),
    }
}

/// Writes P losslessly as PFM (see [`write_pfm`]); NaN is an error.
pub fn write_prob_pfm(path: impl AsRef<Path>, prob: &ProbMap) -> Result<()> {
    let path = path.as_ref();
    check_finite(path, prob)?;
    write_pfm(path, prob)
}

/// Reads a lossless probability map written by [`write_prob_pfm`]; values must lie in [0, 1].
pub fn read_prob_pfm(path: impl AsRef<Path>) -> Result<ProbMap> {
    let path = path.as_ref();
    let map = read_pfm(path)?;
    if let Some((x, y, p)) = map
        .enumerate_pixels()
        .find(|(_, _, p)| !(0.0..=1.0).contains(&p[0]))
    {
        return Err(IoError::invalid(
            path,
            format!("pixel ({x}, {y}) has probability {} outside [0, 1]", p[0]),
        ));
    }
    Ok(map)
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

    #[test]
    fn prob_png_quantisation_matches_the_reference() {
        // In f32, 1 − 0.998 = 0.0019999743, so 0.998 stores 1 (truncation, as in numpy).
        let ps = [0.0f32, 0.1, 0.1000001, 0.5, 0.998, 0.9991, 1.0, -0.5, 1.5];
        let prob = ProbMap::from_fn(ps.len() as u32, 1, |x, _| Luma([ps[x as usize]]));
        let stored: Vec<u16> = MotionProbability::new(prob.clone())
            .to_stored()
            .pixels()
            .map(|p| p[0])
            .collect();
        assert_eq!(stored, vec![1000, 900, 899, 500, 1, 0, 0, 1000, 0]);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("1.png");
        write_prob_png(&p, &prob).unwrap();
        let back = read_prob_png(&p).unwrap();
        assert_eq!(back.get_pixel(0, 0)[0], 0.0);
        assert!((back.get_pixel(3, 0)[0] - 0.5).abs() < 1e-6);
        assert_eq!(back.get_pixel(6, 0)[0], 1.0);
        let nan = ProbMap::from_pixel(2, 2, Luma([f32::NAN]));
        let e = write_prob_png(&p, &nan).unwrap_err().to_string();
        assert!(e.contains("NaN"), "{e}");
        write_gray16(&p, &Gray16Image::from_pixel(2, 2, Luma([1001]))).unwrap();
        let e = read_prob_png(&p).unwrap_err().to_string();
        assert!(e.contains("1.png") && e.contains("1001"), "{e}");
    }

    #[test]
    fn pfm_is_lossless_and_bad_pfm_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("p.pfm");
        let prob = ProbMap::from_fn(5, 3, |x, y| Luma([(x * 3 + y) as f32 / 15.0 + 1e-7]));
        write_prob_pfm(&p, &prob).unwrap();
        assert_eq!(read_prob_pfm(&p).unwrap(), prob);
        let bytes = std::fs::read(&p).unwrap();
        assert!(bytes.starts_with(b"Pf\n5 3\n-1.0\n"));
        // First stored row is the bottom image row.
        let first = f32::from_le_bytes(bytes[12..16].try_into().unwrap());
        assert_eq!(first, prob.get_pixel(0, 2)[0]);
        std::fs::write(&p, &bytes[..bytes.len() - 1]).unwrap();
        let e = read_pfm(&p).unwrap_err().to_string();
        assert!(e.contains("p.pfm") && e.contains("data bytes"), "{e}");
        for bad in [
            &b"PF\n1 1\n-1\n"[..],
            b"Pf\n1\n-1\n",
            b"Pf\n1 1\n0\n",
            b"Pf",
            b"",
        ] {
            std::fs::write(&p, bad).unwrap();
            let e = read_pfm(&p).unwrap_err().to_string();
            assert!(e.contains("p.pfm"), "{e}");
        }
        let big = ProbMap::from_pixel(1, 1, Luma([2.0]));
        write_pfm(&p, &big).unwrap();
        assert!(
            read_prob_pfm(&p)
                .unwrap_err()
                .to_string()
                .contains("outside")
        );
    }
}
