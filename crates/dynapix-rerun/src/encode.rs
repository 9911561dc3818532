//! The per-frame conversions of the logged images, kept cheap because they run on the
//! tracking thread: the colour image as JPEG (the `jpeg-encoder` crate, AVX2 where the CPU
//! has it), the depth as 16-bit millimetres, and the mean of P.

use dynapix_io::DepthImage;
use image::RgbImage;

/// `rgb` as a JPEG file of `quality` (clamped to 1–100).
pub(crate) fn jpeg(rgb: &RgbImage, quality: u8) -> Result<Vec<u8>, String> {
    let (w, h) = rgb.dimensions();
    let (Ok(w), Ok(h)) = (u16::try_from(w), u16::try_from(h)) else {
        return Err(format!("{w}×{h} is larger than JPEG allows (65535×65535)"));
    };
    let mut out = Vec::with_capacity(rgb.as_raw().len() / 8);
    jpeg_encoder::Encoder::new(&mut out, quality.clamp(1, 100))
        .encode(rgb.as_raw(), w, h, jpeg_encoder::ColorType::Rgb)
        .map_err(|e| e.to_string())?;
    Ok(out)
}

/// `depth` (metres) at 1/`downscale` of its size (every `downscale`-th pixel of every
/// `downscale`-th row) as little-endian 16-bit millimetres, 0 where the depth is missing, and
/// the size `[width, height]` of that image.
pub(crate) fn depth_mm(depth: &DepthImage, downscale: u32) -> (Vec<u8>, [u32; 2]) {
    let s = downscale.max(1) as usize;
    let (w, h) = (depth.width() as usize, depth.height() as usize);
    let (ow, oh) = (w / s, h / s);
    let raw = depth.as_raw();
    let mut out = Vec::with_capacity(2 * ow * oh);
    for y in 0..oh {
        let row = &raw[y * s * w..][..w];
        for x in 0..ow {
            let d = row[x * s];
            // Rounded to the nearest millimetre; NaN, ≤ 0 and beyond 65.535 m give 0 / 65535.
            let mm = if d > 0.0 {
                (d * 1000.0 + 0.5).min(65535.0) as u16
            } else {
                0
            };
            out.extend_from_slice(&mm.to_le_bytes());
        }
    }
    (out, [ow as u32, oh as u32])
}

/// The mean motion probability P = 1 − w over static weights `w`.
/// 0 for no pixels.
pub(crate) fn mean_p(weights: &[f32]) -> f64 {
    if weights.is_empty() {
        return 0.0;
    }
    const LANES: usize = 8;
    let mut acc = [0f32; LANES];
    let chunks = weights.chunks_exact(LANES);
    let tail: f64 = chunks.remainder().iter().map(|&w| f64::from(w)).sum();
    for c in chunks {
        for (a, &w) in acc.iter_mut().zip(c) {
            *a += w;
        }
    }
    let sum_w = acc.iter().map(|&a| f64::from(a)).sum::<f64>() + tail;
    1.0 - sum_w / weights.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jpeg_decodes_back_to_the_image() {
        let rgb = RgbImage::from_fn(64, 48, |x, y| {
            image::Rgb([(x * 4) as u8, (y * 5) as u8, ((x + y) * 2) as u8])
        });
        let bytes = jpeg(&rgb, 90).expect("encodes");
        let back = image::load_from_memory_with_format(&bytes, image::ImageFormat::Jpeg)
            .expect("decodes")
            .to_rgb8();
        assert_eq!(back.dimensions(), (64, 48));
        let err: f64 = rgb
            .as_raw()
            .iter()
            .zip(back.as_raw())
            .map(|(&a, &b)| f64::from(a.abs_diff(b)))
            .sum::<f64>()
            / rgb.as_raw().len() as f64;
        assert!(err < 4.0, "mean absolute error {err}");
    }

    #[test]
    fn depth_is_millimetres_of_every_other_pixel_and_missing_is_zero() {
        let d = DepthImage::from_fn(6, 4, |x, y| {
            image::Luma([match (x, y) {
                (0, 0) => f32::NAN,
                (2, 0) => -1.0,
                (4, 0) => 70.0,
                _ => 0.25 * x as f32 + 1.0 * y as f32 + 0.0004,
            }])
        });
        let (bytes, size) = depth_mm(&d, 2);
        assert_eq!(size, [3, 2]);
        let mm: Vec<u16> = bytes
            .chunks_exact(2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .collect();
        // Row 0: NaN, negative, beyond 65.535 m; row 2: 2.0004, 2.5004, 3.0004 m.
        assert_eq!(mm, vec![0, 0, 65535, 2000, 2500, 3000]);
    }

    #[test]
    fn mean_p_is_one_minus_the_mean_weight() {
        let w: Vec<f32> = (0..1003).map(|i| (i % 17) as f32 / 16.0).collect();
        let naive = w.iter().map(|&w| 1.0 - f64::from(w)).sum::<f64>() / w.len() as f64;
        assert!((mean_p(&w) - naive).abs() < 1e-6);
        assert_eq!(mean_p(&[]), 0.0);
    }
}
