//! Pinhole camera with the OpenCV radial-tangential distortion model (k1, k2, p1, p2, k3),
//! as used by ORB-SLAM2 settings files and the TUM RGB-D cameras.
//!
//! Distortion acts on normalised coordinates (x, y) = (X/Z, Y/Z):
//! `x_d = x·(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²)`,
//! `y_d = y·(1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y`.
//! [`PinholeCamera::undistort_point`] inverts this like OpenCV's `undistortPoints` with the
//! camera matrix as new projection (input and output in pixels), but iterates to convergence
//! (Newton steps) instead of OpenCV's fixed five fixed-point steps, so strong distortion such
//! as TUM fr1's is inverted to 1e-9 px.

use nalgebra::{Matrix2, Point2, Point3, Vector2};
use serde::{Deserialize, Serialize};

/// Iteration limit of the undistortion solver.
const UNDISTORT_MAX_ITERS: usize = 30;
/// Convergence threshold of the undistortion solver, in normalised coordinates
/// (≈ 5e-10 px for focal lengths near 500 px).
const UNDISTORT_TOL: f64 = 1e-12;

/// Intrinsics of a pinhole camera with optional radial-tangential distortion.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PinholeCamera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Distortion `[k1, k2, p1, p2, k3]` (all zero for an ideal pinhole).
    pub dist: [f64; 5],
}

impl PinholeCamera {
    /// An ideal (undistorted) pinhole camera.
    pub fn new(width: u32, height: u32, fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Self {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            dist: [0.0; 5],
        }
    }

    /// TUM fr3 intrinsics (no distortion), the default camera of synthetic sequences.
    pub fn tum_fr3() -> Self {
        Self::new(640, 480, 535.4, 539.2, 320.1, 247.6)
    }

    /// The same camera for images of `width × height`: `fx`, `cx` scaled by
    /// `width / self.width`, `fy`, `cy` by `height / self.height`, distortion kept.
    pub fn resized(&self, width: u32, height: u32) -> Self {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Self {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            dist: self.dist,
        }
    }

    /// True when any distortion coefficient is non-zero.
    pub fn is_distorted(&self) -> bool {
        self.dist.iter().any(|&d| d != 0.0)
    }

    /// Projects a camera-frame point with the ideal pinhole model (no distortion).
    /// Returns `None` for points at or behind the camera centre.
    pub fn project(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        if p.z <= 0.0 {
            return None;
        }
        Some(Point2::new(
            self.fx * p.x / p.z + self.cx,
            self.fy * p.y / p.z + self.cy,
        ))
    }

    /// Back-projects an undistorted pixel with depth `z` (metres along the optical axis).
    pub fn unproject(&self, uv: &Point2<f64>, z: f64) -> Point3<f64> {
        Point3::new(
            (uv.x - self.cx) / self.fx * z,
            (uv.y - self.cy) / self.fy * z,
            z,
        )
    }

    /// Projects a camera-frame point through the lens distortion to a raw image pixel.
    /// Returns `None` for points at or behind the camera centre.
    pub fn project_distorted(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        if p.z <= 0.0 {
            return None;
        }
        let d = self.distort_normalized(&Vector2::new(p.x / p.z, p.y / p.z));
        Some(self.to_pixel(&d))
    }

    /// Maps an undistorted (ideal pinhole) pixel to the raw, distorted pixel.
    pub fn distort(&self, uv: &Point2<f64>) -> Point2<f64> {
        let d = self.distort_normalized(&self.to_normalized(uv));
        self.to_pixel(&d)
    }

    /// Maps a raw (distorted) pixel to the undistorted pixel (OpenCV `undistortPoints` with
    /// `P = K`). Best effort: if the solver does not converge (points far outside the
    /// calibrated field), the last iterate is returned; use [`Self::try_undistort_point`] to
    /// detect that.
    pub fn undistort_point(&self, uv: &Point2<f64>) -> Point2<f64> {
        match self.solve_undistort(uv) {
            Ok(p) | Err(p) => p,
        }
    }

    /// Like [`Self::undistort_point`] but `None` when the iteration did not converge.
    pub fn try_undistort_point(&self, uv: &Point2<f64>) -> Option<Point2<f64>> {
        self.solve_undistort(uv).ok()
    }

    /// Distortion in normalised coordinates.
    #[inline]
    pub fn distort_normalized(&self, x: &Vector2<f64>) -> Vector2<f64> {
        let [k1, k2, p1, p2, k3] = self.dist;
        let r2 = x.x * x.x + x.y * x.y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        Vector2::new(
            x.x * radial + 2.0 * p1 * x.x * x.y + p2 * (r2 + 2.0 * x.x * x.x),
            x.y * radial + p1 * (r2 + 2.0 * x.y * x.y) + 2.0 * p2 * x.x * x.y,
        )
    }

    /// Jacobian of [`Self::distort_normalized`] with respect to the normalised point.
    pub fn distort_jacobian(&self, x: &Vector2<f64>) -> Matrix2<f64> {
        let [k1, k2, p1, p2, k3] = self.dist;
        let (u, v) = (x.x, x.y);
        let r2 = u * u + v * v;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        // d(radial)/d(r²)
        let dr = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
        Matrix2::new(
            radial + 2.0 * u * u * dr + 2.0 * p1 * v + 6.0 * p2 * u,
            2.0 * u * v * dr + 2.0 * p1 * u + 2.0 * p2 * v,
            2.0 * u * v * dr + 2.0 * p1 * u + 2.0 * p2 * v,
            radial + 2.0 * v * v * dr + 6.0 * p1 * v + 2.0 * p2 * u,
        )
    }

    fn to_normalized(&self, uv: &Point2<f64>) -> Vector2<f64> {
        Vector2::new((uv.x - self.cx) / self.fx, (uv.y - self.cy) / self.fy)
    }

    #[inline]
    fn to_pixel(&self, x: &Vector2<f64>) -> Point2<f64> {
        Point2::new(self.fx * x.x + self.cx, self.fy * x.y + self.cy)
    }

    /// Newton iteration on `distort(x) = x_d`, started at `x_d` (OpenCV's starting point).
    fn solve_undistort(&self, uv: &Point2<f64>) -> Result<Point2<f64>, Point2<f64>> {
        let target = self.to_normalized(uv);
        if !self.is_distorted() {
            return Ok(*uv);
        }
        let mut x = target;
        for _ in 0..UNDISTORT_MAX_ITERS {
            let r = self.distort_normalized(&x) - target;
            if r.norm() < UNDISTORT_TOL {
                return Ok(self.to_pixel(&x));
            }
            let Some(step) = self.distort_jacobian(&x).lu().solve(&r) else {
                return Err(self.to_pixel(&x));
            };
            x -= step;
            if !x.x.is_finite() || !x.y.is_finite() {
                return Err(self.to_pixel(&target));
            }
        }
        let r = self.distort_normalized(&x) - target;
        if r.norm() < UNDISTORT_TOL * 1e3 {
            Ok(self.to_pixel(&x))
        } else {
            Err(self.to_pixel(&x))
        }
    }
}

/// How far beyond the outermost ray of the image (relative radius) points are still
/// distorted by [`PixelRays::project`]: enough for points that land just outside the frame,
/// well short of where a polynomial lens model folds back onto the image.
const PROJECT_RADIUS_MARGIN: f64 = 1.1;

/// The undistorted viewing ray of every pixel of a camera's raw image, computed once so that
/// per-pixel loops (splatting, background reconstruction) back-project with a table look-up
/// instead of an iterative undistortion.
///
/// Ray `(x_n, y_n)` of pixel `(u, v)` is the normalised coordinate (X/Z, Y/Z) of the points
/// the pixel sees: `undistort_point((u, v))` in normalised units. A pixel whose undistortion
/// does not converge gets no ray.
#[derive(Clone, Debug, PartialEq)]
pub struct PixelRays {
    camera: PinholeCamera,
    /// Row-major normalised rays, NaN where the undistortion failed.
    rays: Vec<[f64; 2]>,
    /// Largest squared normalised radius [`PixelRays::project`] distorts.
    max_r2: f64,
}

impl PixelRays {
    /// Computes the rays of every pixel of `camera` (`width × height` undistortions).
    pub fn new(camera: &PinholeCamera) -> Self {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let mut rays = Vec::with_capacity(w * h);
        let mut image_r2 = 0.0f64;
        for y in 0..h {
            for x in 0..w {
                let ray = camera
                    .try_undistort_point(&Point2::new(x as f64, y as f64))
                    .map_or([f64::NAN; 2], |p| {
                        [(p.x - camera.cx) / camera.fx, (p.y - camera.cy) / camera.fy]
                    });
                let r2 = ray[0] * ray[0] + ray[1] * ray[1];
                if r2.is_finite() {
                    image_r2 = image_r2.max(r2);
                }
                rays.push(ray);
            }
        }
        let max_r2 = camera.monotonic_r2(image_r2 * PROJECT_RADIUS_MARGIN * PROJECT_RADIUS_MARGIN);
        Self {
            camera: camera.clone(),
            rays,
            max_r2,
        }
    }

    /// The camera the rays belong to.
    pub fn camera(&self) -> &PinholeCamera {
        &self.camera
    }

    /// The normalised ray of pixel `(x, y)`; `None` outside the image or where the
    /// undistortion did not converge.
    pub fn ray(&self, x: u32, y: u32) -> Option<[f64; 2]> {
        if x >= self.camera.width || y >= self.camera.height {
            return None;
        }
        let r = self.rays[y as usize * self.camera.width as usize + x as usize];
        r[0].is_finite().then_some(r)
    }

    /// Every pixel's ray, row by row (`width × height`, NaN where the undistortion failed).
    pub fn all(&self) -> &[[f64; 2]] {
        &self.rays
    }

    /// The rays of image row `y` (NaN where the undistortion failed); empty outside the image.
    pub fn row(&self, y: u32) -> &[[f64; 2]] {
        if y >= self.camera.height {
            return &[];
        }
        let w = self.camera.width as usize;
        &self.rays[y as usize * w..(y as usize + 1) * w]
    }

    /// Largest squared normalised radius that [`PixelRays::project`] accepts: 10 % beyond the
    /// image's outermost ray, or less where the radial distortion stops being monotonic.
    pub fn max_r2(&self) -> f64 {
        self.max_r2
    }

    /// Projects a camera-frame point through the distortion to a raw pixel, like
    /// [`PinholeCamera::project_distorted`], but `None` for points whose normalised radius
    /// exceeds [`PixelRays::max_r2`], which the polynomial model could fold back into view.
    #[inline]
    pub fn project(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        if p.z <= 0.0 {
            return None;
        }
        let x = Vector2::new(p.x / p.z, p.y / p.z);
        // NaN radii fail the comparison and are refused as well.
        let inside = x.norm_squared() <= self.max_r2;
        if !inside {
            return None;
        }
        let d = self.camera.distort_normalized(&x);
        Some(self.camera.to_pixel(&d))
    }
}

impl PinholeCamera {
    /// The largest squared radius up to `limit` over which the radial part of the distortion,
    /// `r·(1 + k1 r² + k2 r⁴ + k3 r⁶)`, keeps increasing (sampled finely).
    fn monotonic_r2(&self, limit: f64) -> f64 {
        let [k1, k2, _, _, k3] = self.dist;
        let slope = |r2: f64| 1.0 + r2 * (3.0 * k1 + r2 * (5.0 * k2 + r2 * 7.0 * k3));
        const STEPS: usize = 1000;
        for i in 1..=STEPS {
            let r2 = limit * i as f64 / STEPS as f64;
            if slope(r2) <= 0.0 {
                return limit * (i - 1) as f64 / STEPS as f64;
            }
        }
        limit
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn resizing_scales_projections_and_keeps_rays() {
        let c = PinholeCamera::tum_fr3();
        assert_eq!(c.resized(c.width, c.height), c);
        let half = c.resized(320, 240);
        assert_eq!((half.width, half.height), (320, 240));
        for p in [
            Point3::new(0.3, -0.2, 2.0),
            Point3::new(-1.0, 0.5, 4.5),
            Point3::new(0.0, 0.0, 1.0),
        ] {
            let a = c.project(&p).unwrap();
            let b = half.project(&p).unwrap();
            assert!((a.x * 0.5 - b.x).abs() < 1e-9 && (a.y * 0.5 - b.y).abs() < 1e-9);
            // The ray through a pixel is the ray through the scaled pixel.
            let q = half.unproject(&b, p.z);
            assert!((q - p).norm() < 1e-9);
        }
    }

    #[test]
    fn pixel_rays_are_the_undistorted_pixels() {
        let c = fr1();
        let rays = PixelRays::new(&c);
        assert_eq!(rays.camera(), &c);
        for (x, y) in [(0u32, 0u32), (639, 479), (320, 240), (17, 400)] {
            let r = rays.ray(x, y).expect("converges");
            let und = c.undistort_point(&Point2::new(x as f64, y as f64));
            assert!((r[0] - (und.x - c.cx) / c.fx).abs() < 1e-15);
            assert!((r[1] - (und.y - c.cy) / c.fy).abs() < 1e-15);
            assert_eq!(rays.row(y)[x as usize], r);
            // Back-project at any depth and project again: the same raw pixel.
            let p = Point3::new(r[0] * 2.5, r[1] * 2.5, 2.5);
            let back = rays.project(&p).expect("inside");
            assert!((back - Point2::new(x as f64, y as f64)).norm() < 1e-9);
        }
        assert!(rays.ray(640, 0).is_none() && rays.row(480).is_empty());
        // Far outside the field of view the polynomial would fold back: refused.
        assert!(rays.project(&Point3::new(3.0, 0.0, 1.0)).is_none());
        assert!(rays.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
        // A lens that folds inside the margin is cut where its slope vanishes.
        let mut fold = PinholeCamera::new(100, 100, 50.0, 50.0, 49.5, 49.5);
        fold.dist = [0.0, -0.5, 0.0, 0.0, 0.0];
        let r = PixelRays::new(&fold);
        // The slope 1 − 5·0.5·r⁴ vanishes at r² = √0.4 ≈ 0.632; the image's rays reach about
        // that far, so the 10 % margin alone would go past the fold.
        assert!((r.max_r2() - 0.4f64.sqrt()).abs() < 2e-3, "{}", r.max_r2());
    }

    /// TUM fr1 camera (strong distortion), from the dataset README.
    fn fr1() -> PinholeCamera {
        let mut c = PinholeCamera::new(640, 480, 517.306408, 516.469215, 318.643040, 255.313989);
        c.dist = [0.262383, -0.953104, -0.005358, 0.002628, 1.163314];
        c
    }

    #[test]
    fn ideal_camera_is_identity() {
        let c = PinholeCamera::tum_fr3();
        let p = Point2::new(12.5, 400.25);
        assert_eq!(c.distort(&p), p);
        assert_eq!(c.undistort_point(&p), p);
        let x = Point3::new(0.3, -0.2, 2.0);
        assert_eq!(c.project(&x), c.project_distorted(&x));
    }

    #[test]
    fn corner_of_fr1_image_round_trips() {
        let c = fr1();
        for (u, v) in [(0.0, 0.0), (639.0, 479.0), (0.0, 479.0), (320.0, 240.0)] {
            let raw = Point2::new(u, v);
            let und = c.try_undistort_point(&raw).expect("converges");
            assert!((c.distort(&und) - raw).norm() < 1e-9);
        }
    }

    #[test]
    fn distortion_jacobian_matches_numeric() {
        let c = fr1();
        let x = Vector2::new(0.31, -0.22);
        let h = 1e-7;
        let j = c.distort_jacobian(&x);
        for k in 0..2 {
            let mut d = Vector2::zeros();
            d[k] = h;
            let num = (c.distort_normalized(&(x + d)) - c.distort_normalized(&(x - d))) / (2.0 * h);
            assert!((j.column(k) - num).norm() < 1e-7);
        }
    }

    proptest! {
        #[test]
        fn prop_distort_undistort_round_trip(u in 0.0f64..640.0, v in 0.0f64..480.0) {
            let c = fr1();
            let raw = Point2::new(u, v);
            let und = c.try_undistort_point(&raw);
            prop_assert!(und.is_some());
            let und = und.unwrap_or(raw);
            prop_assert!((c.distort(&und) - raw).norm() < 1e-9);
        }

        #[test]
        fn prop_undistort_distort_round_trip(u in 40.0f64..600.0, v in 40.0f64..440.0) {
            let c = fr1();
            let ideal = Point2::new(u, v);
            let back = c.undistort_point(&c.distort(&ideal));
            prop_assert!((back - ideal).norm() < 1e-9);
        }

        #[test]
        fn prop_project_distorted_is_distort_of_project(
            x in -1.0f64..1.0, y in -0.8f64..0.8, z in 0.5f64..5.0
        ) {
            let c = fr1();
            let p = Point3::new(x * z * 0.5, y * z * 0.5, z);
            let a = c.project_distorted(&p);
            let b = c.project(&p).map(|q| c.distort(&q));
            prop_assert!(a.is_some() && b.is_some());
            if let (Some(a), Some(b)) = (a, b) {
                prop_assert!((a - b).norm() < 1e-9);
                let back = c.unproject(&c.undistort_point(&a), z);
                prop_assert!((back - p).norm() < 1e-9);
            }
        }
    }
}
