//! The RGB-D camera in ORB-SLAM2's virtual-stereo form (intrinsics, distortion, `bf`, close/far
//! depth threshold), the undistorted image bounds, and the optimiser's camera built from it.

use dynapix_geometry::PinholeCamera;
use dynapix_optim::StereoCamera;
use nalgebra::Vector3;

/// An RGB-D camera in ORB-SLAM2's virtual-stereo form.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RgbdCamera {
    /// Intrinsics and distortion.
    pub pinhole: PinholeCamera,
    /// Baseline × fx (`Camera.bf`).
    pub bf: f64,
    /// Close/far threshold in metres (`ThDepth · bf / fx`).
    pub th_depth: f64,
    /// Frame rate (`Camera.fps`), sets keyframe and relocalisation windows.
    pub fps: f64,
    /// Depths above this (metres) are treated as missing (guards against absurd depth).
    pub max_depth: f64,
}

impl RgbdCamera {
    /// Builds a camera from settings values (`th_depth_factor` is the settings `ThDepth`).
    pub fn new(pinhole: PinholeCamera, bf: f64, th_depth_factor: f64, fps: f64) -> Self {
        let th_depth = if pinhole.fx > 0.0 {
            bf * th_depth_factor / pinhole.fx
        } else {
            0.0
        };
        Self {
            pinhole,
            bf,
            th_depth,
            fps,
            max_depth: 20.0,
        }
    }

    /// Stereo baseline in metres (bf / fx).
    pub fn baseline(&self) -> f64 {
        self.bf / self.pinhole.fx
    }

    /// Undistorts a pixel (OpenCV `undistortPoints` model, iterated to convergence).
    pub fn undistort(&self, u: f64, v: f64) -> (f64, f64) {
        let c = &self.pinhole;
        if !c.is_distorted() {
            return (u, v);
        }
        let [k1, k2, p1, p2, k3] = c.dist;
        let xd = (u - c.cx) / c.fx;
        let yd = (v - c.cy) / c.fy;
        let (mut x, mut y) = (xd, yd);
        for _ in 0..20 {
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
            if radial.abs() < 1e-12 {
                break;
            }
            let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
            let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
            let nx = (xd - dx) / radial;
            let ny = (yd - dy) / radial;
            let done = (nx - x).abs() < 1e-10 && (ny - y).abs() < 1e-10;
            x = nx;
            y = ny;
            if done {
                break;
            }
        }
        (x * c.fx + c.cx, y * c.fy + c.cy)
    }

    /// Bounds of the undistorted image (ORB-SLAM2 `ComputeImageBounds`).
    pub fn image_bounds(&self) -> ImageBounds {
        let w = self.pinhole.width as f64;
        let h = self.pinhole.height as f64;
        if !self.pinhole.is_distorted() {
            return ImageBounds {
                min_x: 0.0,
                max_x: w as f32,
                min_y: 0.0,
                max_y: h as f32,
            };
        }
        let c0 = self.undistort(0.0, 0.0);
        let c1 = self.undistort(w, 0.0);
        let c2 = self.undistort(0.0, h);
        let c3 = self.undistort(w, h);
        ImageBounds {
            min_x: c0.0.min(c2.0) as f32,
            max_x: c1.0.max(c3.0) as f32,
            min_y: c0.1.min(c1.1) as f32,
            max_y: c2.1.max(c3.1) as f32,
        }
    }

    /// Stereo (u, v, uR) projection of a camera-frame point; None behind the camera.
    pub fn project(&self, pc: &Vector3<f64>) -> Option<(f64, f64, f64)> {
        if pc.z <= 0.0 {
            return None;
        }
        let inv_z = 1.0 / pc.z;
        let u = self.pinhole.fx * pc.x * inv_z + self.pinhole.cx;
        let v = self.pinhole.fy * pc.y * inv_z + self.pinhole.cy;
        Some((u, v, u - self.bf * inv_z))
    }
}

/// Undistorted image bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageBounds {
    /// Minimum x.
    pub min_x: f32,
    /// Maximum x.
    pub max_x: f32,
    /// Minimum y.
    pub min_y: f32,
    /// Maximum y.
    pub max_y: f32,
}

impl ImageBounds {
    /// True when (u, v) lies inside the bounds (ORB-SLAM2 `IsInImage`, half-open).
    pub fn contains(&self, u: f64, v: f64) -> bool {
        u >= self.min_x as f64
            && u < self.max_x as f64
            && v >= self.min_y as f64
            && v < self.max_y as f64
    }
}

/// The optimiser's camera from the RGB-D camera.
pub fn stereo_camera(cam: &RgbdCamera) -> StereoCamera {
    StereoCamera {
        fx: cam.pinhole.fx,
        fy: cam.pinhole.fy,
        cx: cam.pinhole.cx,
        cy: cam.pinhole.cy,
        bf: cam.bf,
    }
}
