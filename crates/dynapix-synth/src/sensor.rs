//! Sensor realism applied after rendering: Kinect-like depth (disparity noise, so the depth
//! error grows with depth², disparity quantisation, holes at depth discontinuities and beyond
//! the range), image noise and slow exposure changes. (Motion blur is done by the sequence
//! generator by averaging sub-frame renders.)
//!
//! Noise is drawn from a counter-based hash of (seed, frame, pixel, channel) rather than a
//! sequential generator, so it is identical whatever the rayon scheduling, and identical for
//! the background and the with-movers images: a pixel that sees the same surface in both gets
//! the same bytes.

use crate::texture::Rgb;
use std::f32::consts::TAU;

/// Sensor simulation switches and constants.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorParams {
    /// Apply Kinect-like depth noise and quantisation.
    pub depth_noise: bool,
    /// Focal length × baseline of the simulated structured-light sensor (px·m); 0.075 m × 580 px.
    pub depth_fb: f32,
    /// Standard deviation of the disparity noise (px); 0.07 px gives σz ≈ 1.6 mm·z² (Khoshelham 2012).
    pub disparity_sigma: f32,
    /// Disparity quantisation step (px); Kinect v1 uses 1/8 px.
    pub disparity_step: f32,
    /// Drop depth near discontinuities (relative jump to a 4-neighbour above `edge_rel`).
    pub depth_edges: bool,
    /// Relative depth jump that marks a discontinuity.
    pub edge_rel: f32,
    /// Probability that a discontinuity pixel loses its depth.
    pub edge_drop: f32,
    /// Depths below this are invalid (m).
    pub min_range: f32,
    /// Depths beyond this are invalid (m).
    pub max_range: f32,
    /// Standard deviation of additive image noise (grey levels, 0 = off).
    pub image_noise: f32,
    /// Slow exposure (gain) changes.
    pub exposure: bool,
    /// Relative amplitude of the gain changes.
    pub exposure_amp: f32,
    /// Sub-frame samples for motion blur (≤ 1 = off).
    pub blur_samples: u32,
    /// Exposure time over which motion blur integrates (s).
    pub blur_time: f32,
}

impl Default for SensorParams {
    /// Kinect-like defaults: depth noise, quantisation, holes and mild image noise on;
    /// exposure changes and motion blur off (they are scene-wide effects a user opts into).
    fn default() -> Self {
        Self {
            depth_noise: true,
            depth_fb: 43.5,
            disparity_sigma: 0.07,
            disparity_step: 0.125,
            depth_edges: true,
            edge_rel: 0.05,
            edge_drop: 0.8,
            min_range: 0.4,
            max_range: 5.0,
            image_noise: 1.5,
            exposure: false,
            exposure_amp: 0.12,
            blur_samples: 1,
            blur_time: 0.012,
        }
    }
}

impl SensorParams {
    /// Ideal sensor: exact depth (only the ×5000 quantisation of the file), no holes except
    /// no-hit pixels, no image noise, no exposure changes, no blur.
    pub fn clean() -> Self {
        Self {
            depth_noise: false,
            depth_edges: false,
            min_range: 0.0,
            max_range: f32::INFINITY,
            image_noise: 0.0,
            exposure: false,
            blur_samples: 1,
            ..Self::default()
        }
    }

    /// Everything on: Kinect depth, image noise, exposure changes and motion blur.
    pub fn full() -> Self {
        Self {
            exposure: true,
            blur_samples: 3,
            ..Self::default()
        }
    }
}

/// SplitMix64 finaliser.
fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Uniform in `(0, 1)` from a key.
fn uniform(key: u64) -> f32 {
    ((mix64(key) >> 40) as f32 + 0.5) / (1u64 << 24) as f32
}

/// Approximately standard normal from a key: the sum of four 16-bit uniforms from one hash
/// (Irwin–Hall, rescaled to unit variance). No transcendental functions: this runs for every
/// pixel and channel; tails are bounded at ±3.46σ, which is harmless for sensor noise.
fn gauss(key: u64) -> f32 {
    let h = mix64(key);
    let s = (h & 0xFFFF) + ((h >> 16) & 0xFFFF) + ((h >> 32) & 0xFFFF) + (h >> 48);
    // Mean 2, variance 4/12 for uniforms on [0, 1).
    (s as f32 / 65536.0 - 2.0) * 3.0f32.sqrt()
}

/// Rounds a value already known to be ≥ -0.5 (no libm call).
#[inline]
fn round_pos(v: f32) -> f32 {
    ((v + 0.5) as i64) as f32
}

fn key(seed: u64, frame: u64, pixel: u64, channel: u64) -> u64 {
    mix64(mix64(mix64(seed ^ 0x5E45_0000) ^ frame) ^ pixel) ^ (channel << 56)
}

/// Exposure gain at time `t` (1 when exposure changes are off): a smooth random curve.
pub fn exposure_gain(p: &SensorParams, seed: u64, t: f64) -> f32 {
    if !p.exposure {
        return 1.0;
    }
    let ph1 = uniform(seed ^ 0xE1) * TAU;
    let ph2 = uniform(seed ^ 0xE2) * TAU;
    let t = t as f32;
    1.0 + p.exposure_amp * (0.7 * (TAU * t / 7.3 + ph1).sin() + 0.3 * (TAU * t / 2.9 + ph2).sin())
}

/// Converts linear colours to 8-bit RGB with gain and noise.
pub fn to_rgb8(
    p: &SensorParams,
    seed: u64,
    frame: u64,
    gain: f32,
    colours: &[Rgb],
    out: &mut [u8],
) {
    for (i, (c, o)) in colours.iter().zip(out.chunks_exact_mut(3)).enumerate() {
        for ch in 0..3 {
            let mut v = c[ch] * gain * 255.0;
            if p.image_noise > 0.0 {
                v += p.image_noise * gauss(key(seed, frame, i as u64, ch as u64));
            }
            o[ch] = round_pos(v.max(0.0)).min(255.0) as u8;
        }
    }
}

/// Converts ray depths (`INFINITY` = no hit) to 16-bit depth (metres × `factor`) with the
/// Kinect model. `width` is the row length (for the discontinuity test).
pub fn to_depth16(
    p: &SensorParams,
    seed: u64,
    frame: u64,
    factor: f32,
    width: usize,
    depth: &[f32],
    out: &mut [u16],
) {
    let h = depth.len() / width.max(1);
    for (i, (&z, o)) in depth.iter().zip(out.iter_mut()).enumerate() {
        *o = 0;
        if !z.is_finite() || z < p.min_range || z > p.max_range {
            continue;
        }
        if p.depth_edges {
            let (x, y) = (i % width, i / width);
            let mut jump = false;
            for (nx, ny) in [
                (x.wrapping_sub(1), y),
                (x + 1, y),
                (x, y.wrapping_sub(1)),
                (x, y + 1),
            ] {
                if nx < width && ny < h {
                    let zn = depth[ny * width + nx];
                    if !zn.is_finite() || (zn - z).abs() > p.edge_rel * z {
                        jump = true;
                    }
                }
            }
            if jump && uniform(key(seed, frame, i as u64, 7)) < p.edge_drop {
                continue;
            }
        }
        let mut zz = z;
        if p.depth_noise {
            let mut d = p.depth_fb / z + p.disparity_sigma * gauss(key(seed, frame, i as u64, 5));
            if p.disparity_step > 0.0 {
                d = round_pos((d / p.disparity_step).max(0.0)) * p.disparity_step;
            }
            if d <= 0.0 {
                continue;
            }
            zz = p.depth_fb / d;
            if zz > p.max_range {
                continue;
            }
        }
        *o = round_pos(zz * factor).min(u16::MAX as f32) as u16;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_noise_grows_with_depth_squared() {
        let p = SensorParams {
            depth_edges: false,
            ..SensorParams::default()
        };
        let n = 4000;
        let mut sd = Vec::new();
        for z in [1.0f32, 2.0, 4.0] {
            let depth = vec![z; n];
            let mut out = vec![0u16; n];
            to_depth16(&p, 1, 0, 5000.0, 100, &depth, &mut out);
            let vals: Vec<f32> = out.iter().map(|&v| v as f32 / 5000.0).collect();
            let mean = vals.iter().sum::<f32>() / n as f32;
            let var = vals.iter().map(|v| (v - mean).powi(2)).sum::<f32>() / n as f32;
            assert!((mean - z).abs() < 0.01 * z * z, "bias at {z}: {mean}");
            sd.push(var.sqrt());
        }
        // Quadrupling depth multiplies σ by ~16 (z²); allow slack for quantisation.
        let ratio = sd[2] / sd[0];
        assert!(ratio > 8.0 && ratio < 30.0, "{sd:?}");
    }

    #[test]
    fn clean_depth_is_exact_and_holes_beyond_range() {
        let p = SensorParams::clean();
        let mut out = vec![0u16; 3];
        to_depth16(&p, 0, 0, 5000.0, 3, &[1.2345, f32::INFINITY, 3.0], &mut out);
        assert_eq!(out, vec![6173, 0, 15000]);
        let k = SensorParams::default();
        to_depth16(&k, 0, 0, 5000.0, 3, &[6.0, 6.0, 6.0], &mut out);
        assert_eq!(out, vec![0, 0, 0]);
    }
}
