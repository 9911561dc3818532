//! Static depth and the geometric cue (new in this project; not in the paper).
//!
//! Movers are in front of the static scene: a pixel whose depth is clearly nearer than the
//! static surface seen at the same place from other times is not static. The static depth of
//! the current view is built from the depth maps of many frames over a wide time window
//! (seconds, past and future), each forward-splatted into the current view with its relative
//! pose (nearest surface per pixel). Per pixel, the static surface is the farthest depth that
//! at least `min_support` views agree on (movers occlude the static scene, so they are nearer;
//! a single far outlier is not trusted), refined to the median of the views that agree with it.
//! Because the window spans seconds, the scene behind a person who stays in one place for a
//! moment is still recovered from the frames before they arrived or after they left.
//!
//! The cue is the paper's movable term (difference from a static background, §3.1) computed
//! on depth instead of colour, so it covers whole bodies instead of textured edges. It is
//! evaluated at a working resolution of about [`StaticDepthParams::working_width`] pixels
//! across, so its pixel constants mean the same at every input resolution.
//!
//! Everything here is pure computation; which frames and poses to use is the caller's choice.

use dynapix_geometry::camera::PinholeCamera;
use dynapix_geometry::se3::Se3;
use image::Luma;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::{FloatImage, MotionError, check_size, pixel_rays};

/// Parameters of the static depth and the geometric cue.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct StaticDepthParams {
    /// Working image width in pixels (320): the input is subsampled by
    /// `round(width / working_width)` (at least 1).
    pub working_width: u32,
    /// Half width of the time window of neighbour views, in seconds (2.0).
    pub window_s: f64,
    /// Largest number of neighbour views, spread evenly over the window (24).
    pub max_views: usize,
    /// Depth agreement tolerance `tol(z) = tol_a + tol_b·z²`: constant part in metres (0.03).
    pub tol_a: f32,
    /// Depth agreement tolerance: quadratic part in 1/m (0.005; Kinect depth noise grows with
    /// the square of the distance).
    pub tol_b: f32,
    /// Views that must agree on a static surface, the one that sees it included (3).
    pub min_support: usize,
    /// Smallest valid depth in metres (0.1).
    pub min_depth: f32,
    /// Misalignment tolerance in working pixels (2): a pixel is near only when it is nearer
    /// than every static depth within this radius, so static depth edges that the poses
    /// misplace by a pixel or two are not taken for movers.
    pub align_radius: u32,
    /// Opening radius at working resolution (1: 3×3) that removes isolated detections.
    pub open_radius: u32,
    /// Dilation radius at working resolution (4: 9×9) that covers silhouettes, where depth is
    /// unreliable.
    pub dilate_radius: u32,
    /// Steps of 1 working pixel by which detections spread into pixels without depth (8):
    /// dark clothes and hair often have none.
    pub fill_steps: u32,
}

impl Default for StaticDepthParams {
    fn default() -> Self {
        Self {
            working_width: 320,
            window_s: 2.0,
            max_views: 24,
            tol_a: 0.03,
            tol_b: 0.005,
            min_support: 3,
            min_depth: 0.1,
            align_radius: 2,
            open_radius: 1,
            dilate_radius: 4,
            fill_steps: 8,
        }
    }
}

impl StaticDepthParams {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), MotionError> {
        let bad = |name: &'static str, message: &str| {
            Err(MotionError::InvalidParam {
                name,
                message: message.to_string(),
            })
        };
        if self.working_width == 0 {
            return bad("working_width", "must be at least 1");
        }
        if !(self.window_s.is_finite() && self.window_s > 0.0) {
            return bad("window_s", "must be a positive number of seconds");
        }
        if self.max_views == 0 {
            return bad("max_views", "must be at least 1");
        }
        if !(self.tol_a.is_finite() && self.tol_a >= 0.0 && self.tol_b.is_finite())
            || self.tol_b < 0.0
            || self.tol_a + self.tol_b <= 0.0
        {
            return bad("tol_a/tol_b", "must be finite, non-negative and not both 0");
        }
        if self.min_support == 0 {
            return bad("min_support", "must be at least 1");
        }
        if !(self.min_depth.is_finite() && self.min_depth > 0.0) {
            return bad("min_depth", "must be a positive depth in metres");
        }
        Ok(())
    }

    /// Subsampling factor for an image `width` pixels wide.
    pub fn factor(&self, width: u32) -> u32 {
        ((width as f64 / self.working_width.max(1) as f64).round() as u32).max(1)
    }

    /// Depth agreement tolerance at depth `z`.
    pub fn tol(&self, z: f32) -> f32 {
        self.tol_a + self.tol_b * z * z
    }
}

/// A depth map subsampled to the working resolution: pixel `(i, j)` holds the depth of input
/// pixel `(i·factor, j·factor)` (no averaging across depth edges).
#[derive(Clone, Debug, PartialEq)]
pub struct WorkingDepth {
    /// Subsampling factor.
    pub factor: u32,
    /// Width and height of the input image.
    pub full_size: (u32, u32),
    /// Depth in metres at working resolution (0 = none).
    pub depth: FloatImage,
}

impl WorkingDepth {
    /// Subsamples a full-resolution depth map.
    pub fn new(depth: &FloatImage, params: &StaticDepthParams) -> Self {
        let f = params.factor(depth.width());
        let w = depth.width().div_ceil(f);
        let h = depth.height().div_ceil(f);
        let d = FloatImage::from_fn(w, h, |i, j| {
            let z = depth.get_pixel(i * f, j * f).0[0];
            Luma([if z.is_finite() && z > 0.0 { z } else { 0.0 }])
        });
        Self {
            factor: f,
            full_size: depth.dimensions(),
            depth: d,
        }
    }
}

/// One neighbour view for the static depth: its subsampled depth and `T_cs`, which maps its
/// camera coordinates into the current camera's.
#[derive(Clone, Copy, Debug)]
pub struct DepthView<'a> {
    /// The neighbour's depth.
    pub depth: &'a WorkingDepth,
    /// Relative pose current ← neighbour.
    pub t_cs: Se3,
}

/// Viewing rays of the working pixels, row by row: ray of input pixel `(i·f, j·f)`.
struct Rays {
    rays: Vec<[f64; 2]>,
}

impl Rays {
    fn new(cam: &PinholeCamera, factor: u32, w: u32, h: u32) -> Self {
        let table = pixel_rays(cam);
        let mut rays = Vec::with_capacity((w * h) as usize);
        for j in 0..h {
            for i in 0..w {
                let (x, y) = (i * factor, j * factor);
                let r = match &table {
                    Some(t) => t.ray(x, y).unwrap_or([f64::NAN; 2]),
                    None => [(x as f64 - cam.cx) / cam.fx, (y as f64 - cam.cy) / cam.fy],
                };
                rays.push(r);
            }
        }
        Self { rays }
    }
}

/// The static depth of the current view at working resolution (`NaN` where no surface is
/// supported by enough views).
#[derive(Clone, Debug, PartialEq)]
pub struct StaticDepth {
    /// Static depth in metres, `NaN` = unknown.
    pub depth: FloatImage,
    /// Subsampling factor relative to the input.
    pub factor: u32,
}

/// Forward-splats `view` into the current camera at working resolution, keeping the nearest
/// surface per pixel (`INFINITY` = nothing).
///
/// The points are transformed and projected in blocks without branches (invalid points are
/// masked, not skipped), so the compiler vectorises the arithmetic; the nearest-surface
/// writes follow per block. The arithmetic is the same operations in the same order as a
/// point at a time ([`PinholeCamera::project`], [`PixelRays::project`]), so the result is
/// identical bit for bit (test `block_splat_equals_the_point_by_point_splat`).
///
/// [`PixelRays::project`]: dynapix_geometry::camera::PixelRays::project
fn splat_nearest(
    cam: &PinholeCamera,
    table: Option<&dynapix_geometry::camera::PixelRays>,
    rays: &Rays,
    view: &DepthView<'_>,
    out: &mut [f32],
) {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx512) = dynapix_simd::Avx512F::detect() {
        // SAFETY: the token proves the CPU has AVX-512F.
        unsafe { splat_nearest_avx512(avx512, cam, table, rays, view, out) };
        return;
    }
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        unsafe { splat_nearest_avx2(avx2, cam, table, rays, view, out) };
        return;
    }
    splat_nearest_any(cam, table, rays, view, out);
}

/// [`splat_nearest_blocks`] compiled for AVX-512F (8 lanes of `f64`). No FMA: the same
/// operations as the baseline build, so the same bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn splat_nearest_avx512(
    _: dynapix_simd::Avx512F,
    cam: &PinholeCamera,
    table: Option<&dynapix_geometry::camera::PixelRays>,
    rays: &Rays,
    view: &DepthView<'_>,
    out: &mut [f32],
) {
    splat_nearest_any(cam, table, rays, view, out);
}

/// [`splat_nearest_blocks`] for the camera at hand: the lens model is a compile-time choice,
/// so a pinhole camera's loop carries no distortion arithmetic.
#[inline(always)]
fn splat_nearest_any(
    cam: &PinholeCamera,
    table: Option<&dynapix_geometry::camera::PixelRays>,
    rays: &Rays,
    view: &DepthView<'_>,
    out: &mut [f32],
) {
    if table.is_some() {
        splat_nearest_blocks::<true>(cam, table, rays, view, out);
    } else {
        splat_nearest_blocks::<false>(cam, table, rays, view, out);
    }
}

/// [`splat_nearest_blocks`] compiled for AVX2 (4 lanes of `f64`). No FMA: the rounding is
/// that of the baseline build.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn splat_nearest_avx2(
    _: dynapix_simd::Avx2,
    cam: &PinholeCamera,
    table: Option<&dynapix_geometry::camera::PixelRays>,
    rays: &Rays,
    view: &DepthView<'_>,
    out: &mut [f32],
) {
    splat_nearest_any(cam, table, rays, view, out);
}

/// Points per block of [`splat_nearest_blocks`].
const SPLAT_BLOCK: usize = 512;

#[inline(always)]
fn splat_nearest_blocks<const DISTORTED: bool>(
    cam: &PinholeCamera,
    table: Option<&dynapix_geometry::camera::PixelRays>,
    rays: &Rays,
    view: &DepthView<'_>,
    out: &mut [f32],
) {
    let f = view.depth.factor as f64;
    // Dividing by a power of two is multiplying by its reciprocal, bit for bit; other
    // factors keep the division.
    let pow2 = view.depth.factor.is_power_of_two();
    let inv_f = 1.0 / f;
    let d = view.depth.depth.as_raw();
    let (w, h) = view.depth.depth.dimensions();
    let (wf, hf) = (w as f64, h as f64);
    let motion = crate::RigidRows::from_se3(&view.t_cs);
    let (fx, fy, cx, cy) = (cam.fx, cam.fy, cam.cx, cam.cy);
    let (dist, max_r2) = match table {
        Some(t) => (t.camera().dist, t.max_r2()),
        None => ([0.0; 5], 0.0),
    };
    let [k1, k2, p1, p2, k3] = dist;
    let distorted = DISTORTED;
    let mut idx = [0u32; SPLAT_BLOCK];
    let mut zs = [0f32; SPLAT_BLOCK];
    for (dc, rc) in d.chunks(SPLAT_BLOCK).zip(rays.rays.chunks(SPLAT_BLOCK)) {
        let n = dc.len().min(rc.len());
        for k in 0..n {
            let z = dc[k];
            let ray = rc[k];
            let ok = !(z.is_nan() || z <= 0.0) & ray[0].is_finite();
            let z = z as f64;
            let (px, py, pz) = motion.apply(ray[0] * z, ray[1] * z, z);
            let ok = ok & (pz > 0.0);
            let (ux, uy, ok) = if distorted {
                let (x, y) = (px / pz, py / pz);
                let r2 = x * x + y * y;
                let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                let dx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
                let dy = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
                (fx * dx + cx, fy * dy + cy, ok & (r2 <= max_r2))
            } else {
                (fx * px / pz + cx, fy * py / pz + cy, ok)
            };
            // Nearest working pixel, exactly as `f64::round` (half away from zero) followed
            // by the bounds check: inside the image means x + 0.5 in (0, w).
            let (u, v) = if pow2 {
                (ux * inv_f + 0.5, uy * inv_f + 0.5)
            } else {
                (ux / f + 0.5, uy / f + 0.5)
            };
            let ok = ok & (u > 0.0) & (v > 0.0) & (u < wf) & (v < hf);
            // Truncation of the clamped coordinates, which vectorises (`as` saturates, and its
            // range checks are done a lane at a time): the same index wherever `ok`, since
            // then 0 < u < w and 0 < v < h, and clamping leaves u and v as they are.
            let (uc, vc) = (u.max(0.0).min(wf), v.max(0.0).min(hf));
            // SAFETY: `max` turns NaN into 0, so uc and vc are finite, in [0, 2³²).
            let (ui, vi) = unsafe { (uc.to_int_unchecked::<u32>(), vc.to_int_unchecked::<u32>()) };
            let i = vi.wrapping_mul(w).wrapping_add(ui);
            idx[k] = if ok { i } else { u32::MAX };
            zs[k] = pz as f32;
        }
        for (&i, &zf) in idx[..n].iter().zip(&zs[..n]) {
            if let Some(o) = out.get_mut(i as usize) {
                // The nearer surface, selected without a branch (which the order of the
                // depths would make unpredictable): the same value as `if zf < *o`.
                *o = if zf < *o { zf } else { *o };
            }
        }
    }
}

/// [`splat_nearest`] a point at a time with early exits: the test reference it must equal
/// bit for bit.
#[cfg(test)]
fn splat_nearest_reference(
    cam: &PinholeCamera,
    table: Option<&dynapix_geometry::camera::PixelRays>,
    rays: &Rays,
    view: &DepthView<'_>,
    out: &mut [f32],
) {
    let f = view.depth.factor as f64;
    // Dividing by a power of two is multiplying by its reciprocal, bit for bit; other
    // factors keep the division.
    let inv_f = view.depth.factor.is_power_of_two().then(|| 1.0 / f);
    let d = view.depth.depth.as_raw();
    let (w, h) = view.depth.depth.dimensions();
    let (wf, hf) = (w as f64, h as f64);
    let r = *view.t_cs.rotation.to_rotation_matrix().matrix();
    let t = view.t_cs.translation.vector;
    for (&z, ray) in d.iter().zip(&rays.rays) {
        if z.is_nan() || z <= 0.0 || !ray[0].is_finite() {
            continue;
        }
        let z = z as f64;
        let p = r * nalgebra::Vector3::new(ray[0] * z, ray[1] * z, z) + t;
        if p.z <= 0.0 {
            continue;
        }
        let p = nalgebra::Point3::from(p);
        let uv = match table {
            Some(t) => t.project(&p),
            None => cam.project(&p),
        };
        let Some(uv) = uv else { continue };
        // Nearest working pixel, exactly as `f64::round` (half away from zero) followed by
        // the bounds check, without the libm call: inside the image means x + 0.5 in (0, w).
        let (u, v) = match inv_f {
            Some(s) => (uv.x * s + 0.5, uv.y * s + 0.5),
            None => (uv.x / f + 0.5, uv.y / f + 0.5),
        };
        if !(u > 0.0 && v > 0.0 && u < wf && v < hf) {
            continue;
        }
        let idx = v as usize * w as usize + u as usize;
        let zf = p.z as f32;
        if zf < out[idx] {
            out[idx] = zf;
        }
    }
}

/// The static depth of the current view from its neighbour `views` (see the module
/// documentation): every view is splatted at working resolution, then per pixel the farthest
/// depth that `min_support` views agree on is kept, refined to the median of those views.
pub fn static_depth(
    cam: &PinholeCamera,
    views: &[DepthView<'_>],
    params: &StaticDepthParams,
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
    let mut splats = take_buffers(views.len());
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
        .for_each(|(j, row)| static_depth_row(&splats, &network, params, j, row));
    return_buffers(splats);
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

/// Splat buffers kept between calls of [`static_depth`]: a sequence splats 24 views of the
/// same size for every frame, and fresh buffers of that size come from the operating system
/// zeroed, page by page, every time.
static SPLAT_BUFFERS: std::sync::Mutex<Vec<Vec<f32>>> = std::sync::Mutex::new(Vec::new());

/// Largest number of splat buffers kept (two frames of 24 views in flight).
const MAX_KEPT_BUFFERS: usize = 64;

fn take_buffers(k: usize) -> Vec<Vec<f32>> {
    let mut pool = SPLAT_BUFFERS.lock().unwrap_or_else(|e| e.into_inner());
    let keep = pool.len().saturating_sub(k);
    let mut out = pool.split_off(keep);
    out.resize_with(k, Vec::new);
    out
}

fn return_buffers(mut bufs: Vec<Vec<f32>>) {
    let mut pool = SPLAT_BUFFERS.lock().unwrap_or_else(|e| e.into_inner());
    bufs.truncate(MAX_KEPT_BUFFERS.saturating_sub(pool.len()));
    pool.append(&mut bufs);
}

/// Pixels sorted together by [`sort_lanes`].
const LANES: usize = 8;

/// Batcher's odd–even merge sort for `n` (a power of two) inputs: the compare-exchange pairs
/// `(i, j)`, `i < j`, that leave any input sorted ascending when each pair is put in order.
fn sorting_network(n: usize) -> Vec<(usize, usize)> {
    let mut pairs = Vec::new();
    let mut p = 1;
    while p < n {
        let mut k = p;
        while k >= 1 {
            let mut j = k % p;
            while j + k < n {
                for i in 0..k.min(n - j - k) {
                    if (i + j) / (2 * p) == (i + j + k) / (2 * p) {
                        pairs.push((i + j, i + j + k));
                    }
                }
                j += 2 * k;
            }
            k /= 2;
        }
        p *= 2;
    }
    pairs
}

/// A sorting network for any number `n` of rows: [`sorting_network`] of the next power of
/// two without the pairs that reach past `n`. Those rows would hold +∞, the largest value,
/// which no compare-exchange ever moves (the smaller index gets the minimum), so the pairs
/// that reach them change nothing.
fn sorting_network_for(n: usize) -> Vec<(usize, usize)> {
    sorting_network(n.next_power_of_two())
        .into_iter()
        .filter(|&(_, j)| j < n)
        .collect()
}

/// Straight-line code for one fixed network: `$net`, its pairs as data (the test
/// `fixed_network_is_batchers` checks them against [`sorting_network_for`]), and `$name`,
/// which applies them with `ce` to `$n` rows held in local variables, so the rows live in
/// registers instead of being loaded and stored by every compare-exchange of a loop over
/// the pairs.
macro_rules! fixed_network {
    ($name:ident, $net:ident, $n:literal, [$(($i:literal, $j:literal)),* $(,)?]) => {
        /// The pairs of the fixed network (see [`fixed_network`]), for the tests.
        #[cfg(test)]
        const $net: [(usize, usize); [$($i),*].len()] = [$(($i, $j)),*];

        /// The fixed network applied to rows held by value: `ce(a, b)` returns the rows
        /// `(lo, hi)` put in order lane by lane.
        #[inline(always)]
        fn $name<T: Copy>(v: &mut [T; $n], ce: impl Fn(T, T) -> (T, T)) {
            $(
                let (lo, hi) = ce(v[$i], v[$j]);
                v[$i] = lo;
                v[$j] = hi;
            )*
        }
    };
}

/// Rows `a` and `b` in order lane by lane, by the same selection as [`sort_lanes_body`].
#[inline(always)]
fn compare_exchange(a: [f32; LANES], b: [f32; LANES]) -> ([f32; LANES], [f32; LANES]) {
    let mut lo = a;
    let mut hi = b;
    for l in 0..LANES {
        let swap = b[l] < a[l];
        lo[l] = if swap { b[l] } else { a[l] };
        hi[l] = if swap { a[l] } else { b[l] };
    }
    (lo, hi)
}

// Batcher's network for 24 rows, the default number of static-depth views: one line per
// step of the merges (a line's pairs are independent of each other).
#[rustfmt::skip]
fixed_network!(apply_network_24, NETWORK_24, 24, [
    (0, 1), (2, 3), (4, 5), (6, 7), (8, 9), (10, 11), (12, 13), (14, 15), (16, 17), (18, 19),
    (20, 21), (22, 23),
    (0, 2), (1, 3), (4, 6), (5, 7), (8, 10), (9, 11), (12, 14), (13, 15), (16, 18), (17, 19),
    (20, 22), (21, 23),
    (1, 2), (5, 6), (9, 10), (13, 14), (17, 18), (21, 22),
    (0, 4), (1, 5), (2, 6), (3, 7), (8, 12), (9, 13), (10, 14), (11, 15), (16, 20), (17, 21),
    (18, 22), (19, 23),
    (2, 4), (3, 5), (10, 12), (11, 13), (18, 20), (19, 21),
    (1, 2), (3, 4), (5, 6), (9, 10), (11, 12), (13, 14), (17, 18), (19, 20), (21, 22),
    (0, 8), (1, 9), (2, 10), (3, 11), (4, 12), (5, 13), (6, 14), (7, 15),
    (4, 8), (5, 9), (6, 10), (7, 11),
    (2, 4), (3, 5), (6, 8), (7, 9), (10, 12), (11, 13), (18, 20), (19, 21),
    (1, 2), (3, 4), (5, 6), (7, 8), (9, 10), (11, 12), (13, 14), (17, 18), (19, 20), (21, 22),
    (0, 16), (1, 17), (2, 18), (3, 19), (4, 20), (5, 21), (6, 22), (7, 23),
    (8, 16), (9, 17), (10, 18), (11, 19), (12, 20), (13, 21), (14, 22), (15, 23),
    (4, 8), (5, 9), (6, 10), (7, 11), (12, 16), (13, 17), (14, 18), (15, 19),
    (2, 4), (3, 5), (6, 8), (7, 9), (10, 12), (11, 13), (14, 16), (15, 17), (18, 20), (19, 21),
    (1, 2), (3, 4), (5, 6), (7, 8), (9, 10), (11, 12), (13, 14), (15, 16), (17, 18), (19, 20),
    (21, 22),
]);

/// Sorts every lane of `cols` ascending (row `r` holds the `r`-th value of each lane) with a
/// network from [`sorting_network`]. The values must not be NaN. Sorting the same values
/// gives the same sequence whatever the algorithm, so this equals a per-pixel sort.
fn sort_lanes(cols: &mut [[f32; LANES]], network: &[(usize, usize)]) {
    if let Ok(rows) = <&mut [[f32; LANES]; 24]>::try_from(&mut *cols) {
        // The default 24 views: the fixed network (any sorting network sorts the same). With
        // AVX2, [`static_depth_row`] sorts them in vector registers instead.
        apply_network_24(rows, compare_exchange);
        return;
    }
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        unsafe { sort_lanes_avx2(avx2, cols, network) };
        return;
    }
    sort_lanes_body(cols, network);
}

/// [`sort_lanes_body`] compiled for AVX2 (8 lanes of `f32` per instruction).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn sort_lanes_avx2(_: dynapix_simd::Avx2, cols: &mut [[f32; LANES]], network: &[(usize, usize)]) {
    sort_lanes_body(cols, network);
}

/// The 24-row network on `ymm` registers. `min(b, a)` is `b < a ? b : a` and `max(a, b)` is
/// `a > b ? a : b`, the selection of [`compare_exchange`] (for NaN too), so the same bits.
/// Inlined into the kernels (24 rows fit in the 32 registers of AVX-512VL; with AVX2's 16
/// some spill); the token proves that the AVX intrinsics may run.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn network_24_ymm(_: dynapix_simd::Avx2, v: &mut [std::arch::x86_64::__m256; 24]) {
    use std::arch::x86_64::{_mm256_max_ps, _mm256_min_ps};
    // SAFETY: the token proves the CPU has AVX.
    apply_network_24(v, |a, b| unsafe {
        (_mm256_min_ps(b, a), _mm256_max_ps(a, b))
    });
}

#[inline(always)]
fn sort_lanes_body(cols: &mut [[f32; LANES]], network: &[(usize, usize)]) {
    for &(i, j) in network {
        let (Some(&a), Some(&b)) = (cols.get(i), cols.get(j)) else {
            continue;
        };
        let mut lo = a;
        let mut hi = b;
        for l in 0..LANES {
            let swap = b[l] < a[l];
            lo[l] = if swap { b[l] } else { a[l] };
            hi[l] = if swap { a[l] } else { b[l] };
        }
        cols[i] = lo;
        cols[j] = hi;
    }
}

/// The farthest value that at least `min_support` values agree with (within `tol`), refined
/// to the median of the values agreeing with it; `NaN` when none is supported.
#[cfg(test)]
fn farthest_supported(vals: &mut [f32], params: &StaticDepthParams) -> f32 {
    vals.sort_unstable_by(|a, b| b.total_cmp(a));
    farthest_supported_in_sorted(vals, params)
}

/// [`farthest_supported`] of the `n` values `a(0) ≤ … ≤ a(n − 1)`, read in place: the same
/// scan as [`farthest_supported_in_sorted`] from the far end, so the same result bit for bit
/// (test `ascending_scan_equals_the_descending_scan`).
#[inline(always)]
fn farthest_supported_ascending(
    a: impl Fn(usize) -> f32,
    n: usize,
    params: &StaticDepthParams,
) -> f32 {
    if n < params.min_support {
        return f32::NAN;
    }
    for k in (0..n).rev() {
        let v = a(k);
        let tol = params.tol(v);
        // The values within tol of v are a contiguous run lo..=hi around k.
        let mut hi = k;
        while hi + 1 < n && a(hi + 1) - v < tol {
            hi += 1;
        }
        let mut lo = k;
        while lo > 0 && v - a(lo - 1) < tol {
            lo -= 1;
        }
        let m = hi - lo + 1;
        if m >= params.min_support {
            // The median of the run in descending order, as `median_sorted_desc`.
            return if m % 2 == 1 {
                a(hi - m / 2)
            } else {
                0.5 * (a(hi - m / 2 + 1) + a(hi - m / 2))
            };
        }
    }
    f32::NAN
}

/// [`farthest_supported_ascending`] of every lane of `cols`, sorted ascending per lane with
/// the views without a surface (+∞) last. Most pixels are decided at their farthest value:
/// the run of values within `tol` below it is counted for all lanes at once (the test
/// `v − a(j) < tol` holds on a contiguous run below the top because rounded subtraction is
/// monotone, so the count is the run's length, as the step-by-step scan finds it) and the
/// median taken from it; only lanes whose farthest value lacks support scan further, one at
/// a time. The same values bit for bit (test `lane_scan_equals_the_scan_of_each_lane`).
#[inline(always)]
fn farthest_supported_lanes(cols: &[[f32; LANES]], params: &StaticDepthParams) -> [f32; LANES] {
    // Finite values per lane (they come first).
    let mut n_fin = [0u32; LANES];
    for c in cols {
        for l in 0..LANES {
            n_fin[l] += u32::from(c[l].is_finite());
        }
    }
    let mut top = [0f32; LANES];
    let mut tol = [0f32; LANES];
    for l in 0..LANES {
        if let Some(k) = (n_fin[l] as usize).checked_sub(1) {
            top[l] = cols[k][l];
            tol[l] = params.tol(top[l]);
        }
    }
    let below = run_below_top(cols, &n_fin, &top, &tol);
    let mut out = [f32::NAN; LANES];
    for l in 0..LANES {
        let n = n_fin[l] as usize;
        if n < params.min_support {
            continue;
        }
        let (hi, m) = (n - 1, below[l] as usize + 1);
        out[l] = if m >= params.min_support {
            // The median of the run, as `farthest_supported_ascending`.
            if m % 2 == 1 {
                cols[hi - m / 2][l]
            } else {
                0.5 * (cols[hi - m / 2 + 1][l] + cols[hi - m / 2][l])
            }
        } else {
            farthest_supported_ascending(|k| cols[k][l], n, params)
        };
    }
    out
}

/// Per lane, the number of values at rows `j < n_fin − 1` with `top − a(j) < tol`,
/// compiled for AVX2 when the CPU has it (a count: the same in every build).
fn run_below_top(
    cols: &[[f32; LANES]],
    n_fin: &[u32; LANES],
    top: &[f32; LANES],
    tol: &[f32; LANES],
) -> [u32; LANES] {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        return unsafe { run_below_top_avx2(avx2, cols, n_fin, top, tol) };
    }
    run_below_top_body(cols, n_fin, top, tol)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn run_below_top_avx2(
    _: dynapix_simd::Avx2,
    cols: &[[f32; LANES]],
    n_fin: &[u32; LANES],
    top: &[f32; LANES],
    tol: &[f32; LANES],
) -> [u32; LANES] {
    run_below_top_body(cols, n_fin, top, tol)
}

#[inline(always)]
fn run_below_top_body(
    cols: &[[f32; LANES]],
    n_fin: &[u32; LANES],
    top: &[f32; LANES],
    tol: &[f32; LANES],
) -> [u32; LANES] {
    let mut count = [0u32; LANES];
    for (j, c) in cols.iter().enumerate() {
        let j = j as u32;
        for l in 0..LANES {
            let inside = j + 1 < n_fin[l];
            let near = top[l] - c[l] < tol[l];
            count[l] += u32::from(inside & near);
        }
    }
    count
}

/// [`farthest_supported`] of values already sorted descending.
#[cfg(test)]
fn farthest_supported_in_sorted(vals: &[f32], params: &StaticDepthParams) -> f32 {
    if vals.len() < params.min_support {
        return f32::NAN;
    }
    for (k, &v) in vals.iter().enumerate() {
        let tol = params.tol(v);
        // Sorted descending: the values within tol of v are a contiguous run around k.
        let lo = vals[..k].iter().rev().take_while(|&&x| x - v < tol).count();
        let hi = vals[k + 1..].iter().take_while(|&&x| v - x < tol).count();
        if lo + hi + 1 >= params.min_support {
            let run = &vals[k - lo..=k + hi];
            return median_sorted_desc(run);
        }
    }
    f32::NAN
}

#[cfg(test)]
fn median_sorted_desc(run: &[f32]) -> f32 {
    let m = run.len();
    if m % 2 == 1 {
        run[m / 2]
    } else {
        0.5 * (run[m / 2 - 1] + run[m / 2])
    }
}

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

/// The geometric cue of frame `t` of a sequence: neighbour views chosen by [`select_views`]
/// among frames with a pose, splatted with the relative poses from `poses_wc` (camera-to-world,
/// `None` = unknown). A frame without a pose, or without usable neighbours, gets P = 0.
pub fn geometric_frame(
    cam: &PinholeCamera,
    t: usize,
    stamps: &[f64],
    poses_wc: &[Option<Se3>],
    depths: &[WorkingDepth],
    params: &StaticDepthParams,
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
    let sd = static_depth(cam, &views, params)?;
    geometric_term(cur, &sd, params)
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynapix_geometry::se3::exp;
    use nalgebra::Vector6;

    fn cam(w: u32, h: u32) -> PinholeCamera {
        PinholeCamera::new(
            w,
            h,
            0.8 * w as f64,
            0.8 * w as f64,
            w as f64 / 2.0,
            h as f64 / 2.0,
        )
    }

    /// A fronto-parallel wall at `z` with an optional box nearer than it.
    fn wall(w: u32, h: u32, z: f32, block: Option<(u32, u32, u32, u32, f32)>) -> FloatImage {
        FloatImage::from_fn(w, h, |x, y| {
            if let Some((x0, y0, x1, y1, zb)) = block
                && x >= x0
                && x < x1
                && y >= y0
                && y < y1
            {
                return Luma([zb]);
            }
            Luma([z])
        })
    }

    /// Views of `depths` from the current camera's own pose.
    fn same_pose_views(depths: &[WorkingDepth]) -> Vec<DepthView<'_>> {
        depths
            .iter()
            .map(|d| DepthView {
                depth: d,
                t_cs: Se3::identity(),
            })
            .collect()
    }

    fn params() -> StaticDepthParams {
        StaticDepthParams {
            working_width: 80,
            ..Default::default()
        }
    }

    /// Minimum filter by its definition: every window visited pixel by pixel.
    fn min_filter_naive(v: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
        let fmin = |a: f32, b: f32| if b < a || a.is_nan() { b } else { a };
        let mut out = vec![f32::NAN; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut m = f32::NAN;
                for yy in y.saturating_sub(r)..=(y + r).min(h - 1) {
                    for xx in x.saturating_sub(r)..=(x + r).min(w - 1) {
                        m = fmin(m, v[yy * w + xx]);
                    }
                }
                out[y * w + x] = m;
            }
        }
        out
    }

    /// Dilation by its definition.
    fn dilate_naive(m: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
        let mut out = vec![false; w * h];
        for y in 0..h {
            for x in 0..w {
                out[y * w + x] = (y.saturating_sub(r)..=(y + r).min(h - 1))
                    .any(|yy| (x.saturating_sub(r)..=(x + r).min(w - 1)).any(|xx| m[yy * w + xx]));
            }
        }
        out
    }

    /// A small deterministic generator for the law tests.
    fn lcg(state: &mut u64) -> u32 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*state >> 33) as u32
    }

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

    /// Equal bit for bit, element by element (NaN included).
    fn same_bits(a: &[f32], b: &[f32]) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
    }

    #[test]
    fn block_splat_equals_the_point_by_point_splat() {
        let mut st = 3u64;
        for (w, h, distorted) in [(80u32, 60u32, false), (80, 60, true), (96, 72, true)] {
            let mut c = cam(w, h);
            if distorted {
                c.dist = [0.262383, -0.953104, -0.005358, 0.002628, 1.163314];
            }
            let table = pixel_rays(&c);
            for working_width in [80, 40, 32] {
                let p = StaticDepthParams {
                    working_width,
                    ..Default::default()
                };
                // Depths with holes, NaN and values near the camera.
                let depth = FloatImage::from_fn(w, h, |_, _| {
                    Luma([match lcg(&mut st) % 10 {
                        0 => 0.0,
                        1 => f32::NAN,
                        2 => 0.05,
                        _ => 0.5 + (lcg(&mut st) % 4000) as f32 * 0.001,
                    }])
                });
                let wd = WorkingDepth::new(&depth, &p);
                let (ww, wh) = wd.depth.dimensions();
                let rays = Rays::new(&c, wd.factor, ww, wh);
                for _ in 0..20 {
                    let mut xi = [0.0; 6];
                    for v in &mut xi {
                        *v = ((lcg(&mut st) % 2001) as f64 - 1000.0) * 2e-4;
                    }
                    let view = DepthView {
                        depth: &wd,
                        t_cs: exp(&Vector6::from_row_slice(&xi)),
                    };
                    let n = (ww * wh) as usize;
                    let (mut a, mut b) = (vec![f32::INFINITY; n], vec![f32::INFINITY; n]);
                    splat_nearest(&c, table.as_deref(), &rays, &view, &mut a);
                    splat_nearest_reference(&c, table.as_deref(), &rays, &view, &mut b);
                    assert!(a.iter().any(|z| z.is_finite()));
                    assert!(
                        same_bits(&a, &b),
                        "{w}x{h} distorted {distorted} working width {working_width}"
                    );
                    let mut c2 = vec![f32::INFINITY; n];
                    splat_nearest_any(&c, table.as_deref(), &rays, &view, &mut c2);
                    assert!(same_bits(&c2, &b));
                    // Every instruction set the CPU has gives the same bits.
                    #[cfg(target_arch = "x86_64")]
                    {
                        if let Some(avx2) = dynapix_simd::Avx2::detect() {
                            c2.fill(f32::INFINITY);
                            let t = table.as_deref();
                            // SAFETY: the token proves the CPU has AVX2.
                            unsafe { splat_nearest_avx2(avx2, &c, t, &rays, &view, &mut c2) };
                            assert!(same_bits(&c2, &b), "avx2");
                        }
                        if let Some(avx512) = dynapix_simd::Avx512F::detect() {
                            c2.fill(f32::INFINITY);
                            let t = table.as_deref();
                            // SAFETY: the token proves the CPU has AVX-512F.
                            unsafe { splat_nearest_avx512(avx512, &c, t, &rays, &view, &mut c2) };
                            assert!(same_bits(&c2, &b), "avx512f");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn the_network_for_any_number_of_rows_sorts_every_lane() {
        let mut st = 7u64;
        for n in 1usize..=40 {
            let net = sorting_network_for(n);
            assert!(net.iter().all(|&(i, j)| i < j && j < n));
            for _ in 0..100 {
                let mut cols: Vec<[f32; LANES]> = (0..n)
                    .map(|_| {
                        std::array::from_fn(|_| match lcg(&mut st) % 8 {
                            0 => f32::INFINITY,
                            _ => (lcg(&mut st) % 30) as f32 * 0.1,
                        })
                    })
                    .collect();
                let mut want = cols.clone();
                sort_lanes(&mut cols, &net);
                for l in 0..LANES {
                    let mut lane: Vec<f32> = want.iter().map(|c| c[l]).collect();
                    lane.sort_unstable_by(f32::total_cmp);
                    for (c, v) in want.iter_mut().zip(lane) {
                        c[l] = v;
                    }
                }
                assert_eq!(cols, want, "n {n}");
            }
        }
        // The pruned network is smaller (24 views: 132 pairs instead of 191).
        assert_eq!(sorting_network_for(24).len(), 132);
        assert_eq!(sorting_network(32).len(), 191);
    }

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
    fn fixed_network_is_batchers() {
        assert_eq!(NETWORK_24.to_vec(), sorting_network_for(24));
    }

    #[test]
    fn the_fixed_network_sorts_like_the_loop_over_its_pairs() {
        let net = sorting_network_for(24);
        let mut st = 11u64;
        for _ in 0..500 {
            let cols: Vec<[f32; LANES]> = (0..24)
                .map(|_| {
                    std::array::from_fn(|_| match lcg(&mut st) % 6 {
                        0 => f32::INFINITY,
                        _ => (lcg(&mut st) % 40) as f32 * 0.07,
                    })
                })
                .collect();
            let mut want = cols.clone();
            sort_lanes_body(&mut want, &net);
            let bits = |c: &[[f32; LANES]]| -> Vec<u32> {
                c.iter().flatten().map(|v| v.to_bits()).collect()
            };
            // The straight-line network and the dispatching entry point (the vector-register
            // builds are compared in `rows_of_24_views_equal_the_generic_rows`).
            let mut v: [[f32; LANES]; 24] = std::array::from_fn(|r| cols[r]);
            apply_network_24(&mut v, compare_exchange);
            assert_eq!(bits(&v), bits(&want));
            let mut c = cols.clone();
            sort_lanes(&mut c, &net);
            assert_eq!(bits(&c), bits(&want));
        }
    }

    #[test]
    fn the_sorting_network_sorts_every_lane() {
        let mut st = 5u64;
        for n in [1usize, 2, 4, 8, 16, 32, 64] {
            let net = sorting_network(n);
            // 0-1 principle for the small ones, random values with ties for all.
            if n <= 16 {
                for bits in 0u32..(1 << n) {
                    let mut cols: Vec<[f32; LANES]> =
                        (0..n).map(|r| [((bits >> r) & 1) as f32; LANES]).collect();
                    sort_lanes(&mut cols, &net);
                    assert!(
                        cols.windows(2).all(|w| w[0][0] <= w[1][0]),
                        "n {n} bits {bits}"
                    );
                }
            }
            for _ in 0..200 {
                let mut cols: Vec<[f32; LANES]> = (0..n)
                    .map(|_| {
                        let mut c = [0.0; LANES];
                        for v in &mut c {
                            *v = match lcg(&mut st) % 8 {
                                0 => f32::INFINITY,
                                k => (lcg(&mut st) % 50) as f32 * 0.1 * k as f32,
                            };
                        }
                        c
                    })
                    .collect();
                let mut want: Vec<Vec<u32>> = (0..LANES)
                    .map(|l| {
                        let mut v: Vec<f32> = cols.iter().map(|c| c[l]).collect();
                        v.sort_unstable_by(f32::total_cmp);
                        v.into_iter().map(f32::to_bits).collect()
                    })
                    .collect();
                sort_lanes(&mut cols, &net);
                for (l, want) in want.iter_mut().enumerate() {
                    let got: Vec<u32> = cols.iter().map(|c| c[l].to_bits()).collect();
                    assert_eq!(&got, want, "n {n} lane {l}");
                }
            }
        }
    }

    #[test]
    fn farthest_supported_ignores_a_single_far_outlier() {
        let p = params();
        let mut v = vec![2.0, 2.01, 1.99, 1.0, 1.01, 5.0];
        let s = farthest_supported(&mut v, &p);
        assert!((s - 2.0).abs() < 0.011, "{s}");
        let mut v = vec![1.0, 5.0];
        assert!(farthest_supported(&mut v, &p).is_nan());
    }

    /// A depth from one of four clusters (with close values and exact ties) or an outlier.
    fn cluster_depth(st: &mut u64) -> f32 {
        let c = (lcg(st) % 4) as f32;
        match lcg(st) % 8 {
            0 => 0.3 + (lcg(st) % 8000) as f32 * 0.001,
            1 => 1.0 + c,
            _ => 1.0 + c + (lcg(st) % 100) as f32 * 0.0007,
        }
    }

    #[test]
    fn ascending_scan_equals_the_descending_scan() {
        let p = StaticDepthParams::default();
        let mut st = 11u64;
        let mut supported = 0;
        for n in 0..40 {
            for _ in 0..200 {
                // Clusters of nearby depths with outliers and exact ties.
                let mut v: Vec<f32> = (0..n).map(|_| cluster_depth(&mut st)).collect();
                v.sort_unstable_by(f32::total_cmp);
                let want = farthest_supported(&mut v.clone(), &p);
                let got = farthest_supported_ascending(|k| v[k], v.len(), &p);
                assert_eq!(got.to_bits(), want.to_bits(), "{v:?}");
                supported += usize::from(want.is_finite());
            }
        }
        assert!(supported > 1000, "{supported}");
    }

    #[test]
    #[allow(clippy::needless_range_loop)] // lane l of every row is written
    fn lane_scan_equals_the_scan_of_each_lane() {
        let mut st = 5u64;
        let mut decided_at_top = 0;
        let mut scanned = 0;
        for rows in [1, 3, 8, 17, 24] {
            for min_support in [1, 3, 6] {
                let p = StaticDepthParams {
                    min_support,
                    ..StaticDepthParams::default()
                };
                for _ in 0..300 {
                    let mut cols = vec![[f32::INFINITY; LANES]; rows];
                    for l in 0..LANES {
                        let n = (lcg(&mut st) as usize) % (rows + 1);
                        let mut v: Vec<f32> = (0..n).map(|_| cluster_depth(&mut st)).collect();
                        v.sort_unstable_by(f32::total_cmp);
                        for (k, x) in v.iter().enumerate() {
                            cols[k][l] = *x;
                        }
                    }
                    let got = farthest_supported_lanes(&cols, &p);
                    for l in 0..LANES {
                        let n = cols.partition_point(|c| c[l].is_finite());
                        let want = farthest_supported_ascending(|k| cols[k][l], n, &p);
                        assert_eq!(got[l].to_bits(), want.to_bits(), "lane {l} of {cols:?}");
                        if n >= min_support && want.is_finite() {
                            let top = cols[n - 1][l];
                            let support = (0..n).filter(|&k| top - cols[k][l] < p.tol(top)).count();
                            if support >= min_support {
                                decided_at_top += 1;
                            } else {
                                scanned += 1;
                            }
                        }
                    }
                }
            }
        }
        assert!(
            decided_at_top > 1000 && scanned > 100,
            "{decided_at_top} {scanned}"
        );
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
    fn bad_parameters_are_refused() {
        let p = StaticDepthParams {
            min_support: 0,
            ..Default::default()
        };
        assert!(p.validate().is_err());
        let p = StaticDepthParams {
            window_s: f64::NAN,
            ..Default::default()
        };
        assert!(p.validate().is_err());
    }
}
