//! Static background reconstructed from neighbouring frames (new; the reference needs
//! externally inpainted or re-rendered backgrounds, spec §7.2). Many neighbour frames are
//! splatted into the current view with their depth and poses (paper-mode splatting, so holes
//! are known), and each pixel takes the per-channel median of all samples that landed there,
//! the current frame included. A person walking through covers a pixel in only a few of the
//! frames and drops out of the median; the median of the splatted depths gives the background
//! depth that the moving term needs to warp the background.

use dynapix_geometry::{PinholeCamera, Se3};
use image::{Rgb, RgbImage};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::splat::{SplatParams, splat};
use crate::{FloatImage, Mode, MotionError, check_size};

/// Parameters of the reconstruction. `Default`: ±15 frames, every 3rd.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReconstructParams {
    /// Largest frame offset used (frames).
    pub radius: usize,
    /// Offset step (frames): offsets ±step, ±2·step, … up to ±radius.
    pub step: usize,
    /// Splatting used for the sources (paper mode: holes must be known).
    pub splat: SplatParams,
}

impl Default for ReconstructParams {
    fn default() -> Self {
        Self {
            radius: 15,
            step: 3,
            splat: SplatParams::new(Mode::Paper),
        }
    }
}

impl ReconstructParams {
    /// Frame offsets used as sources, nearest first (`+step, −step, +2·step, …`).
    pub fn offsets(&self) -> Vec<i64> {
        let step = self.step.max(1) as i64;
        let mut out = Vec::new();
        let mut k = step;
        while k <= self.radius as i64 {
            out.push(k);
            out.push(-k);
            k += step;
        }
        out
    }
}

/// A reconstructed background.
#[derive(Clone, Debug)]
pub struct Background {
    /// Background colour.
    pub image: RgbImage,
    /// Background depth, metres (0 where no sample had a depth).
    pub depth: FloatImage,
    /// Number of samples per pixel (the current frame included).
    pub samples: Vec<u8>,
}

/// One source frame: colour, depth and `T_ts`, the transform from its camera into the target
/// camera (`T_wt⁻¹ · T_ws`).
#[derive(Clone, Copy, Debug)]
pub struct Source<'a> {
    /// Colour image.
    pub rgb: &'a RgbImage,
    /// Depth, metres.
    pub depth: &'a FloatImage,
    /// Source camera → target camera.
    pub t_ts: Se3,
}

/// One reconstructed image row: colours, depths, sample counts.
type Row = (Vec<[u8; 3]>, Vec<f32>, Vec<u8>);

fn median_u8(v: &mut [u8]) -> u8 {
    let mid = v.len() / 2;
    *v.select_nth_unstable(mid).1
}

fn median_f32(v: &mut [f32]) -> f32 {
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// Reconstructs the static background of the target frame (`rgb`, `depth`) from `sources`.
pub fn reconstruct_background(
    rgb: &RgbImage,
    depth: &FloatImage,
    sources: &[Source],
    cam: &PinholeCamera,
    params: &ReconstructParams,
) -> Result<Background, MotionError> {
    let size = (cam.width, cam.height);
    check_size("background target image", size, rgb.dimensions())?;
    check_size("background target depth", size, depth.dimensions())?;
    let warped = sources
        .par_iter()
        .map(|s| splat(s.rgb, s.depth, &s.t_ts, cam, &params.splat))
        .collect::<Result<Vec<_>, _>>()?;
    let w = cam.width as usize;
    let mut image = RgbImage::new(cam.width, cam.height);
    let mut bdepth = FloatImage::new(cam.width, cam.height);
    let mut samples = vec![0u8; w * cam.height as usize];
    let rows: Vec<Row> = (0..cam.height as usize)
        .into_par_iter()
        .map(|y| {
            let mut cols = Vec::with_capacity(w);
            let mut zs = Vec::with_capacity(w);
            let mut ns = Vec::with_capacity(w);
            let cap = warped.len() + 1;
            let mut ch = [
                Vec::with_capacity(cap),
                Vec::with_capacity(cap),
                Vec::with_capacity(cap),
            ];
            let mut zv = Vec::with_capacity(cap);
            for x in 0..w {
                let i = y * w + x;
                for c in &mut ch {
                    c.clear();
                }
                zv.clear();
                let p = rgb.get_pixel(x as u32, y as u32).0;
                for c in 0..3 {
                    ch[c].push(p[c]);
                }
                let z0 = depth.as_raw()[i];
                if z0 > 0.0 {
                    zv.push(z0);
                }
                for wp in &warped {
                    if wp.holes[i] {
                        continue;
                    }
                    let q = wp.image.get_pixel(x as u32, y as u32).0;
                    for c in 0..3 {
                        ch[c].push(q[c]);
                    }
                    zv.push(wp.depth.as_raw()[i]);
                }
                cols.push([
                    median_u8(&mut ch[0]),
                    median_u8(&mut ch[1]),
                    median_u8(&mut ch[2]),
                ]);
                zs.push(if zv.is_empty() {
                    0.0
                } else {
                    median_f32(&mut zv)
                });
                ns.push(ch[0].len().min(255) as u8);
            }
            (cols, zs, ns)
        })
        .collect();
    for (y, (cols, zs, ns)) in rows.into_iter().enumerate() {
        for (x, ((c, z), n)) in cols.into_iter().zip(zs).zip(ns).enumerate() {
            image.put_pixel(x as u32, y as u32, Rgb(c));
            bdepth.put_pixel(x as u32, y as u32, image::Luma([z]));
            samples[y * w + x] = n;
        }
    }
    Ok(Background {
        image,
        depth: bdepth,
        samples,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::psnr_masked;
    use crate::testutil::{Scene, small_camera};

    #[test]
    fn walking_mover_vanishes_from_the_median() {
        let cam = small_camera();
        let scene = Scene::default();
        // Eleven frames; the camera slides sideways while the panel crosses the view.
        let frames: Vec<_> = (0..11)
            .map(|k| {
                let t = Se3::translation(-0.1 + 0.02 * k as f64, 0.0, 0.0);
                let (rgb, d) = scene.render(&cam, &t, true, -0.5 + 0.1 * k as f64);
                (rgb, d, t)
            })
            .collect();
        let c = 5;
        let t_wc = frames[c].2;
        let sources: Vec<Source> = frames
            .iter()
            .enumerate()
            .filter(|&(k, _)| k != c)
            .map(|(_, f)| Source {
                rgb: &f.0,
                depth: &f.1,
                t_ts: t_wc.inverse() * f.2,
            })
            .collect();
        let bg = reconstruct_background(
            &frames[c].0,
            &frames[c].1,
            &sources,
            &cam,
            &ReconstructParams::default(),
        )
        .unwrap();
        let (truth, truth_depth) = scene.render(&cam, &t_wc, false, 0.0);
        let mover: Vec<bool> = frames[c].1.iter().map(|z| (z - 1.5).abs() < 1e-3).collect();
        assert!(mover.iter().filter(|&&m| m).count() > 100);
        let before = psnr_masked(&frames[c].0, &truth, &mover).unwrap();
        let after = psnr_masked(&bg.image, &truth, &mover).unwrap();
        assert!(after > 25.0 && after > before + 10.0, "{before} → {after}");
        // The depth behind the mover is the background's, not the mover's 1.5 m.
        let mut ok = 0;
        let mut n = 0;
        for ((z, t), &m) in bg.depth.iter().zip(truth_depth.iter()).zip(&mover) {
            if m {
                n += 1;
                if (z - t).abs() < 0.05 {
                    ok += 1;
                }
            }
        }
        assert!(ok * 10 > n * 9, "{ok} of {n}");
    }

    #[test]
    fn offsets_are_nearest_first() {
        let p = ReconstructParams {
            radius: 7,
            step: 3,
            ..Default::default()
        };
        assert_eq!(p.offsets(), vec![3, -3, 6, -6]);
    }
}
