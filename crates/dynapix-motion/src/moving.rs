//! Moving term M (paper §3.1 "Flow Differencing", Eq. 6-7; reference `compute_motion` and
//! `flow_to_gray`, spec §1.7): each neighbour frame and its background are splatted into the
//! current view, the flows current→warped are computed for both pairs, and
//! `F* = min(‖F_d − F_s‖, ‖F_d‖)` keeps only motion that the static background does not
//! explain. The per-neighbour values are then mapped to [0, 1]:
//! - `Mode::Reference`: averaged over the neighbours, then clipped to `[a, b]` px and rescaled
//!   (TUM [1, 4], GRADE [0.5, 2.5]);
//! - `Mode::Paper`: holes of either warp are left out; each pair is low-pass filtered
//!   (a masked Gaussian) and min-max normalised (robust extremes, with a floor on the range so a
//!   frame without motion does not blow its noise up to 1), then averaged over the neighbours
//!   that see the pixel. In the warped images holes are filled with the current image so that
//!   their borders do not create spurious flow.

use dynapix_flow::{FlowField, FlowProvider};
use dynapix_geometry::{PinholeCamera, Se3};
use image::{GrayImage, RgbImage};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

pub use crate::gray::to_gray;
use crate::splat::{SplatParams, Warped, splat};
use crate::{FloatImage, Mode, MotionError, Variant, check_size};

/// The images of one frame that the motion computation needs.
#[derive(Clone, Copy, Debug)]
pub struct FrameImages<'a> {
    /// Dynamic colour image.
    pub rgb: &'a RgbImage,
    /// Dynamic depth, metres (0 = invalid).
    pub depth: &'a FloatImage,
    /// Static background colour image.
    pub background: &'a RgbImage,
    /// Depth of the static background, metres (the dynamic depth when none is known, as the
    /// reference does on TUM).
    pub background_depth: &'a FloatImage,
}

/// A neighbour frame and its pose relative to the current frame.
#[derive(Clone, Copy, Debug)]
pub struct Neighbour<'a> {
    /// The neighbour's images.
    pub frame: FrameImages<'a>,
    /// Maps neighbour-camera points into the current camera: `T_cn = T_wc⁻¹ · T_wn`.
    pub t_cn: Se3,
}

/// Parameters of the moving term. `Default` = TUM constants, paper mode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct MovingParams {
    /// Reference or paper behaviour.
    pub mode: Mode,
    /// Reference clip `[a, b]` in pixels.
    pub clip: [f32; 2],
    /// Paper: standard deviation (pixels) of the Gaussian low-pass on F*.
    pub lowpass_sigma: f32,
    /// Paper: fraction of pixels whose mean forms the robust min and max of the normalisation.
    pub norm_fraction: f64,
    /// Paper: the normalisation divides by at least this range (pixels), so a frame whose
    /// largest motion is tiny keeps small values.
    pub min_range: f32,
    /// Rotation-refinement iterations of each neighbour's relative pose before splatting
    /// ([`crate::align::refine_rotation`]); 0 trusts the poses (reference behaviour).
    pub refine_iterations: usize,
}

impl Default for MovingParams {
    fn default() -> Self {
        Self::new(Variant::Tum, Mode::Paper)
    }
}

impl MovingParams {
    /// Constants of `variant` in `mode`.
    pub fn new(variant: Variant, mode: Mode) -> Self {
        let clip = match variant {
            Variant::Tum => [1.0, 4.0],
            Variant::Grade => [0.5, 2.5],
        };
        Self {
            mode,
            clip,
            lowpass_sigma: 2.0,
            norm_fraction: 0.01,
            min_range: clip[1],
            refine_iterations: 0,
        }
    }
}

/// Grey level of a warped image with its holes replaced by `fill`.
fn to_gray_filled(w: &Warped, fill: &RgbImage) -> GrayImage {
    let mut img = w.image.clone();
    for ((p, f), &hole) in img.pixels_mut().zip(fill.pixels()).zip(&w.holes) {
        if hole {
            *p = *f;
        }
    }
    to_gray(&img)
}

/// Per-pixel `min(‖F_d − F_s‖, ‖F_d‖)`.
pub fn flow_difference(fd: &FlowField, fs: &FlowField) -> Result<Vec<f32>, MotionError> {
    check_size(
        "background flow",
        (fd.width, fd.height),
        (fs.width, fs.height),
    )?;
    Ok(fd
        .data
        .iter()
        .zip(&fs.data)
        .map(|(d, s)| {
            let diff = ((d[0] - s[0]).powi(2) + (d[1] - s[1]).powi(2)).sqrt();
            let mag = (d[0] * d[0] + d[1] * d[1]).sqrt();
            diff.min(mag)
        })
        .collect())
}

/// Gaussian blur of `values` counting only `valid` pixels (normalised convolution); invalid
/// pixels keep 0.
pub fn masked_blur(values: &[f32], valid: &[bool], w: usize, h: usize, sigma: f32) -> Vec<f32> {
    if sigma <= 0.0 {
        return values
            .iter()
            .zip(valid)
            .map(|(&v, &ok)| if ok { v } else { 0.0 })
            .collect();
    }
    let radius = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f32> = (-radius..=radius)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let mut num: Vec<f32> = values
        .iter()
        .zip(valid)
        .map(|(&v, &ok)| if ok { v } else { 0.0 })
        .collect();
    let mut den: Vec<f32> = valid.iter().map(|&ok| ok as u8 as f32).collect();
    for pass in 0..2 {
        let (len, n_lines) = if pass == 0 { (w, h) } else { (h, w) };
        let idx = |line: usize, i: usize| {
            if pass == 0 {
                line * w + i
            } else {
                i * w + line
            }
        };
        let mut buf_n = vec![0.0f32; len];
        let mut buf_d = vec![0.0f32; len];
        for line in 0..n_lines {
            for i in 0..len {
                let (mut sn, mut sd) = (0.0, 0.0);
                for (k, &kv) in kernel.iter().enumerate() {
                    let j = i as isize + k as isize - radius;
                    if j < 0 || j >= len as isize {
                        continue;
                    }
                    let t = idx(line, j as usize);
                    sn += kv * num[t];
                    sd += kv * den[t];
                }
                buf_n[i] = sn;
                buf_d[i] = sd;
            }
            for i in 0..len {
                let t = idx(line, i);
                num[t] = buf_n[i];
                den[t] = buf_d[i];
            }
        }
    }
    num.iter()
        .zip(&den)
        .zip(valid)
        .map(|((&n, &d), &ok)| if ok && d > 0.0 { n / d } else { 0.0 })
        .collect()
}

/// Robust min-max normalisation over the valid pixels: `(v − lo)/max(hi − lo, min_range)`.
fn normalise(values: &[f32], valid: &[bool], params: &MovingParams) -> Vec<f32> {
    let mut vals: Vec<f32> = values
        .iter()
        .zip(valid)
        .filter(|&(_, &ok)| ok)
        .map(|(&v, _)| v)
        .collect();
    if vals.is_empty() {
        return vec![0.0; values.len()];
    }
    let n = vals.len();
    let k = ((params.norm_fraction * n as f64) as usize).clamp(1, n);
    let (lower, pivot, _) = vals.select_nth_unstable_by(k - 1, f32::total_cmp);
    let lo = (lower.iter().map(|&v| v as f64).sum::<f64>() + *pivot as f64) / k as f64;
    let (_, pivot, upper) = vals.select_nth_unstable_by(n - k, f32::total_cmp);
    let hi = (upper.iter().map(|&v| v as f64).sum::<f64>() + *pivot as f64) / k as f64;
    let range = ((hi - lo) as f32).max(params.min_range).max(f32::EPSILON);
    let lo = lo as f32;
    values
        .iter()
        .zip(valid)
        .map(|(&v, &ok)| {
            if ok {
                ((v - lo) / range).clamp(0.0, 1.0)
            } else {
                0.0
            }
        })
        .collect()
}

/// One neighbour's raw differenced flow and the pixels where it is meaningful.
struct PairResult {
    r: Vec<f32>,
    valid: Vec<bool>,
}

/// What every neighbour pair shares.
struct PairContext<'a> {
    cur: &'a FrameImages<'a>,
    cur_gray: &'a GrayImage,
    bg_gray: &'a GrayImage,
    cam: &'a PinholeCamera,
    splat_params: &'a SplatParams,
    flow: &'a dyn FlowProvider,
    mode: Mode,
    refine_iterations: usize,
}

fn pair(ctx: &PairContext, nb: &Neighbour) -> Result<PairResult, MotionError> {
    let PairContext {
        cur,
        cur_gray,
        bg_gray,
        cam,
        splat_params,
        flow,
        mode,
        refine_iterations,
    } = *ctx;
    let t_cn = if refine_iterations > 0 {
        crate::align::refine_rotation(
            cur_gray,
            nb.frame.rgb,
            nb.frame.depth,
            &nb.t_cn,
            cam,
            splat_params,
            flow,
            refine_iterations,
        )?
    } else {
        nb.t_cn
    };
    let (wd, wb) = rayon::join(
        || {
            let _stage = tracing::info_span!(target: "dynapix::stage", "paper: splat").entered();
            splat(nb.frame.rgb, nb.frame.depth, &t_cn, cam, splat_params)
        },
        || {
            let _stage = tracing::info_span!(target: "dynapix::stage", "paper: splat").entered();
            splat(
                nb.frame.background,
                nb.frame.background_depth,
                &t_cn,
                cam,
                splat_params,
            )
        },
    );
    let (wd, wb) = (wd?, wb?);
    let (gd, gb) = match mode {
        Mode::Reference => (to_gray(&wd.image), to_gray(&wb.image)),
        Mode::Paper => (
            to_gray_filled(&wd, cur.rgb),
            to_gray_filled(&wb, cur.background),
        ),
    };
    let (fd, fs) = rayon::join(
        || {
            let _stage = tracing::info_span!(target: "dynapix::stage", "paper: flow").entered();
            flow.flow(cur_gray, &gd)
        },
        || {
            let _stage = tracing::info_span!(target: "dynapix::stage", "paper: flow").entered();
            flow.flow(bg_gray, &gb)
        },
    );
    let r = flow_difference(&fd?, &fs?)?;
    let valid = match mode {
        Mode::Reference => vec![true; r.len()],
        Mode::Paper => wd
            .holes
            .iter()
            .zip(&wb.holes)
            .map(|(a, b)| !a && !b)
            .collect(),
    };
    Ok(PairResult { r, valid })
}

/// Computes the moving term M ∈ [0, 1] of `cur` from its `neighbours`. With no neighbour,
/// M = 0 (nothing can be said to move).
pub fn moving_term(
    cur: &FrameImages,
    neighbours: &[Neighbour],
    cam: &PinholeCamera,
    splat_params: &SplatParams,
    flow: &dyn FlowProvider,
    params: &MovingParams,
) -> Result<FloatImage, MotionError> {
    let size = (cam.width, cam.height);
    check_size("current image", size, cur.rgb.dimensions())?;
    check_size("current background", size, cur.background.dimensions())?;
    let (w, h) = (cam.width as usize, cam.height as usize);
    if params.clip[1].partial_cmp(&params.clip[0]) != Some(std::cmp::Ordering::Greater) {
        return Err(MotionError::InvalidParam {
            name: "clip",
            message: format!("upper bound must exceed lower bound, got {:?}", params.clip),
        });
    }
    let cur_gray = to_gray(cur.rgb);
    let bg_gray = to_gray(cur.background);
    let ctx = PairContext {
        cur,
        cur_gray: &cur_gray,
        bg_gray: &bg_gray,
        cam,
        splat_params,
        flow,
        mode: params.mode,
        refine_iterations: params.refine_iterations,
    };
    let pairs: Vec<PairResult> = neighbours
        .par_iter()
        .map(|nb| pair(&ctx, nb))
        .collect::<Result<_, _>>()?;
    let mut m = FloatImage::new(cam.width, cam.height);
    if pairs.is_empty() {
        return Ok(m);
    }
    match params.mode {
        Mode::Reference => {
            let [a, b] = params.clip;
            let inv = 1.0 / pairs.len() as f32;
            for (i, out) in m.iter_mut().enumerate() {
                let r: f32 = pairs.iter().map(|p| p.r[i]).sum::<f32>() * inv;
                *out = (r.clamp(a, b) - a) / (b - a);
            }
        }
        Mode::Paper => {
            let mut sum = vec![0.0f32; w * h];
            let mut cnt = vec![0u32; w * h];
            for p in &pairs {
                let lp = masked_blur(&p.r, &p.valid, w, h, params.lowpass_sigma);
                let nm = normalise(&lp, &p.valid, params);
                for i in 0..w * h {
                    if p.valid[i] {
                        sum[i] += nm[i];
                        cnt[i] += 1;
                    }
                }
            }
            for ((out, s), c) in m.iter_mut().zip(&sum).zip(&cnt) {
                *out = if *c > 0 { s / *c as f32 } else { 0.0 };
            }
        }
    }
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::testutil::{BlockFlow, Scene, small_camera};

    #[test]
    fn flow_difference_takes_the_smaller_magnitude() {
        let mut fd = FlowField::zeros(2, 1);
        let mut fs = FlowField::zeros(2, 1);
        fd.data = vec![[3.0, 4.0], [1.0, 0.0]];
        fs.data = vec![[3.0, 3.0], [-5.0, 0.0]];
        let r = flow_difference(&fd, &fs).unwrap();
        assert_eq!(r, vec![1.0, 1.0]);
    }

    #[test]
    fn masked_blur_ignores_invalid_pixels() {
        let (w, h) = (9, 5);
        let mut v = vec![2.0f32; w * h];
        let mut valid = vec![true; w * h];
        v[2 * w + 4] = 1000.0;
        valid[2 * w + 4] = false;
        let out = masked_blur(&v, &valid, w, h, 1.5);
        for (i, o) in out.iter().enumerate() {
            if valid[i] {
                assert!((o - 2.0).abs() < 1e-4, "{i}: {o}");
            } else {
                assert_eq!(*o, 0.0);
            }
        }
    }

    /// rgb, depth, background, background depth, pose.
    type TestFrame = (RgbImage, FloatImage, RgbImage, FloatImage, Se3);

    fn scene_frames(with_mover: bool) -> (PinholeCamera, Vec<TestFrame>) {
        let cam = small_camera();
        let scene = Scene::default();
        let poses = [
            dynapix_geometry::se3::exp(&nalgebra::Vector6::new(0.0, -0.01, 0.0, -0.04, 0.0, 0.0)),
            Se3::identity(),
            dynapix_geometry::se3::exp(&nalgebra::Vector6::new(0.0, 0.01, 0.0, 0.04, 0.01, 0.0)),
        ];
        let movers = [-0.25, -0.17, -0.09];
        let frames = poses
            .iter()
            .zip(movers)
            .map(|(t, mx)| {
                let (rgb, d) = scene.render(&cam, t, with_mover, mx);
                let (bg, bd) = scene.render(&cam, t, false, 0.0);
                (rgb, d, bg, bd, *t)
            })
            .collect();
        (cam, frames)
    }

    fn run(with_mover: bool, mode: Mode) -> (FloatImage, Vec<bool>) {
        let (cam, f) = scene_frames(with_mover);
        let view = |i: usize| FrameImages {
            rgb: &f[i].0,
            depth: &f[i].1,
            background: &f[i].2,
            background_depth: &f[i].3,
        };
        let t_wc = f[1].4;
        let nbs: Vec<Neighbour> = [0usize, 2]
            .iter()
            .map(|&i| Neighbour {
                frame: view(i),
                t_cn: t_wc.inverse() * f[i].4,
            })
            .collect();
        let flow = BlockFlow { radius: 5, half: 2 };
        let sp = SplatParams::new(mode);
        let m = moving_term(
            &view(1),
            &nbs,
            &cam,
            &sp,
            &flow,
            &MovingParams::new(Variant::Tum, mode),
        )
        .unwrap();
        // Ground-truth mover mask of the current frame (depth of the mover panel is 1.5 m).
        let mask = f[1]
            .1
            .pixels()
            .map(|z| (z.0[0] - 1.5).abs() < 1e-3)
            .collect();
        (m, mask)
    }

    #[test]
    fn static_scene_with_camera_motion_gives_no_motion() {
        for mode in [Mode::Reference, Mode::Paper] {
            let (m, _) = run(false, mode);
            let n = m.len();
            // Stay away from the image border, where the neighbours' views do not reach.
            let (w, h) = (m.width(), m.height());
            let mut high = 0;
            let mut total = 0;
            for y in 6..h - 6 {
                for x in 6..w - 6 {
                    total += 1;
                    if m.get_pixel(x, y).0[0] > 0.2 {
                        high += 1;
                    }
                }
            }
            assert!(
                high * 50 < total,
                "{mode:?}: {high} of {total} (of {n}) above 0.2"
            );
        }
    }

    #[test]
    fn moving_panel_is_found() {
        for mode in [Mode::Reference, Mode::Paper] {
            let (m, mask) = run(true, mode);
            let mean = |want: bool| {
                let v: Vec<f32> = m
                    .iter()
                    .zip(&mask)
                    .filter(|&(_, &k)| k == want)
                    .map(|(&p, _)| p)
                    .collect();
                v.iter().sum::<f32>() / v.len() as f32
            };
            let (inside, outside) = (mean(true), mean(false));
            assert!(
                inside > 0.5 && outside < 0.1,
                "{mode:?}: {inside} vs {outside}"
            );
        }
    }
}
