//! The geometric cue: pixels clearly nearer than the static depth, after an opening and a
//! dilation ([`geometric_term`]), and the cue of one frame of a sequence
//! ([`geometric_frame`]).

use dynapix_geometry::camera::PinholeCamera;
use dynapix_geometry::se3::Se3;

use super::depth::{StaticDepthWorkspace, select_views, static_depth_with, with_thread_workspace};
use super::params::StaticDepthParams;
use super::{DepthView, StaticDepth, WorkingDepth};
use crate::{FloatImage, MotionError, check_size};

/// `op` folded over the `(2r+1)²` square window of every pixel (pixels outside the image are
/// left out), separably, as shifted copies of whole rows and then whole columns, which the
/// compiler vectorises. `op` must be commutative and associative on the values given, so
/// that the visiting order does not matter.
#[inline(always)]
fn window_fold<T: Copy>(v: &[T], w: usize, h: usize, r: usize, op: impl Fn(T, T) -> T) -> Vec<T> {
    if r == 0 || w == 0 || h == 0 {
        return v.to_vec();
    }
    let mut tmp = v.to_vec();
    for (row_in, row_out) in v.chunks_exact(w).zip(tmp.chunks_exact_mut(w)) {
        for d in 1..=r.min(w - 1) {
            for (o, &i) in row_out[d..].iter_mut().zip(&row_in[..w - d]) {
                *o = op(*o, i);
            }
            for (o, &i) in row_out[..w - d].iter_mut().zip(&row_in[d..]) {
                *o = op(*o, i);
            }
        }
    }
    let mut out = tmp.clone();
    for d in 1..=r.min(h - 1) {
        let s = d * w;
        for (o, &i) in out[s..].iter_mut().zip(&tmp[..w * h - s]) {
            *o = op(*o, i);
        }
        for (o, &i) in out[..w * h - s].iter_mut().zip(&tmp[s..]) {
            *o = op(*o, i);
        }
    }
    out
}

/// Minimum over a square window of radius `r`, ignoring `NaN` (NaN where all are NaN).
/// Pixels outside the image are ignored. The values are positive or `NaN`, so the minimum
/// does not depend on the order in which the window is visited.
#[inline(always)]
fn min_filter(v: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    window_fold(v, w, h, r, |a, b| if b < a || a.is_nan() { b } else { a })
}

/// Binary dilation by a `(2r+1)²` square on a working-resolution mask (pixels outside the
/// image are ignored).
#[inline(always)]
fn dilate(mask: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    window_fold(mask, w, h, r, |a, b| a | b)
}

#[inline(always)]
fn erode(mask: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    let inv: Vec<bool> = mask.iter().map(|&m| !m).collect();
    dilate(&inv, w, h, r).into_iter().map(|m| !m).collect()
}

/// The geometric cue at full resolution: 1 where the current depth is nearer than the static
/// depth by more than the tolerance (after an opening, a dilation and spreading into pixels
/// without depth), else 0.
pub fn geometric_term(
    current: &WorkingDepth,
    sd: &StaticDepth,
    params: &StaticDepthParams,
) -> Result<FloatImage, MotionError> {
    let _stage = tracing::info_span!(target: "dynapix::stage", "geometric: term").entered();
    params.validate()?;
    check_size(
        "static depth",
        current.depth.dimensions(),
        sd.depth.dimensions(),
    )?;
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        return Ok(unsafe { geometric_term_avx2(avx2, current, sd, params) });
    }
    Ok(geometric_term_body(current, sd, params))
}

/// [`geometric_term_body`] compiled for AVX2 (the morphology on whole rows; comparisons,
/// minima and booleans only, so the same mask in every build).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn geometric_term_avx2(
    _: dynapix_simd::Avx2,
    current: &WorkingDepth,
    sd: &StaticDepth,
    params: &StaticDepthParams,
) -> FloatImage {
    geometric_term_body(current, sd, params)
}

/// [`geometric_term`] after its checks.
#[inline(always)]
fn geometric_term_body(
    current: &WorkingDepth,
    sd: &StaticDepth,
    params: &StaticDepthParams,
) -> FloatImage {
    let (w, h) = current.depth.dimensions();
    let (wu, hu) = (w as usize, h as usize);
    if wu == 0 || hu == 0 {
        let (fw, fh) = current.full_size;
        return FloatImage::new(fw, fh);
    }
    let z = current.depth.as_raw();
    let s = min_filter(sd.depth.as_raw(), wu, hu, params.align_radius as usize);
    let near: Vec<bool> = z
        .iter()
        .zip(&s)
        .map(|(&z, &s)| z > params.min_depth && s.is_finite() && z < s - params.tol(s))
        .collect();
    let r = params.open_radius as usize;
    let opened = dilate(&erode(&near, wu, hu, r), wu, hu, r);
    let mut mask = dilate(&opened, wu, hu, params.dilate_radius as usize);
    let hole: Vec<bool> = z
        .iter()
        .map(|&z| z.is_nan() || z <= params.min_depth)
        .collect();
    for _ in 0..params.fill_steps {
        let grown = dilate(&mask, wu, hu, 1);
        for ((m, &g), &hole) in mask.iter_mut().zip(&grown).zip(&hole) {
            if hole {
                *m = g;
            }
        }
    }
    // Nearest working pixel of every full-resolution pixel, a row at a time.
    let f = current.factor as usize;
    let (fw, fh) = current.full_size;
    let cols: Vec<usize> = (0..fw as usize).map(|x| (x / f).min(wu - 1)).collect();
    let mut out = Vec::with_capacity(fw as usize * fh as usize);
    for y in 0..fh as usize {
        let row = &mask[(y / f).min(hu - 1) * wu..][..wu];
        out.extend(cols.iter().map(|&i| if row[i] { 1.0f32 } else { 0.0 }));
    }
    FloatImage::from_raw(fw, fh, out).unwrap_or_else(|| FloatImage::new(fw, fh))
}

/// The geometric cue of frame `t` of a sequence: neighbour views chosen by [`select_views`]
/// among frames with a pose, splatted with the relative poses from `poses_wc` (camera-to-world,
/// `None` = unknown). A frame without a pose, or without usable neighbours, gets P = 0.
/// The splats live in a workspace of the calling thread ([`geometric_frame_with`] takes
/// the caller's).
pub fn geometric_frame(
    cam: &PinholeCamera,
    t: usize,
    stamps: &[f64],
    poses_wc: &[Option<Se3>],
    depths: &[WorkingDepth],
    params: &StaticDepthParams,
) -> Result<FloatImage, MotionError> {
    with_thread_workspace(|ws| geometric_frame_with(cam, t, stamps, poses_wc, depths, params, ws))
}

/// [`geometric_frame`] with the splat buffers in the caller's `ws`.
pub fn geometric_frame_with(
    cam: &PinholeCamera,
    t: usize,
    stamps: &[f64],
    poses_wc: &[Option<Se3>],
    depths: &[WorkingDepth],
    params: &StaticDepthParams,
    ws: &mut StaticDepthWorkspace,
) -> Result<FloatImage, MotionError> {
    let (Some(cur), Some(Some(twc))) = (depths.get(t), poses_wc.get(t)) else {
        return Ok(FloatImage::new(cam.width, cam.height));
    };
    let usable = |s: usize| matches!(poses_wc.get(s), Some(Some(_))) && s < depths.len();
    let tcw = twc.inverse();
    let views: Vec<DepthView<'_>> = select_views(stamps, t, usable, params)
        .into_iter()
        .filter_map(|s| {
            Some(DepthView {
                depth: depths.get(s)?,
                t_cs: tcw * (*poses_wc.get(s)?)?,
            })
        })
        .collect();
    if views.is_empty() {
        return Ok(FloatImage::new(cam.width, cam.height));
    }
    let sd = static_depth_with(cam, &views, params, ws)?;
    geometric_term(cur, &sd, params)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::static_depth::{fixtures::*, *};
    use image::Luma;

    #[test]
    fn fast_morphology_equals_its_definition() {
        let mut st = 7u64;
        for (w, h) in [(1, 1), (1, 7), (9, 1), (13, 11), (40, 30)] {
            for r in 0..5 {
                let mask: Vec<bool> = (0..w * h).map(|_| lcg(&mut st).is_multiple_of(5)).collect();
                assert_eq!(
                    dilate(&mask, w, h, r),
                    dilate_naive(&mask, w, h, r),
                    "{w}x{h} r{r}"
                );
                let v: Vec<f32> = (0..w * h)
                    .map(|_| match lcg(&mut st) % 4 {
                        0 => f32::NAN,
                        k => 0.1 + (lcg(&mut st) % 1000) as f32 * 0.01 * k as f32,
                    })
                    .collect();
                let (a, b) = (min_filter(&v, w, h, r), min_filter_naive(&v, w, h, r));
                assert!(same_bits(&a, &b), "{w}x{h} r{r}");
            }
        }
    }

    #[test]
    fn the_geometric_term_is_the_same_in_every_build() {
        let (w, h) = (97, 61);
        let c = cam(w, h);
        let p = params();
        let mut st = 9u64;
        for _ in 0..4 {
            // Two boxes in front of a wall at 3 m, and holes without depth.
            let boxes: Vec<(u32, u32, u32)> = (0..2)
                .map(|_| {
                    (
                        lcg(&mut st) % (w - 16),
                        lcg(&mut st) % (h - 16),
                        6 + lcg(&mut st) % 10,
                    )
                })
                .collect();
            let z = FloatImage::from_fn(w, h, |x, y| {
                let hole = lcg(&mut st).is_multiple_of(20);
                let in_box = boxes
                    .iter()
                    .any(|&(bx, by, s)| (bx..bx + s).contains(&x) && (by..by + s).contains(&y));
                Luma([if hole {
                    0.0
                } else if in_box {
                    1.0
                } else {
                    3.0
                }])
            });
            let cur = WorkingDepth::new(&z, &p);
            let walls = [
                wall(w, h, 3.0, None),
                wall(w, h, 3.0, None),
                wall(w, h, 3.0, None),
            ];
            let working: Vec<WorkingDepth> =
                walls.iter().map(|d| WorkingDepth::new(d, &p)).collect();
            let sd = static_depth(&c, &same_pose_views(&working), &p).unwrap();
            let fast = geometric_term(&cur, &sd, &p).unwrap();
            let base = geometric_term_body(&cur, &sd, &p);
            assert_eq!(fast.as_raw(), base.as_raw());
            assert!(fast.iter().any(|&v| v > 0.0) && fast.contains(&0.0));
        }
    }

    #[test]
    fn a_box_that_moved_away_is_near_and_the_wall_is_not() {
        let (w, h) = (80, 60);
        let c = cam(w, h);
        let p = params();
        // The current frame sees a box at 1 m in front of a wall at 3 m; neighbours (the
        // same camera pose) see only the wall: the box is near, the wall is static.
        let cur = WorkingDepth::new(&wall(w, h, 3.0, Some((20, 20, 40, 40, 1.0))), &p);
        let nb: Vec<WorkingDepth> = (0..4)
            .map(|_| WorkingDepth::new(&wall(w, h, 3.0, None), &p))
            .collect();
        let views = same_pose_views(&nb);
        let sd = static_depth(&c, &views, &p).unwrap();
        assert!((sd.depth.get_pixel(5, 5).0[0] - 3.0).abs() < 1e-4);
        let g = geometric_term(&cur, &sd, &p).unwrap();
        assert_eq!(g.get_pixel(30, 30).0[0], 1.0);
        assert_eq!(g.get_pixel(5, 5).0[0], 0.0);
        assert_eq!(g.get_pixel(75, 55).0[0], 0.0);
        // The dilation covers the silhouette, but not far beyond it.
        assert_eq!(g.get_pixel(18, 30).0[0], 1.0);
        assert_eq!(g.get_pixel(10, 30).0[0], 0.0);
    }

    #[test]
    fn a_box_present_in_every_view_is_static() {
        let (w, h) = (80, 60);
        let c = cam(w, h);
        let p = params();
        let d = wall(w, h, 3.0, Some((20, 20, 40, 40, 1.0)));
        let cur = WorkingDepth::new(&d, &p);
        let nb: Vec<WorkingDepth> = (0..4).map(|_| WorkingDepth::new(&d, &p)).collect();
        let views = same_pose_views(&nb);
        let sd = static_depth(&c, &views, &p).unwrap();
        let g = geometric_term(&cur, &sd, &p).unwrap();
        assert!(g.as_raw().iter().all(|&v| v == 0.0));
    }
}
