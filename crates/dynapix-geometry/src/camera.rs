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

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

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
