//! The normalised residual of every pixel under a fitted motion ([`dense_residual`], step 3
//! of the cue).

use dynapix_flow::FlowField;
use dynapix_geometry::{PixelRays, Se3};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::pair::{Model, Pair};
use super::params::RigidityParams;
use crate::{FloatImage, MotionError};

/// The normalised residual `r = √r²` ([`residual_squared`](super::residual_squared)) of every pixel
/// of frame i under
/// `motion` (camera i → camera j) with the flow i → j; NaN where the pixel has no depth, its
/// flow target leaves the image or the rounded target has no depth (the same conditions as
/// [`correspondences`](super::correspondences)).
pub fn dense_residual(
    depth_i: &FloatImage,
    depth_j: &FloatImage,
    flow: &FlowField,
    rays: &PixelRays,
    motion: &Se3,
    params: &RigidityParams,
) -> Result<FloatImage, MotionError> {
    params.validate()?;
    let pair = Pair::new(depth_i, depth_j, flow, rays, params)?;
    let cam = rays.camera();
    let model = Model::new(cam, params);
    let r: Matrix3<f64> = *motion.rotation.to_rotation_matrix().matrix();
    let t = motion.translation.vector;
    let w = cam.width as usize;
    let mut out = FloatImage::new(cam.width, cam.height);
    if w == 0 {
        return Ok(out);
    }
    out.par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, row)| residual_row(&pair, &model, &r, &t, y, row));
    Ok(out)
}

/// One row of [`dense_residual`]: [`Pair::lift`] and [`Model::r2`] over slices of the row
/// instead of per-pixel look-ups, and compiled for AVX2 when present (where `f64::round` is
/// inlined instead of called). The same operations on the same values: bit-identical (test
/// `row_residual_equals_the_pixel_by_pixel_residual`).
fn residual_row(
    pair: &Pair<'_>,
    model: &Model,
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    y: usize,
    row: &mut [f32],
) {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        unsafe { residual_row_avx2(avx2, pair, model, r, t, y, row) };
        return;
    }
    residual_row_body(pair, model, r, t, y, row);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn residual_row_avx2(
    _: dynapix_simd::Avx2,
    pair: &Pair<'_>,
    model: &Model,
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    y: usize,
    row: &mut [f32],
) {
    residual_row_body(pair, model, r, t, y, row);
}

/// Pixels per block of [`residual_row_body`].
const RESIDUAL_BLOCK: usize = 64;

#[inline(always)]
fn residual_row_body(
    pair: &Pair<'_>,
    model: &Model,
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    y: usize,
    row: &mut [f32],
) {
    let cam = pair.rays.camera();
    let (w, h) = (cam.width as usize, cam.height as usize);
    let (xmax, ymax) = ((cam.width - 1) as f64, (cam.height - 1) as f64);
    let (fx, fy) = (cam.fx, cam.fy);
    let zi = &pair.depth_i.as_raw()[y * w..][..w];
    let zj = pair.depth_j.as_raw();
    let flow = &pair.flow.data[y * w..][..w];
    let rays_i = pair.rays.row(y as u32);
    let rays = pair.rays.all();
    let min_depth = pair.min_depth;
    let rt = crate::RigidRows::new(r, t);
    let (fxs, fys) = (model.fx_over_sigma, model.fy_over_sigma);
    let (sz_a, sz_b, min_pz) = (model.sz_a, model.sz_b, model.min_pz);
    let mut ok = [false; RESIDUAL_BLOCK];
    let mut at = [0usize; RESIDUAL_BLOCK];
    let mut z2 = [0f64; RESIDUAL_BLOCK];
    let mut rj = [[0f64; 2]; RESIDUAL_BLOCK];
    let mut du = [0f64; RESIDUAL_BLOCK];
    let mut dv = [0f64; RESIDUAL_BLOCK];
    let row = &mut row[..w];
    for x0 in (0..w).step_by(RESIDUAL_BLOCK) {
        let n = RESIDUAL_BLOCK.min(w - x0);
        // The source pixel and its flow target, without branches.
        for j in 0..n {
            let x = x0 + j;
            let z = zi[x] as f64;
            let f = flow[x];
            let u2 = x as f64 + f[0] as f64;
            let v2 = y as f64 + f[1] as f64;
            let inside = (0.0..=xmax).contains(&u2) & (0.0..=ymax).contains(&v2);
            let (ur, vr) = (u2.round(), v2.round());
            let valid = !(z.is_nan() || z <= min_depth) & rays_i[x][0].is_finite() & inside;
            // Truncation of the clamped rounded target, which vectorises (`as` saturates, a
            // lane at a time): the same index wherever `inside`, where clamping changes
            // nothing; elsewhere the pixel is invalid anyway.
            let (uc, vc) = (ur.max(0.0).min(xmax), vr.max(0.0).min(ymax));
            // SAFETY: `max` turns NaN into 0, so uc and vc are finite, in [0, 2³²).
            let (ui, vi) = unsafe { (uc.to_int_unchecked::<u32>(), vc.to_int_unchecked::<u32>()) };
            let k = (vi as usize).wrapping_mul(w).wrapping_add(ui as usize);
            ok[j] = valid & (k < w * h);
            at[j] = if ok[j] { k } else { 0 };
            du[j] = u2 - ur;
            dv[j] = v2 - vr;
        }
        // The target's depth and ray (a gather).
        for j in 0..n {
            z2[j] = zj[at[j]] as f64;
            rj[j] = rays[at[j]];
        }
        // The residual, without branches; a pixel that failed a test gets NaN.
        for j in 0..n {
            let x = x0 + j;
            let z = zi[x] as f64;
            let ri = rays_i[x];
            let valid = ok[j] & !(z2[j].is_nan() || z2[j] <= min_depth) & rj[j][0].is_finite();
            let bn0 = rj[j][0] + du[j] / fx;
            let bn1 = rj[j][1] + dv[j] / fy;
            let bz = z2[j];
            let (px, py, pz) = rt.apply(ri[0] * z, ri[1] * z, z);
            // `Model::r2`: a NaN depth counts as behind the camera.
            let ex = (px / pz - bn0) * fxs;
            let ey = (py / pz - bn1) * fys;
            let ez = (pz - bz) / (sz_a * bz * bz + sz_b);
            let r2 = ex * ex + ey * ey + ez * ez;
            let r2 = if pz.is_nan() || pz <= min_pz {
                f64::INFINITY
            } else {
                r2
            };
            row[x] = if valid { r2.sqrt() as f32 } else { f32::NAN };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rigidity::{fixtures::*, *};
    use crate::testutil::{small_camera, small_distorted_camera};
    use rand::Rng;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn row_residual_equals_the_pixel_by_pixel_residual() {
        for cam in [small_camera(), small_distorted_camera()] {
            let (w, h) = (cam.width, cam.height);
            let params = RigidityParams::default();
            let mut rng = ChaCha8Rng::seed_from_u64(4);
            let (di, dj) = (random_depth(&mut rng, w, h), random_depth(&mut rng, w, h));
            let flow = FlowField {
                width: w,
                height: h,
                data: (0..w * h)
                    .map(|_| {
                        [
                            rng.random_range(-6.0f32..6.0),
                            rng.random_range(-6.0f32..6.0),
                        ]
                    })
                    .collect(),
            };
            let rays = camera_rays(&cam);
            let motion = se3([0.02, -0.01, 0.005], [0.05, 0.01, -0.02]);
            let got = dense_residual(&di, &dj, &flow, &rays, &motion, &params).unwrap();
            let pair = Pair::new(&di, &dj, &flow, &rays, &params).unwrap();
            let model = Model::new(&cam, &params);
            let (r, t) = (
                *motion.rotation.to_rotation_matrix().matrix(),
                motion.translation.vector,
            );
            let mut finite = 0;
            for y in 0..h {
                for x in 0..w {
                    let want = match pair.lift(x, y) {
                        Some(l) => model.r2(&(r * l.a + t), l.bn, l.bz).sqrt() as f32,
                        None => f32::NAN,
                    };
                    let g = got.get_pixel(x, y).0[0];
                    assert_eq!(g.to_bits(), want.to_bits(), "({x}, {y}): {g} vs {want}");
                    finite += usize::from(want.is_finite());
                }
            }
            assert!(finite > (w * h / 4) as usize, "{finite}");
        }
    }

    #[test]
    fn a_translating_camera_over_a_plane_is_fitted_and_has_no_residual() {
        // Fronto-parallel plane at 2 m, camera j = camera i shifted: points move by
        // t = (0.05, 0, 0) in camera coordinates, i.e. a constant flow of fx·0.05/2 px.
        let (cam, rays, depth, du, flow) = translating_plane();
        let w = cam.width;
        let params = RigidityParams::default();
        let c = correspondences(&depth, &depth, &flow, &rays, &params).unwrap();
        let fit = fit_rigid_motion(&c, &cam, &params).unwrap();
        let truth = se3([0.0; 3], [0.05, 0.0, 0.0]);
        // A plane leaves rotations about in-plane axes nearly unobservable; the fit still
        // reproduces every correspondence.
        assert_eq!(fit.inliers, c.len());
        let (dr, dt) = distance(&fit.motion, &truth);
        assert!(dr < 1e-3 && dt < 1e-3, "{dr} {dt}");
        let r = dense_residual(&depth, &depth, &flow, &rays, &fit.motion, &params).unwrap();
        for (x, _, v) in r.enumerate_pixels() {
            let inside = x as f32 + du <= (w - 1) as f32;
            if inside {
                assert!(v[0] < 0.05, "{x}: {}", v[0]);
            } else {
                assert!(v[0].is_nan());
            }
        }
        // Under a wrong motion the residual is large everywhere it is defined.
        // (0.25 m of disagreement at 2 m: 10 px.)
        let wrong = se3([0.0; 3], [-0.2, 0.0, 0.0]);
        let r = dense_residual(&depth, &depth, &flow, &rays, &wrong, &params).unwrap();
        assert!(r.iter().filter(|v| !v.is_nan()).all(|&v| v > 8.0));
    }
}
