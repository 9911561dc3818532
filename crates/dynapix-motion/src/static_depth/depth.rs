//! The static depth of a view ([`static_depth`]): the neighbour views are splatted, then
//! each row is sorted across the views and scanned for the farthest supported depth; and
//! the choice of the views ([`select_views`]).

use dynapix_geometry::camera::PinholeCamera;
use rayon::prelude::*;

use super::network::{LANES, network_24_ymm, sort_lanes, sorting_network_for};
use super::params::StaticDepthParams;
use super::splat::{Rays, splat_nearest};
use super::support::farthest_supported_lanes;
use super::{DepthView, StaticDepth};
use crate::{FloatImage, MotionError, check_size, pixel_rays};

/// Buffers of [`static_depth_with`], kept by the caller between frames: a sequence splats
/// 24 views of the same size for every frame, and fresh buffers of that size come from the
/// operating system zeroed, page by page, every time. The contents never leak into a result
/// (every buffer is refilled before it is read).
#[derive(Debug, Default)]
pub struct StaticDepthWorkspace {
    /// One splat (working-resolution depth, +∞ = no surface) per view.
    splats: Vec<Vec<f32>>,
}

impl StaticDepthWorkspace {
    /// An empty workspace; its buffers grow on first use.
    pub fn new() -> Self {
        Self::default()
    }
}

/// Runs `f` with the calling thread's workspace, kept between calls for callers that do not
/// hold one. A nested call on the same thread (rayon may run another task while this one
/// waits) finds the workspace taken and gets a fresh one, so it never blocks or fails; a
/// result does not depend on which buffers it used.
pub(super) fn with_thread_workspace<R>(f: impl FnOnce(&mut StaticDepthWorkspace) -> R) -> R {
    thread_local! {
        static WORKSPACE: std::cell::Cell<StaticDepthWorkspace> =
            std::cell::Cell::new(StaticDepthWorkspace::default());
    }
    let mut ws = WORKSPACE.take();
    let out = f(&mut ws);
    WORKSPACE.set(ws);
    out
}

/// [`static_depth_with`] with a workspace of the calling thread (kept between calls).
pub fn static_depth(
    cam: &PinholeCamera,
    views: &[DepthView<'_>],
    params: &StaticDepthParams,
) -> Result<StaticDepth, MotionError> {
    with_thread_workspace(|ws| static_depth_with(cam, views, params, ws))
}

/// The static depth of the current view from its neighbour `views` (see the module
/// documentation): every view is splatted at working resolution, then per pixel the farthest
/// depth that `min_support` views agree on is kept, refined to the median of those views.
/// The splats live in `ws` (see [`StaticDepthWorkspace`]).
pub fn static_depth_with(
    cam: &PinholeCamera,
    views: &[DepthView<'_>],
    params: &StaticDepthParams,
    ws: &mut StaticDepthWorkspace,
) -> Result<StaticDepth, MotionError> {
    let _stage = tracing::info_span!(target: "dynapix::stage", "geometric: static depth").entered();
    params.validate()?;
    let Some(first) = views.first() else {
        return Err(MotionError::InvalidParam {
            name: "views",
            message: "the static depth needs at least one neighbour view".into(),
        });
    };
    let size = first.depth.depth.dimensions();
    let factor = first.depth.factor;
    for v in views {
        check_size("neighbour depth", size, v.depth.depth.dimensions())?;
        check_size(
            "neighbour depth (input size)",
            first.depth.full_size,
            v.depth.full_size,
        )?;
    }
    check_size("camera", (cam.width, cam.height), first.depth.full_size)?;
    let (w, h) = size;
    let n = (w * h) as usize;
    let rays = Rays::new(cam, factor, w, h);
    let table = pixel_rays(cam);
    if ws.splats.len() < views.len() {
        ws.splats.resize_with(views.len(), Vec::new);
    }
    let splats = &mut ws.splats[..views.len()];
    splats.par_iter_mut().zip(views).for_each(|(out, v)| {
        out.clear();
        out.resize(n, f32::INFINITY);
        splat_nearest(cam, table.as_deref(), &rays, v, out);
    });
    // Per pixel the views' depths are sorted, LANES pixels at a time, by a sorting network
    // over the views (branch-free min/max, vectorised across the pixels), then scanned.
    let rows = splats.len();
    let network = sorting_network_for(rows);
    let wu = w as usize;
    let mut depth = vec![f32::NAN; n];
    depth
        .par_chunks_mut(wu)
        .enumerate()
        .for_each(|(j, row)| static_depth_row(&*splats, &network, params, j, row));
    Ok(StaticDepth {
        depth: FloatImage::from_raw(w, h, depth).unwrap_or_else(|| FloatImage::new(w, h)),
        factor,
    })
}

/// Row `j` of the static depth from the views' `splats` (each `row.len()` pixels wide),
/// sorted by `network`. The default 24 views go straight from the splats into the registers
/// of the fixed network ([`network_24_ymm`]) in a build for AVX-512VL or AVX2, which also
/// compiles the scan; the same operations on the same values, so the same depths (test
/// `rows_of_24_views_equal_the_generic_rows`).
fn static_depth_row(
    splats: &[Vec<f32>],
    network: &[(usize, usize)],
    params: &StaticDepthParams,
    j: usize,
    row: &mut [f32],
) {
    #[cfg(target_arch = "x86_64")]
    if let Ok(splats) = <&[Vec<f32>; 24]>::try_from(splats) {
        if let Some(avx512) = dynapix_simd::Avx512Vl::detect() {
            // SAFETY: the token proves the CPU has AVX-512F and AVX-512VL.
            unsafe { static_depth_row_24_avx512(avx512, splats, params, j, row) };
            return;
        }
        if let Some(avx2) = dynapix_simd::Avx2::detect() {
            // SAFETY: the token proves the CPU has AVX2.
            unsafe { static_depth_row_24_avx2(avx2, splats, params, j, row) };
            return;
        }
    }
    static_depth_row_any(splats, network, params, j, row);
}

/// [`static_depth_row`] for any number of views and any CPU: each block of [`LANES`] pixels
/// is copied out of the splats, sorted by [`sort_lanes`] and scanned.
fn static_depth_row_any(
    splats: &[Vec<f32>],
    network: &[(usize, usize)],
    params: &StaticDepthParams,
    j: usize,
    row: &mut [f32],
) {
    let wu = row.len();
    let mut cols = vec![[f32::INFINITY; LANES]; splats.len()];
    for i0 in (0..wu).step_by(LANES) {
        let m = LANES.min(wu - i0);
        gather_block(splats, j * wu + i0, m, &mut cols);
        sort_lanes(&mut cols, network);
        let lanes = farthest_supported_lanes(&cols, params);
        row[i0..i0 + m].copy_from_slice(&lanes[..m]);
    }
}

/// Pixels `k0 .. k0 + m` (`m ≤ LANES`) of every splat into the rows of `cols`, the lanes
/// past `m` filled with +∞ (no surface).
#[inline(always)]
fn gather_block(splats: &[Vec<f32>], k0: usize, m: usize, cols: &mut [[f32; LANES]]) {
    for (c, s) in cols.iter_mut().zip(splats) {
        match s
            .get(k0..k0 + LANES)
            .and_then(|v| <&[f32; LANES]>::try_from(v).ok())
        {
            // A whole block: a fixed-size copy, inlined instead of a `memmove` call.
            Some(v) if m == LANES => *c = *v,
            _ => {
                let end = (k0 + m).min(s.len());
                let got = end.saturating_sub(k0);
                c[..got].copy_from_slice(&s[k0.min(end)..end]);
                c[got..].fill(f32::INFINITY);
            }
        }
    }
}

/// [`static_depth_row_24`] compiled for AVX-512VL (the 24 rows fit in its 32 registers).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl")]
fn static_depth_row_24_avx512(
    avx512: dynapix_simd::Avx512Vl,
    splats: &[Vec<f32>; 24],
    params: &StaticDepthParams,
    j: usize,
    row: &mut [f32],
) {
    static_depth_row_24(avx512.avx2(), splats, params, j, row);
}

/// [`static_depth_row_24`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn static_depth_row_24_avx2(
    avx2: dynapix_simd::Avx2,
    splats: &[Vec<f32>; 24],
    params: &StaticDepthParams,
    j: usize,
    row: &mut [f32],
) {
    static_depth_row_24(avx2, splats, params, j, row);
}

/// [`static_depth_row_any`] for 24 views: whole blocks are loaded from the splats straight
/// into the registers of the fixed network. Inlined into the kernels above, so compiled
/// with their instruction set; the token proves that the AVX intrinsics may run (it cannot
/// carry `#[target_feature]` itself: that excludes `#[inline(always)]`).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn static_depth_row_24(
    avx2: dynapix_simd::Avx2,
    splats: &[Vec<f32>; 24],
    params: &StaticDepthParams,
    j: usize,
    row: &mut [f32],
) {
    use std::arch::x86_64::{__m256, _mm256_loadu_ps, _mm256_storeu_ps};
    let wu = row.len();
    let end = (j + 1) * wu;
    let whole_rows = splats.iter().all(|s| s.len() >= end);
    let mut cols = [[f32::INFINITY; LANES]; 24];
    for i0 in (0..wu).step_by(LANES) {
        let m = LANES.min(wu - i0);
        let k0 = j * wu + i0;
        let mut v: [__m256; 24] = if m == LANES && whole_rows {
            // SAFETY: the token proves the CPU has AVX; k0 + LANES ≤ end ≤ every splat's
            // length, checked above.
            std::array::from_fn(|r| unsafe { _mm256_loadu_ps(splats[r].as_ptr().add(k0)) })
        } else {
            gather_block(splats, k0, m, &mut cols);
            // SAFETY: the token proves the CPU has AVX; each row holds LANES `f32`.
            cols.map(|c| unsafe { _mm256_loadu_ps(c.as_ptr()) })
        };
        network_24_ymm(avx2, &mut v);
        for (c, x) in cols.iter_mut().zip(v) {
            // SAFETY: the token proves the CPU has AVX; each row holds LANES `f32`.
            unsafe { _mm256_storeu_ps(c.as_mut_ptr(), x) };
        }
        let lanes = farthest_supported_lanes(&cols, params);
        row[i0..i0 + m].copy_from_slice(&lanes[..m]);
    }
}

/// Indices of the neighbour views of frame `t` among frames with timestamps `stamps`: frames
/// within `window_s` seconds (not `t` itself) for which `usable` holds, at most `max_views`
/// of them, spread evenly.
pub fn select_views(
    stamps: &[f64],
    t: usize,
    usable: impl Fn(usize) -> bool,
    params: &StaticDepthParams,
) -> Vec<usize> {
    let Some(&tt) = stamps.get(t) else {
        return Vec::new();
    };
    let cands: Vec<usize> = (0..stamps.len())
        .filter(|&s| s != t && (stamps[s] - tt).abs() <= params.window_s && usable(s))
        .collect();
    if cands.len() <= params.max_views {
        return cands;
    }
    let m = params.max_views;
    (0..m)
        .map(|k| cands[(k * (cands.len() - 1)) / (m - 1).max(1)])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::static_depth::{fixtures::*, *};
    use dynapix_geometry::se3::Se3;
    use dynapix_geometry::se3::exp;
    use image::Luma;
    use nalgebra::Vector6;

    #[test]
    fn rows_of_24_views_equal_the_generic_rows() {
        let params = StaticDepthParams::default();
        let net = sorting_network_for(24);
        let mut st = 3u64;
        // A width that is not a multiple of the block, and values that agree within the
        // tolerance, some not; no surface (+∞) here and there.
        let (w, h) = (43usize, 60usize);
        let splats: Vec<Vec<f32>> = (0..24)
            .map(|_| {
                (0..w * h)
                    .map(|_| match lcg(&mut st) % 7 {
                        0 => f32::INFINITY,
                        k => 1.0 + (lcg(&mut st) % 60) as f32 * 0.01 * k as f32,
                    })
                    .collect()
            })
            .collect();
        let bits = |r: &[f32]| -> Vec<u32> { r.iter().map(|v| v.to_bits()).collect() };
        for j in 0..h {
            let mut want = vec![0f32; w];
            static_depth_row_any(&splats, &net, &params, j, &mut want);
            assert!(want.iter().any(|v| v.is_finite()) && want.iter().any(|v| v.is_nan()));
            let mut got = vec![0f32; w];
            static_depth_row(&splats, &net, &params, j, &mut got);
            assert_eq!(bits(&got), bits(&want), "row {j}");
            #[cfg(target_arch = "x86_64")]
            {
                let s24 = <&[Vec<f32>; 24]>::try_from(&splats[..]).unwrap();
                if let Some(avx512) = dynapix_simd::Avx512Vl::detect() {
                    // SAFETY: the token proves the CPU has AVX-512F and AVX-512VL.
                    unsafe { static_depth_row_24_avx512(avx512, s24, &params, j, &mut got) };
                    assert_eq!(bits(&got), bits(&want), "avx512 row {j}");
                }
                if let Some(avx2) = dynapix_simd::Avx2::detect() {
                    // SAFETY: the token proves the CPU has AVX2.
                    unsafe { static_depth_row_24_avx2(avx2, s24, &params, j, &mut got) };
                    assert_eq!(bits(&got), bits(&want), "avx2 row {j}");
                }
            }
        }
    }

    #[test]
    fn moved_views_are_splatted_with_their_pose() {
        // A wall at 2 m seen from cameras shifted sideways: with the right relative poses the
        // static depth is the wall everywhere the views overlap; with identity poses and a
        // tilted wall it would not be.
        let (w, h) = (80, 60);
        let c = cam(w, h);
        let p = params();
        // Slanted plane z = 2 + 0.5·X in the current camera.
        let plane = |t: &Se3| {
            let inv = t.inverse();
            FloatImage::from_fn(w, h, |x, y| {
                // Ray in the neighbour camera; intersect with the plane expressed there.
                let r = [(x as f64 - c.cx) / c.fx, (y as f64 - c.cy) / c.fy];
                // Solve for depth s: point q = s·(r,1) in neighbour; in current: p = T·q.
                let dir = t.rotation * nalgebra::Vector3::new(r[0], r[1], 1.0);
                let o = t.translation.vector;
                // p.z = 2 + 0.5 p.x  →  o.z + s dir.z = 2 + 0.5 (o.x + s dir.x)
                let s = (2.0 + 0.5 * o.x - o.z) / (dir.z - 0.5 * dir.x);
                let _ = inv;
                Luma([s as f32])
            })
        };
        let poses: Vec<Se3> = [-0.1, -0.05, 0.05, 0.1]
            .iter()
            .map(|&dx| exp(&Vector6::new(0.0, 0.02, 0.0, dx, 0.0, 0.0)))
            .collect();
        let nb: Vec<WorkingDepth> = poses
            .iter()
            .map(|t| WorkingDepth::new(&plane(t), &p))
            .collect();
        let views: Vec<DepthView> = nb
            .iter()
            .zip(&poses)
            .map(|(d, t)| DepthView { depth: d, t_cs: *t })
            .collect();
        let sd = static_depth(&c, &views, &p).unwrap();
        let cur = WorkingDepth::new(&plane(&Se3::identity()), &p);
        let mut checked = 0;
        for j in 10..50 {
            for i in 20..60 {
                let s = sd.depth.get_pixel(i, j).0[0];
                let z = cur.depth.get_pixel(i, j).0[0];
                if s.is_finite() {
                    assert!((s - z).abs() < 0.02, "({i},{j}) static {s} vs {z}");
                    checked += 1;
                }
            }
        }
        assert!(checked > 1000, "{checked}");
        let g = geometric_term(&cur, &sd, &p).unwrap();
        assert!(g.as_raw().iter().all(|&v| v == 0.0));
    }

    #[test]
    fn views_are_chosen_evenly_inside_the_window() {
        let stamps: Vec<f64> = (0..300).map(|k| k as f64 / 30.0).collect();
        let p = StaticDepthParams::default();
        let v = select_views(&stamps, 150, |_| true, &p);
        assert_eq!(v.len(), 24);
        assert!(
            v.iter()
                .all(|&s| s != 150 && (stamps[s] - 5.0).abs() <= 2.0)
        );
        assert_eq!(v[0], 90);
        assert_eq!(*v.last().unwrap(), 210);
        let v = select_views(&stamps, 0, |s| s % 2 == 0, &p);
        assert!(v.iter().all(|&s| s % 2 == 0 && s > 0 && s <= 60));
    }

    #[test]
    fn a_reused_workspace_gives_the_bytes_of_a_fresh_one() {
        // Views of different sizes and counts through one workspace: leftovers of a larger
        // or earlier call never reach a result.
        let p = params();
        let bits = |sd: &StaticDepth| -> Vec<u32> {
            sd.depth.as_raw().iter().map(|v| v.to_bits()).collect()
        };
        let mut ws = StaticDepthWorkspace::new();
        for (k, (w, h)) in [(80u32, 60u32), (64, 48), (80, 60)].into_iter().enumerate() {
            let c = cam(w, h);
            let depths: Vec<WorkingDepth> = (0..[24, 5, 7][k])
                .map(|v| {
                    let block = (v % 3 != 0).then_some((10 + v as u32, 8, 30, 30, 1.0));
                    WorkingDepth::new(&wall(w, h, 2.0 + 0.01 * v as f32, block), &p)
                })
                .collect();
            let views = same_pose_views(&depths);
            let fresh = static_depth_with(&c, &views, &p, &mut StaticDepthWorkspace::new());
            let fresh = fresh.unwrap();
            let reused = static_depth_with(&c, &views, &p, &mut ws).unwrap();
            let threaded = static_depth(&c, &views, &p).unwrap();
            assert!(fresh.depth.as_raw().iter().any(|v| v.is_finite()));
            assert_eq!(bits(&reused), bits(&fresh), "call {k}");
            assert_eq!(bits(&threaded), bits(&fresh), "call {k}");
        }
    }
}
