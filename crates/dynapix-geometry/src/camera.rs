//! Pinhole camera with the OpenCV radial-tangential distortion model (k1, k2, p1, p2, k3),
//! as used by ORB-SLAM2 settings files and the TUM RGB-D cameras.

use nalgebra::{Point2, Point3};
use serde::{Deserialize, Serialize};

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
}
