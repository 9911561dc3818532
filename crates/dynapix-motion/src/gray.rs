//! Grey level of a colour image for the optical flow (reference `flow_to_gray`, spec §1.7):
//! ITU-R BT.601 weights, rounded to the nearest level.

use image::{GrayImage, RgbImage};

/// Grey level of an RGB image (ITU-R BT.601 weights) for the flow.
pub fn to_gray(img: &RgbImage) -> GrayImage {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        return unsafe { to_gray_avx2(avx2, img) };
    }
    to_gray_body(img)
}

/// [`to_gray_body`] compiled for AVX2: element-wise `f32` products and sums without fused
/// multiply-add, so the same grey levels (test `grey_is_the_same_in_every_build`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn to_gray_avx2(_: dynapix_simd::Avx2, img: &RgbImage) -> GrayImage {
    to_gray_body(img)
}

#[inline(always)]
fn to_gray_body(img: &RgbImage) -> GrayImage {
    let mut out = GrayImage::new(img.width(), img.height());
    for (o, p) in out.iter_mut().zip(img.as_raw().chunks_exact(3)) {
        let v = 0.299 * p[0] as f32 + 0.587 * p[1] as f32 + 0.114 * p[2] as f32;
        *o = round_grey(v);
    }
    out
}

/// `v.round().clamp(0.0, 255.0) as u8` for a weighted sum `v` of bytes (0 ≤ v < 256),
/// without a call to `roundf`: the truncation's fraction `v − ⌊v⌋` is exact in `f32` below
/// 2²³, so comparing it with ½ rounds half away from zero exactly as `f32::round`.
#[inline(always)]
fn round_grey(v: f32) -> u8 {
    let t = v as u32; // truncation towards zero (saturating: 0 for v < 0)
    let up = u32::from(v - t as f32 >= 0.5);
    (t + up).min(255) as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grey_is_the_same_in_every_build() {
        let img = RgbImage::from_fn(97, 31, |x, y| {
            let k = (x * 31 + y * 17) as u64;
            let b = |s: u32| ((k.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> s) & 0xFF) as u8;
            image::Rgb([b(8), b(24), b(40)])
        });
        assert_eq!(to_gray(&img).as_raw(), to_gray_body(&img).as_raw());
    }

    #[test]
    fn to_gray_rounds_every_colour_as_f32_round() {
        // Every (r, g, b) at once: a 4096 × 4096 image holds all 2²⁴ colours.
        let img = RgbImage::from_fn(4096, 4096, |x, y| {
            let i = y * 4096 + x;
            image::Rgb([(i >> 16) as u8, (i >> 8) as u8, i as u8])
        });
        let grey = to_gray(&img);
        for (g, p) in grey.pixels().zip(img.pixels()) {
            let [r, gr, b] = p.0;
            let v = 0.299 * r as f32 + 0.587 * gr as f32 + 0.114 * b as f32;
            assert_eq!(g.0[0], v.round().clamp(0.0, 255.0) as u8, "{:?}", p.0);
        }
        // Halves and their neighbours, where truncating and rounding differ.
        for k in 0..=255u32 {
            for v in [
                k as f32 + 0.5,
                (k as f32 + 0.5).next_down(),
                (k as f32 + 0.5).next_up(),
            ] {
                assert_eq!(round_grey(v), v.round().clamp(0.0, 255.0) as u8, "{v}");
            }
        }
    }
}
