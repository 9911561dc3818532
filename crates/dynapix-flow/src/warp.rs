//! Backward warping of an image by a flow: `out(x) = B(x + f(x))`, bilinear with replicated
//! borders. For the flow from A to B this produces an approximation of A from B; the motion
//! module uses it to align neighbouring frames, tests use it to build pairs with known flow.

use crate::plane::Plane;
use crate::{FlowError, FlowField};
use image::GrayImage;
use rayon::prelude::*;

fn check(w: u32, h: u32, flow: &FlowField) -> Result<(), FlowError> {
    if (w, h) != (flow.width, flow.height) || flow.data.len() != (w as usize) * (h as usize) {
        return Err(FlowError::SizeMismatch {
            a: (w, h),
            b: (flow.width, flow.height),
        });
    }
    Ok(())
}

/// Warps a float plane (see the module documentation).
pub fn warp_plane_by(src: &Plane, flow: &FlowField) -> Result<Plane, FlowError> {
    check(src.w as u32, src.h as u32, flow)?;
    let w = src.w;
    let mut out = Plane::zeros(src.w, src.h);
    if w == 0 {
        return Ok(out);
    }
    out.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, px) in row.iter_mut().enumerate() {
            let f = flow.data[y * w + x];
            *px = src.bilinear(x as f32 + f[0], y as f32 + f[1]);
        }
    });
    Ok(out)
}

/// Warps a grey image (values rounded back to 8 bits).
pub fn warp_gray(src: &GrayImage, flow: &FlowField) -> Result<GrayImage, FlowError> {
    let p = warp_plane_by(&Plane::from_gray(src), flow)?;
    let raw = p
        .data
        .iter()
        .map(|v| v.round().clamp(0.0, 255.0) as u8)
        .collect();
    GrayImage::from_raw(src.width(), src.height(), raw)
        .ok_or_else(|| FlowError::Other("warped image buffer has the wrong size".into()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integer_shift_moves_pixels() {
        let img = GrayImage::from_fn(6, 4, |x, y| image::Luma([(10 * x + 50 * y) as u8]));
        let flow = FlowField::constant(6, 4, [1.0, 1.0]);
        let out = warp_gray(&img, &flow).unwrap();
        assert_eq!(out.get_pixel(2, 1).0[0], img.get_pixel(3, 2).0[0]);
        // Replicated border at the far edge.
        assert_eq!(out.get_pixel(5, 3).0[0], img.get_pixel(5, 3).0[0]);
        assert!(warp_gray(&img, &FlowField::zeros(5, 4)).is_err());
    }
}
