//! Image pairs with known flow for tests and evaluation: a ground-truth flow `f` on the grid of
//! A and an image B give `A = warp(B, f)`, so `B(x + f(x)) = A(x)` holds exactly (up to the
//! bilinear interpolation and 8-bit rounding of A). Provides the flows used by the evaluation:
//! constant translation, a similarity/affine motion and a smooth non-rigid field.

use crate::FlowField;
use crate::warp::warp_gray;
use image::GrayImage;

/// A constant translation `t` everywhere.
pub fn translation(width: u32, height: u32, t: [f32; 2]) -> FlowField {
    FlowField::constant(width, height, t)
}

/// The flow of the affine map `x ↦ c + M (x − c) + t` about the image centre `c`, with `M` a
/// rotation by `angle_deg` times `scale`.
pub fn affine(width: u32, height: u32, angle_deg: f32, scale: f32, t: [f32; 2]) -> FlowField {
    let (s, c) = angle_deg.to_radians().sin_cos();
    let (m00, m01, m10, m11) = (scale * c, -scale * s, scale * s, scale * c);
    let (cx, cy) = ((width as f32 - 1.0) / 2.0, (height as f32 - 1.0) / 2.0);
    let mut f = FlowField::zeros(width, height);
    for (i, d) in f.data.iter_mut().enumerate() {
        let x = (i % width as usize) as f32 - cx;
        let y = (i / width as usize) as f32 - cy;
        *d = [m00 * x + m01 * y + t[0] - x, m10 * x + m11 * y + t[1] - y];
    }
    f
}

/// A smooth non-rigid field of sines with peak magnitude about `amplitude` pixels.
pub fn smooth_nonrigid(width: u32, height: u32, amplitude: f32) -> FlowField {
    let tau = std::f32::consts::TAU;
    let (w, h) = (width as f32, height as f32);
    let mut f = FlowField::zeros(width, height);
    for (i, d) in f.data.iter_mut().enumerate() {
        let x = (i % width as usize) as f32 / w;
        let y = (i / width as usize) as f32 / h;
        *d = [
            amplitude * (0.6 * (tau * 1.3 * x + 0.4).sin() * (tau * 0.9 * y).cos() + 0.4),
            amplitude * (0.7 * (tau * 0.8 * x).cos() * (tau * 1.1 * y + 1.0).sin() - 0.2),
        ];
    }
    f
}

/// Image A of the pair (A, `b`) whose flow from A to B is `gt`.
pub fn make_a(b: &GrayImage, gt: &FlowField) -> Result<GrayImage, crate::FlowError> {
    warp_gray(b, gt)
}

/// A deterministic textured test image (sum of sines of several frequencies).
pub fn texture(width: u32, height: u32) -> GrayImage {
    GrayImage::from_fn(width, height, |x, y| {
        let (x, y) = (x as f32, y as f32);
        let v = 128.0
            + 45.0 * (0.21 * x + 0.05 * y).sin()
            + 35.0 * (0.13 * y - 0.07 * x).cos()
            + 25.0 * (0.37 * x).sin() * (0.29 * y).cos();
        image::Luma([v.round().clamp(0.0, 255.0) as u8])
    })
}
