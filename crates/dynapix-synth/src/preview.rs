//! Contact sheet of all presets: for a few frames of each, rgb | background | mask | depth
//! side by side (depth shown with a colour ramp, black = no depth), to check by eye that the
//! room looks plausible and the layers line up.

use crate::sequence::{Preset, Sequence, SynthParams};
use crate::{Scene, SynthError};
use image::{Rgb, RgbImage, imageops};
use std::sync::Arc;

/// Builds the contact sheet: one block per preset, blocks laid out row-major in a grid of
/// `ceil(sqrt(n))` columns (so 9 presets make a 3×3 grid); inside a block each row is one
/// frame (picked at `times`, seconds) and the columns are rgb, background, mask and depth, each
/// scaled to `thumb_width` pixels wide. Blocks are separated by a 4-pixel grey border.
pub fn contact_sheet(
    base: &SynthParams,
    presets: &[Preset],
    times: &[f64],
    thumb_width: u32,
) -> Result<RgbImage, SynthError> {
    let scene = Arc::new(Scene::generate(base.seed, &base.scene));
    let (w, h) = (base.camera.width, base.camera.height);
    let tw = thumb_width.max(16);
    let th = (tw as u64 * h as u64 / w.max(1) as u64).max(1) as u32;
    let grid_cols = (presets.len() as f64).sqrt().ceil().max(1.0) as u32;
    let grid_rows = (presets.len() as u32).div_ceil(grid_cols);
    let gap = 4u32;
    let block_w = 4 * tw + gap;
    let block_h = times.len() as u32 * th + gap;
    let mut sheet = RgbImage::from_pixel(
        grid_cols * block_w,
        grid_rows * block_h,
        Rgb([128, 128, 128]),
    );
    for (b, &preset) in presets.iter().enumerate() {
        let (bx, by) = (
            (b as u32 % grid_cols) * block_w,
            (b as u32 / grid_cols) * block_h,
        );
        let frames = times
            .iter()
            .map(|t| (t * base.fps).round() as usize + 1)
            .max()
            .unwrap_or(1);
        let params = SynthParams {
            preset,
            frames,
            ..base.clone()
        };
        let seq = Sequence::with_scene(params, scene.clone())?;
        for (row, &t) in times.iter().enumerate() {
            let row = row as u32;
            let i = (t * base.fps).round() as usize;
            let (f, _) = seq.frame(i, None);
            let mask = RgbImage::from_fn(w, h, |x, y| {
                let m = f.mask.get_pixel(x, y)[0];
                Rgb([m, m, m])
            });
            let depth = RgbImage::from_fn(w, h, |x, y| ramp(f.depth.get_pixel(x, y)[0]));
            for (c, img) in [&f.rgb, &f.background, &mask, &depth]
                .into_iter()
                .enumerate()
            {
                let small = imageops::resize(img, tw, th, imageops::FilterType::Triangle);
                imageops::replace(
                    &mut sheet,
                    &small,
                    (bx + c as u32 * tw) as i64,
                    (by + row * th) as i64,
                );
            }
        }
    }
    Ok(sheet)
}

/// Colour ramp for depth (0 m blue … 5 m red), black for missing depth.
fn ramp(v: u16) -> Rgb<u8> {
    if v == 0 {
        return Rgb([0, 0, 0]);
    }
    let z = (v as f32 / 5000.0 / 5.0).clamp(0.0, 1.0);
    let r = (255.0 * (1.5 * z - 0.25).clamp(0.0, 1.0)) as u8;
    let g = (255.0 * (1.0 - (2.0 * z - 1.0).abs())) as u8;
    let b = (255.0 * (1.0 - 1.5 * z).clamp(0.0, 1.0)) as u8;
    Rgb([r, g, b])
}
