//! Test helpers: a ray-cast synthetic scene (textured wall, a box, an optional moving panel;
//! rendered through the lens distortion of the camera, if any)
//! and a brute-force block-matching flow, so the algorithms can be tested without data files.

use dynapix_flow::{FlowError, FlowField, FlowProvider};
use dynapix_geometry::{PinholeCamera, Se3};
use image::{GrayImage, Rgb, RgbImage};
use nalgebra::{Point3, Vector3};

use crate::FloatImage;

/// A 96×72 camera, 80 px focal length.
pub fn small_camera() -> PinholeCamera {
    PinholeCamera::new(96, 72, 80.0, 80.0, 47.5, 35.5)
}

/// [`small_camera`] with the strong radial-tangential distortion of the TUM fr1 Kinect
/// (a few pixels of displacement towards the corners of this small image).
pub fn small_distorted_camera() -> PinholeCamera {
    let mut c = small_camera();
    c.dist = [0.262383, -0.953104, -0.005358, 0.002628, 1.163314];
    c
}

/// Fronto-parallel rectangles at fixed world depth.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Depth of the back wall (world z).
    pub wall_z: f64,
}

impl Default for Scene {
    fn default() -> Self {
        Self { wall_z: 3.0 }
    }
}

fn texture(x: f64, y: f64, seed: f64) -> [u8; 3] {
    use std::f64::consts::TAU;
    let mut out = [0u8; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let ph = seed + c as f64 * 1.3;
        let v = 128.0
            + 55.0 * (TAU * x / 0.37 + ph).sin() * (TAU * y / 0.29 + 0.5 * ph).cos()
            + 35.0 * (TAU * (x + 0.6 * y) / 0.8 + ph).sin();
        *o = v.round().clamp(0.0, 255.0) as u8;
    }
    out
}

impl Scene {
    /// Renders colour and depth from camera pose `t_wc`. The mover is a panel at world z = 1.5
    /// centred at x = `mover_x` whose texture moves with it.
    pub fn render(
        &self,
        cam: &PinholeCamera,
        t_wc: &Se3,
        with_mover: bool,
        mover_x: f64,
    ) -> (RgbImage, FloatImage) {
        let mut img = RgbImage::new(cam.width, cam.height);
        let mut depth = FloatImage::new(cam.width, cam.height);
        let o = t_wc.translation.vector;
        for y in 0..cam.height {
            for x in 0..cam.width {
                // A distorted camera sees along the undistorted ray of each raw pixel.
                let (ux, uy) = if cam.is_distorted() {
                    let p = cam.undistort_point(&nalgebra::Point2::new(x as f64, y as f64));
                    (p.x, p.y)
                } else {
                    (x as f64, y as f64)
                };
                let dc = Vector3::new((ux - cam.cx) / cam.fx, (uy - cam.cy) / cam.fy, 1.0);
                let dw = t_wc.rotation * dc;
                let hit = |z: f64| -> Option<(f64, Point3<f64>)> {
                    let s = (z - o.z) / dw.z;
                    (s > 0.0).then(|| (s, Point3::from(o + s * dw)))
                };
                let mut best: Option<(f64, [u8; 3])> = None;
                let mut consider = |s: f64, c: [u8; 3]| {
                    if best.is_none_or(|(b, _)| s < b) {
                        best = Some((s, c));
                    }
                };
                if let Some((s, p)) = hit(self.wall_z) {
                    consider(s, texture(p.x, p.y, 0.0));
                }
                if let Some((s, p)) = hit(2.0)
                    && (-0.45..0.05).contains(&p.x)
                    && (-0.3..0.3).contains(&p.y)
                {
                    consider(s, texture(p.x, p.y, 2.0));
                }
                if with_mover
                    && let Some((s, p)) = hit(1.5)
                    && (p.x - mover_x).abs() < 0.15
                    && (-0.25..0.35).contains(&p.y)
                {
                    consider(s, texture(p.x - mover_x, p.y, 4.0));
                }
                if let Some((s, c)) = best {
                    img.put_pixel(x, y, Rgb(c));
                    depth.put_pixel(x, y, image::Luma([s as f32]));
                }
            }
        }
        (img, depth)
    }
}

/// Exhaustive integer block matching (sum of absolute differences over a square patch),
/// preferring the smallest displacement on ties so that flat areas give zero flow.
pub struct BlockFlow {
    /// Search radius in pixels.
    pub radius: i32,
    /// Patch half size.
    pub half: i32,
}

impl FlowProvider for BlockFlow {
    fn flow(&self, a: &GrayImage, b: &GrayImage) -> Result<FlowField, FlowError> {
        if a.dimensions() != b.dimensions() {
            return Err(FlowError::SizeMismatch {
                a: a.dimensions(),
                b: b.dimensions(),
            });
        }
        let (w, h) = (a.width() as i32, a.height() as i32);
        let px = |img: &GrayImage, x: i32, y: i32| {
            img.get_pixel(x.clamp(0, w - 1) as u32, y.clamp(0, h - 1) as u32)
                .0[0] as i32
        };
        let mut f = FlowField::zeros(a.width(), a.height());
        for y in 0..h {
            for x in 0..w {
                let mut best = (i32::MAX, i32::MAX, 0, 0);
                for dy in -self.radius..=self.radius {
                    for dx in -self.radius..=self.radius {
                        let mut sad = 0;
                        for ky in -self.half..=self.half {
                            for kx in -self.half..=self.half {
                                sad +=
                                    (px(a, x + kx, y + ky) - px(b, x + dx + kx, y + dy + ky)).abs();
                            }
                        }
                        let key = (sad, dx * dx + dy * dy, dx, dy);
                        if (key.0, key.1) < (best.0, best.1) {
                            best = key;
                        }
                    }
                }
                f.data[(y * w + x) as usize] = [best.2 as f32, best.3 as f32];
            }
        }
        Ok(f)
    }
}
