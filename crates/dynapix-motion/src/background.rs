//! Static background reconstructed from neighbouring frames (new; the reference needs
//! externally inpainted or re-rendered backgrounds, spec §7.2). Many neighbour frames are
//! splatted into the current view with their depth and poses (paper-mode splatting, so holes
//! are known), and each pixel combines all samples that landed there, the current frame
//! included: by default the median of the samples on the far surface (movers are in front of
//! the static scene), or a plain per-channel median. A person walking through covers a pixel
//! in only some of the frames and drops out; the depth of the kept samples gives the
//! background depth that the moving term needs to warp the background.

use dynapix_flow::FlowProvider;
use dynapix_geometry::{PinholeCamera, Se3};
use image::{Rgb, RgbImage};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::splat::{SplatParams, splat};
use crate::{FloatImage, Mode, MotionError, check_size};

/// Parameters of the reconstruction. `Default`: ±15 frames, every 3rd.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ReconstructParams {
    /// Largest frame offset used (frames).
    pub radius: usize,
    /// Offset step (frames): offsets ±step, ±2·step, … up to ±radius.
    pub step: usize,
    /// Splatting used for the sources (paper mode: holes must be known).
    pub splat: SplatParams,
    /// Per-pixel statistic over the samples.
    pub statistic: Statistic,
    /// Rotation-refinement iterations of each source pose when a flow provider is given
    /// ([`crate::align::refine_rotation`]); 0 trusts the poses.
    pub refine_iterations: usize,
}

/// How the samples of a pixel are combined.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Statistic {
    /// Per-channel median of all samples.
    Median,
    /// Median of the samples on the far surface: movers are in front of the static scene, so
    /// the samples whose depth lies within `tolerance` (relative) of the depth at `quantile`
    /// of the pixel's depths are kept. Works while the background is seen in at least
    /// `1 − quantile` of the frames, where a plain median needs half.
    FarMedian {
        /// Quantile of the sample depths that defines the far surface.
        quantile: f32,
        /// Relative depth tolerance around it.
        tolerance: f32,
    },
}

impl Default for ReconstructParams {
    fn default() -> Self {
        Self {
            radius: 15,
            step: 3,
            splat: SplatParams::new(Mode::Paper),
            statistic: Statistic::FarMedian {
                quantile: 0.9,
                tolerance: 0.05,
            },
            refine_iterations: 0,
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

/// Per-pixel colour and depth from the samples `(r, g, b, z)` (z = 0: no depth).
fn combine(samples: &mut [[f32; 4]], stat: &Statistic, scratch: &mut Vec<f32>) -> ([u8; 3], f32) {
    let median_of = |scratch: &mut Vec<f32>, vals: &mut dyn Iterator<Item = f32>| -> f32 {
        scratch.clear();
        scratch.extend(vals);
        if scratch.is_empty() {
            return 0.0;
        }
        let mid = scratch.len() / 2;
        *scratch.select_nth_unstable_by(mid, f32::total_cmp).1
    };
    // Which samples count: all of them, or those on the far surface.
    let mut keep_far = None;
    if let Statistic::FarMedian {
        quantile,
        tolerance,
    } = *stat
    {
        scratch.clear();
        scratch.extend(samples.iter().map(|s| s[3]).filter(|&z| z > 0.0));
        if !scratch.is_empty() {
            let k = ((quantile.clamp(0.0, 1.0) * (scratch.len() - 1) as f32).round() as usize)
                .min(scratch.len() - 1);
            let z_ref = *scratch.select_nth_unstable_by(k, f32::total_cmp).1;
            keep_far = Some((z_ref * (1.0 - tolerance), z_ref * (1.0 + tolerance)));
        }
    }
    let kept = |s: &[f32; 4]| match keep_far {
        Some((lo, hi)) => s[3] >= lo && s[3] <= hi,
        None => true,
    };
    let mut col = [0u8; 3];
    for (c, out) in col.iter_mut().enumerate() {
        let v = median_of(
            scratch,
            &mut samples.iter().filter(|s| kept(s)).map(|s| s[c]),
        );
        *out = v.round().clamp(0.0, 255.0) as u8;
    }
    let z = median_of(
        scratch,
        &mut samples
            .iter()
            .filter(|s| kept(s))
            .map(|s| s[3])
            .filter(|&z| z > 0.0),
    );
    (col, z)
}

/// Reconstructs the static background of the target frame (`rgb`, `depth`) from `sources`.
/// With `flow` and `params.refine_iterations > 0`, each source pose is first refined
/// ([`crate::align::refine_rotation`]).
pub fn reconstruct_background(
    rgb: &RgbImage,
    depth: &FloatImage,
    sources: &[Source],
    cam: &PinholeCamera,
    params: &ReconstructParams,
    flow: Option<&dyn FlowProvider>,
) -> Result<Background, MotionError> {
    let size = (cam.width, cam.height);
    check_size("background target image", size, rgb.dimensions())?;
    check_size("background target depth", size, depth.dimensions())?;
    let gray = crate::gray::to_gray(rgb);
    let warped = sources
        .par_iter()
        .map(|s| {
            let t_ts = match flow {
                Some(f) if params.refine_iterations > 0 => crate::align::refine_rotation(
                    &gray,
                    s.rgb,
                    s.depth,
                    &s.t_ts,
                    cam,
                    &params.splat,
                    f,
                    params.refine_iterations,
                )?,
                _ => s.t_ts,
            };
            splat(s.rgb, s.depth, &t_ts, cam, &params.splat)
        })
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
            let mut buf: Vec<[f32; 4]> = Vec::with_capacity(warped.len() + 1);
            let mut scratch = Vec::with_capacity(warped.len() + 1);
            for x in 0..w {
                let i = y * w + x;
                buf.clear();
                let p = rgb.as_raw();
                buf.push([
                    p[3 * i] as f32,
                    p[3 * i + 1] as f32,
                    p[3 * i + 2] as f32,
                    depth.as_raw()[i].max(0.0),
                ]);
                for wp in &warped {
                    if wp.holes[i] {
                        continue;
                    }
                    let q = wp.image.as_raw();
                    buf.push([
                        q[3 * i] as f32,
                        q[3 * i + 1] as f32,
                        q[3 * i + 2] as f32,
                        wp.depth.as_raw()[i],
                    ]);
                }
                let (c, z) = combine(&mut buf, &params.statistic, &mut scratch);
                cols.push(c);
                zs.push(z);
                ns.push(buf.len().min(255) as u8);
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
    use crate::testutil::{Scene, small_camera, small_distorted_camera};
    use dynapix_geometry::se3;
    use nalgebra::Vector6;

    /// Every frame but `c` as a source, posed relative to frame `c` (`frames`: image, depth,
    /// `T_wc`).
    fn neighbour_sources(frames: &[(RgbImage, FloatImage, Se3)], c: usize) -> Vec<Source<'_>> {
        let t_cw = frames[c].2.inverse();
        frames
            .iter()
            .enumerate()
            .filter(|&(k, _)| k != c)
            .map(|(_, f)| Source {
                rgb: &f.0,
                depth: &f.1,
                t_ts: t_cw * f.2,
            })
            .collect()
    }

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
        let sources = neighbour_sources(&frames, c);
        let bg = reconstruct_background(
            &frames[c].0,
            &frames[c].1,
            &sources,
            &cam,
            &ReconstructParams::default(),
            None,
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
    fn a_distorted_camera_is_reconstructed_through_its_lens() {
        let cam = small_distorted_camera();
        let mut ideal = cam.clone();
        ideal.dist = [0.0; 5];
        let scene = Scene::default();
        // The camera slides and turns one way while the panel crosses the view; only later
        // frames are sources, so the pinhole model's errors do not cancel in the median.
        let frames: Vec<_> = (0..6)
            .map(|k| {
                let s = k as f64;
                let t = se3::exp(&Vector6::new(0.0, 0.02 * s, 0.0, 0.04 * s, 0.0, 0.0));
                let (rgb, d) = scene.render(&cam, &t, true, 0.1 * s);
                (rgb, d, t)
            })
            .collect();
        let sources = neighbour_sources(&frames, 0);
        let (truth, _) = scene.render(&cam, &frames[0].2, false, 0.0);
        let mover: Vec<bool> = frames[0].1.iter().map(|z| (z - 1.5).abs() < 1e-3).collect();
        let errors = |cam: &PinholeCamera| {
            let p = ReconstructParams::default();
            let bg = reconstruct_background(&frames[0].0, &frames[0].1, &sources, cam, &p, None)
                .unwrap();
            let (mut all, mut behind) = (0.0, 0.0);
            for ((a, b), &m) in bg.image.pixels().zip(truth.pixels()).zip(&mover) {
                let e = (a.0[1] as f64 - b.0[1] as f64).abs();
                all += e;
                if m {
                    behind += e;
                }
            }
            let n_mover = mover.iter().filter(|&&m| m).count() as f64;
            (all / mover.len() as f64, behind / n_mover)
        };
        let (lens, pinhole) = (errors(&cam), errors(&ideal));
        // Mean absolute error over the image and behind the mover: (1.43, 1.00) through the
        // lens against (2.74, 1.46) with the pinhole model when this test was written.
        assert!(
            lens.0 < 0.7 * pinhole.0 && lens.1 < pinhole.1 && lens.1 < 1.5,
            "lens {lens:?}, pinhole {pinhole:?}"
        );
    }

    #[test]
    fn far_median_survives_a_slow_mover_that_defeats_the_median() {
        let cam = small_camera();
        let scene = Scene::default();
        // The panel moves 3 cm per frame and the camera 2 cm the other way: most pixels of the
        // panel see the box behind it in only 1 to 5 of the 10 neighbours.
        let frames: Vec<_> = (0..11)
            .map(|k| {
                let t = Se3::translation(0.1 - 0.02 * k as f64, 0.0, 0.0);
                let (rgb, d) = scene.render(&cam, &t, true, -0.35 + 0.03 * k as f64);
                (rgb, d, t)
            })
            .collect();
        let c = 5;
        let t_wc = frames[c].2;
        let sources = neighbour_sources(&frames, c);
        let (truth, _) = scene.render(&cam, &t_wc, false, 0.0);
        let mover: Vec<bool> = frames[c].1.iter().map(|z| (z - 1.5).abs() < 1e-3).collect();
        let run = |statistic: Statistic| {
            let p = ReconstructParams {
                statistic,
                ..Default::default()
            };
            let bg = reconstruct_background(&frames[c].0, &frames[c].1, &sources, &cam, &p, None)
                .unwrap();
            psnr_masked(&bg.image, &truth, &mover).unwrap()
        };
        let median = run(Statistic::Median);
        let far = run(ReconstructParams::default().statistic);
        assert!(
            far > median + 3.0,
            "median {median} dB, far median {far} dB"
        );
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
