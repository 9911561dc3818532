//! Test fixtures shared by the tests of the submodules.

use dynapix_geometry::camera::PinholeCamera;
use dynapix_geometry::se3::Se3;
use image::Luma;

use super::params::StaticDepthParams;
use super::{DepthView, WorkingDepth};
use crate::FloatImage;

pub(super) fn cam(w: u32, h: u32) -> PinholeCamera {
    PinholeCamera::new(
        w,
        h,
        0.8 * w as f64,
        0.8 * w as f64,
        w as f64 / 2.0,
        h as f64 / 2.0,
    )
}

/// A fronto-parallel wall at `z` with an optional box nearer than it.
pub(super) fn wall(w: u32, h: u32, z: f32, block: Option<(u32, u32, u32, u32, f32)>) -> FloatImage {
    FloatImage::from_fn(w, h, |x, y| {
        if let Some((x0, y0, x1, y1, zb)) = block
            && x >= x0
            && x < x1
            && y >= y0
            && y < y1
        {
            return Luma([zb]);
        }
        Luma([z])
    })
}

/// Views of `depths` from the current camera's own pose.
pub(super) fn same_pose_views(depths: &[WorkingDepth]) -> Vec<DepthView<'_>> {
    depths
        .iter()
        .map(|d| DepthView {
            depth: d,
            t_cs: Se3::identity(),
        })
        .collect()
}

pub(super) fn params() -> StaticDepthParams {
    StaticDepthParams {
        working_width: 80,
        ..Default::default()
    }
}

/// Minimum filter by its definition: every window visited pixel by pixel.
pub(super) fn min_filter_naive(v: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    let fmin = |a: f32, b: f32| if b < a || a.is_nan() { b } else { a };
    let mut out = vec![f32::NAN; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut m = f32::NAN;
            for yy in y.saturating_sub(r)..=(y + r).min(h - 1) {
                for xx in x.saturating_sub(r)..=(x + r).min(w - 1) {
                    m = fmin(m, v[yy * w + xx]);
                }
            }
            out[y * w + x] = m;
        }
    }
    out
}

/// Dilation by its definition.
pub(super) fn dilate_naive(m: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    let mut out = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            out[y * w + x] = (y.saturating_sub(r)..=(y + r).min(h - 1))
                .any(|yy| (x.saturating_sub(r)..=(x + r).min(w - 1)).any(|xx| m[yy * w + xx]));
        }
    }
    out
}

/// A small deterministic generator for the law tests.
pub(super) fn lcg(state: &mut u64) -> u32 {
    *state = state
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (*state >> 33) as u32
}

/// Equal bit for bit, element by element (NaN included).
pub(super) fn same_bits(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}
