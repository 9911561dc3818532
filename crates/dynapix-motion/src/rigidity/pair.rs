//! One frame pair with its flow: the normalised residual model, the per-pixel lift of a
//! pixel to 3-D in both cameras, and the [`correspondences`] on a grid (step 1 of the cue).

use dynapix_flow::FlowField;
use dynapix_geometry::{PinholeCamera, PixelRays, Se3};
use nalgebra::{Point3, Vector3};

use super::Correspondences;
use super::params::RigidityParams;
use crate::{FloatImage, MotionError, check_size};

/// The normalised residual model of one parameter set and camera.
#[derive(Clone, Copy, Debug)]
pub(super) struct Model {
    pub(super) fx_over_sigma: f64,
    pub(super) fy_over_sigma: f64,
    pub(super) sz_a: f64,
    pub(super) sz_b: f64,
    pub(super) min_pz: f64,
}

impl Model {
    pub(super) fn new(cam: &PinholeCamera, params: &RigidityParams) -> Self {
        Self {
            fx_over_sigma: cam.fx / params.sigma_px_for(cam),
            fy_over_sigma: cam.fy / params.sigma_px_for(cam),
            sz_a: params.sigma_z_quadratic,
            sz_b: params.sigma_z_constant,
            min_pz: params.min_projected_depth,
        }
    }

    /// `r²` of the moved point `p` against the target with normalised image coordinates `bn`
    /// and depth `bz`.
    #[inline]
    pub(super) fn r2(&self, p: &Vector3<f64>, bn: [f64; 2], bz: f64) -> f64 {
        // A NaN depth counts as behind the camera.
        if p.z.is_nan() || p.z <= self.min_pz {
            return f64::INFINITY;
        }
        let ex = (p.x / p.z - bn[0]) * self.fx_over_sigma;
        let ey = (p.y / p.z - bn[1]) * self.fy_over_sigma;
        let ez = (p.z - bz) / (self.sz_a * bz * bz + self.sz_b);
        ex * ex + ey * ey + ez * ez
    }
}

/// Normalised squared residual of the pair `(a, b)` under `motion`: with `P = motion·a`,
/// `e_x = (P.x/P.z − b.x/b.z)·fx/σ_px`, `e_y` likewise with `fy`, `e_z = (P.z − b.z)/σ_z`,
/// `σ_z = a·b.z² + b`; `r² = e_x² + e_y² + e_z²`. Infinite when `P.z` is at or below
/// [`RigidityParams::min_projected_depth`] or `b` is not in front of the camera.
pub fn residual_squared(
    motion: &Se3,
    a: &Point3<f64>,
    b: &Point3<f64>,
    cam: &PinholeCamera,
    params: &RigidityParams,
) -> f64 {
    if b.z.is_nan() || b.z <= 0.0 {
        return f64::INFINITY;
    }
    let p = motion.transform_point(a).coords;
    Model::new(cam, params).r2(&p, [b.x / b.z, b.y / b.z], b.z)
}

/// Checks that `flow` has the image size `size` and one vector per pixel.
pub(super) fn check_flow(flow: &FlowField, size: (u32, u32)) -> Result<(), MotionError> {
    check_size("flow", size, (flow.width, flow.height))?;
    if flow.data.len() != size.0 as usize * size.1 as usize {
        return Err(MotionError::SizeMismatch {
            what: "flow data".into(),
            expected: size,
            got: (flow.data.len() as u32, 1),
        });
    }
    Ok(())
}

/// One frame pair with its flow, for the per-pixel look-ups shared by the correspondences
/// and the dense residual.
pub(super) struct Pair<'a> {
    pub(super) depth_i: &'a FloatImage,
    pub(super) depth_j: &'a FloatImage,
    pub(super) flow: &'a FlowField,
    pub(super) rays: &'a PixelRays,
    pub(super) min_depth: f64,
}

/// A pixel of frame i lifted to 3-D and the normalised coordinates and depth of its target.
pub(super) struct Lifted {
    pub(super) a: Vector3<f64>,
    pub(super) bn: [f64; 2],
    pub(super) bz: f64,
}

impl<'a> Pair<'a> {
    pub(super) fn new(
        depth_i: &'a FloatImage,
        depth_j: &'a FloatImage,
        flow: &'a FlowField,
        rays: &'a PixelRays,
        params: &RigidityParams,
    ) -> Result<Self, MotionError> {
        let cam = rays.camera();
        let size = (cam.width, cam.height);
        check_size("depth of frame i", size, depth_i.dimensions())?;
        check_size("depth of the neighbour", size, depth_j.dimensions())?;
        check_flow(flow, size)?;
        Ok(Self {
            depth_i,
            depth_j,
            flow,
            rays,
            min_depth: params.min_depth,
        })
    }

    /// The pixel `(x, y)` of frame i lifted, if it has depth, a ray, a flow target inside the
    /// image (within the span of pixel centres) and depth at the rounded target pixel.
    #[inline(always)]
    pub(super) fn lift(&self, x: u32, y: u32) -> Option<Lifted> {
        let cam = self.rays.camera();
        let z = self.depth_i.get_pixel(x, y)[0] as f64;
        if z.is_nan() || z <= self.min_depth {
            return None;
        }
        let ri = self.rays.ray(x, y)?;
        let f = self.flow.get(x, y);
        let u2 = x as f64 + f[0] as f64;
        let v2 = y as f64 + f[1] as f64;
        let inside = (0.0..=(cam.width - 1) as f64).contains(&u2)
            && (0.0..=(cam.height - 1) as f64).contains(&v2);
        if !inside {
            return None;
        }
        let (ur, vr) = (u2.round(), v2.round());
        let (ui, vi) = (ur as u32, vr as u32);
        let z2 = self.depth_j.get_pixel(ui, vi)[0] as f64;
        if z2.is_nan() || z2 <= self.min_depth {
            return None;
        }
        let rj = self.rays.ray(ui, vi)?;
        Some(Lifted {
            a: Vector3::new(ri[0] * z, ri[1] * z, z),
            bn: [rj[0] + (u2 - ur) / cam.fx, rj[1] + (v2 - vr) / cam.fy],
            bz: z2,
        })
    }
}

/// Correspondences of frame i to its neighbour j on a grid of step
/// [`RigidityParams::stride`]: pixel `(x, y)` with depth `z_i > min_depth` whose flow target
/// `(u2, v2)` lies inside the image with depth `z_j > min_depth` at the rounded target gives
/// `A = z_i·ray(x, y)` and `B = z_j·(ray(round(u2), round(v2)) + ((u2 − round u2)/fx,
/// (v2 − round v2)/fy), 1)`. `flow` goes from i to j; `rays` fixes the camera and image size.
pub fn correspondences(
    depth_i: &FloatImage,
    depth_j: &FloatImage,
    flow: &FlowField,
    rays: &PixelRays,
    params: &RigidityParams,
) -> Result<Correspondences, MotionError> {
    params.validate()?;
    let pair = Pair::new(depth_i, depth_j, flow, rays, params)?;
    let stride = params.stride_for(rays.camera());
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        return Ok(unsafe { correspondences_avx2(avx2, &pair, stride) });
    }
    Ok(correspondences_body(&pair, stride))
}

/// [`correspondences_body`] compiled for AVX2, where `f64::round` is an instruction instead
/// of a library call; the same arithmetic, so the same correspondences (test
/// `correspondences_are_the_same_in_every_build`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn correspondences_avx2(_: dynapix_simd::Avx2, pair: &Pair<'_>, stride: usize) -> Correspondences {
    correspondences_body(pair, stride)
}

/// The correspondences of `pair` on the grid of step `stride`.
#[inline(always)]
fn correspondences_body(pair: &Pair<'_>, stride: usize) -> Correspondences {
    let cam = pair.rays.camera();
    let mut out = Correspondences::default();
    for y in (0..cam.height).step_by(stride) {
        for x in (0..cam.width).step_by(stride) {
            if let Some(l) = pair.lift(x, y) {
                out.source.push(Point3::from(l.a));
                out.target
                    .push(Point3::new(l.bn[0] * l.bz, l.bn[1] * l.bz, l.bz));
                out.pixels.push([x, y]);
            }
        }
    }
    out
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
    fn correspondences_are_the_same_in_every_build() {
        for cam in [small_camera(), small_distorted_camera()] {
            let (w, h) = (cam.width, cam.height);
            let params = RigidityParams::default();
            let mut rng = ChaCha8Rng::seed_from_u64(8);
            let (di, dj) = (random_depth(&mut rng, w, h), random_depth(&mut rng, w, h));
            let flow = FlowField {
                width: w,
                height: h,
                // Half-pixel flows too, where rounding matters.
                data: (0..w * h)
                    .map(|i| {
                        let f = rng.random_range(-6.0f32..6.0);
                        if i % 3 == 0 {
                            [f.round() + 0.5, -1.5]
                        } else {
                            [f, f * 0.5]
                        }
                    })
                    .collect(),
            };
            let rays = camera_rays(&cam);
            let got = correspondences(&di, &dj, &flow, &rays, &params).unwrap();
            let pair = Pair::new(&di, &dj, &flow, &rays, &params).unwrap();
            let want = correspondences_body(&pair, params.stride_for(&cam));
            assert!(got.len() > 10, "{}", got.len());
            assert_eq!(got.pixels, want.pixels);
            for (a, b) in [(&got.source, &want.source), (&got.target, &want.target)] {
                let bits = |p: &[Point3<f64>]| {
                    p.iter()
                        .flat_map(|q| q.coords.iter().map(|c| c.to_bits()).collect::<Vec<_>>())
                        .collect::<Vec<_>>()
                };
                assert_eq!(bits(a), bits(b));
            }
        }
    }

    #[test]
    fn residual_squared_follows_its_formula() {
        let cam = small_camera();
        // σ_px is given at the camera's own focal length here: 1 px.
        let params = RigidityParams {
            reference_focal_px: cam.fx,
            ..Default::default()
        };
        let id = Se3::identity();
        let a = Point3::new(0.2, -0.1, 2.0);
        assert_eq!(residual_squared(&id, &a, &a, &cam, &params), 0.0);
        // One pixel along x and one σ_z in depth: r² = 1 + 1 (the ray stays put when the
        // depth changes, so the pixel error is unchanged).
        let sz = 1.5e-3 * 4.0 + 0.003;
        let bz = 2.0 + sz;
        let b = Point3::new((0.1 + 1.0 / cam.fx) * bz, -0.05 * bz, bz);
        let r2 = residual_squared(&id, &a, &b, &cam, &params);
        // σ_z is taken at the target depth.
        let ez = (2.0 - bz) / (1.5e-3 * bz * bz + 0.003);
        assert!((r2 - (1.0 + ez * ez)).abs() < 1e-9, "{r2}");
        // Behind the camera, or a target without depth: infinite.
        let behind = se3([0.0; 3], [0.0, 0.0, -1.96]);
        assert_eq!(
            residual_squared(&behind, &a, &a, &cam, &params),
            f64::INFINITY
        );
        let no_depth = Point3::new(0.0, 0.0, 0.0);
        assert_eq!(
            residual_squared(&id, &a, &no_depth, &cam, &params),
            f64::INFINITY
        );
    }

    #[test]
    fn correspondences_use_the_undistorted_rays_and_the_subpixel_offset() {
        let cam = small_distorted_camera();
        let rays = camera_rays(&cam);
        let (w, h) = (cam.width, cam.height);
        let depth = FloatImage::from_fn(w, h, |x, _| image::Luma([1.0 + 0.01 * x as f32]));
        let mut depth_j = depth.clone();
        depth_j.put_pixel(12, 0, image::Luma([0.05])); // no usable depth at one target
        let flow = FlowField::constant(w, h, [0.25, -0.375]);
        // The stride is given at the camera's own focal length here: 4 px.
        let params = RigidityParams {
            reference_focal_px: cam.fx,
            ..Default::default()
        };
        let c = correspondences(&depth, &depth_j, &flow, &rays, &params).unwrap();
        // Grid rows y = 0 lose their targets (v2 < 0); the last grid column stays inside.
        assert!(
            c.pixels
                .iter()
                .all(|p| p[1] > 0 && p[0] % 4 == 0 && p[1] % 4 == 0)
        );
        assert_eq!(c.len(), (w / 4) as usize * (h / 4 - 1) as usize);
        for ((a, b), px) in c.source.iter().zip(&c.target).zip(&c.pixels) {
            let und = cam.undistort_point(&nalgebra::Point2::new(px[0] as f64, px[1] as f64));
            let z = 1.0 + 0.01 * px[0] as f32;
            assert!((a.z - z as f64).abs() < 1e-12);
            assert!((a.x / a.z - (und.x - cam.cx) / cam.fx).abs() < 1e-12);
            // Target: x + 0.25 rounds to x and y − 0.375 to y, plus the sub-pixel offset.
            let r = rays.ray(px[0], px[1]).unwrap();
            assert!((b.x / b.z - (r[0] + 0.25 / cam.fx)).abs() < 1e-12);
            assert!((b.y / b.z - (r[1] - 0.375 / cam.fy)).abs() < 1e-12);
            assert!((b.z - z as f64).abs() < 1e-12);
        }
        // A target without depth drops the pair.
        let c2 = correspondences(
            &depth,
            &depth_j,
            &FlowField::constant(w, h, [0.0, 0.0]),
            &rays,
            &params,
        )
        .unwrap();
        assert!(!c2.pixels.contains(&[12, 0]) && c2.pixels.contains(&[16, 0]));
        // Sizes must agree.
        let small = FloatImage::new(w - 1, h);
        assert!(matches!(
            correspondences(&small, &depth_j, &flow, &rays, &params),
            Err(MotionError::SizeMismatch { .. })
        ));
    }
}
