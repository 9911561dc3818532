//! Forward splatting of a neighbour view into the current camera at working resolution,
//! nearest surface per pixel, in branch-free blocks with AVX2/AVX-512 builds.

use dynapix_geometry::camera::PinholeCamera;

use super::DepthView;
use crate::pixel_rays;

/// Viewing rays of the working pixels, row by row: ray of input pixel `(i·f, j·f)`.
pub(super) struct Rays {
    rays: Vec<[f64; 2]>,
}

impl Rays {
    pub(super) fn new(cam: &PinholeCamera, factor: u32, w: u32, h: u32) -> Self {
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
pub(super) fn splat_nearest(
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::FloatImage;
    use crate::static_depth::{fixtures::*, *};
    use dynapix_geometry::se3::exp;
    use image::Luma;
    use nalgebra::Vector6;

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
}
