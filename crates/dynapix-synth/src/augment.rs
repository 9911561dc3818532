//! Augmentation of a real RGB-D sequence with virtual movers (`dynapix synth --augment`).
//!
//! The movers are posed in the sequence's ground-truth world frame, rendered with the same ray
//! caster into each frame's ground-truth camera and composited with a depth test against the
//! real depth: a mover pixel is shown where the real depth is missing or farther. The original
//! frames become `background/` and `depth_bg/`; the mover's depth is written into `depth/`;
//! `mask/` and `instance/` follow the synthetic conventions (0 / 128 / 255).
//!
//! The renderer is an ideal pinhole: for a distorted camera (TUM fr1) movers are composited in
//! the undistorted model with the distorted image's intrinsics. With fr1's small distortion this
//! shifts mover pixels by at most a few pixels near the image border; static pixels are never
//! touched, so mask-0 pixels keep the original bytes exactly.
//!
//! Placement: the real scene's floor is unknown, so movers are flying textured boxes and
//! spheres placed relative to the first ground-truth camera, in front of it at a fraction of
//! the median depth of the first frame, moving within a box a few decimetres wide.

use crate::SynthError;
use crate::movers::{Mover, MoverKind, PersonLook};
use crate::render::{self, Intrinsics, Layers, MOVER_BIT, NO_HIT, RenderParams};
use crate::scene::{Light, Scene};
use crate::sequence::Gray16Image;
use crate::shape::{Primitive, Shape};
use crate::texture::TextureKind;
use image::{GrayImage, RgbImage};
use nalgebra::{Isometry3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Settings of the augmentation.
#[derive(Clone, Debug)]
pub struct AugmentParams {
    /// Seed of the movers' shapes, textures and paths.
    pub seed: u64,
    /// Number of flying objects.
    pub objects: usize,
    /// Distance of the motion centre from the first camera, as a fraction of the first
    /// frame's median depth.
    pub depth_fraction: f32,
    /// Size of the objects relative to that distance.
    pub size_fraction: f32,
    /// Per-frame displacement (m) above which a mover pixel counts as moving.
    pub moving_threshold: f32,
    /// Renderer settings.
    pub render: RenderParams,
}

impl Default for AugmentParams {
    fn default() -> Self {
        Self {
            seed: 0,
            objects: 3,
            depth_fraction: 0.6,
            size_fraction: 0.09,
            moving_threshold: 0.0005,
            render: RenderParams::default(),
        }
    }
}

/// Movers and their materials, placed in a real sequence's world frame.
#[derive(Clone, Debug)]
pub struct Augmenter {
    /// Settings.
    pub params: AugmentParams,
    scene: Scene,
    movers: Vec<Mover>,
}

/// One composited frame.
#[derive(Clone, Debug)]
pub struct Composite {
    /// Colour with movers.
    pub rgb: RgbImage,
    /// Raw depth with movers (same units as the input).
    pub depth: Gray16Image,
    /// Motion mask 0 / 128 / 255.
    pub mask: GrayImage,
    /// Instance ids (0 = real scene, k + 1 = mover k).
    pub instance: Gray16Image,
}

impl Augmenter {
    /// Places movers in front of the first camera `first_pose` (camera-to-world), whose frame
    /// has median depth `median_depth` (m).
    pub fn new(
        params: AugmentParams,
        first_pose: &Isometry3<f64>,
        median_depth: f32,
    ) -> Result<Self, SynthError> {
        if !(median_depth.is_finite() && median_depth > 0.0) {
            return Err(SynthError::InvalidParams(format!(
                "median depth {median_depth} of the first frame is not usable"
            )));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(params.seed ^ 0xA06E_0000_0000_0004);
        let mut scene = Scene::empty();
        let pose = first_pose.cast::<f32>();
        let cam_pos = pose.translation.vector;
        // A light above and behind the camera (its -y is roughly up), plus a strong ambient,
        // so that movers are lit from the viewer's side like the real scene.
        let up = pose.rotation * Vector3::new(0.0, -1.0, 0.0);
        scene.lights = vec![Light {
            position: Point3::from(cam_pos + up * 0.8 - pose.rotation * Vector3::z() * 0.3),
            intensity: 0.6,
            falloff: 3.0,
        }];
        scene.ambient = 0.55;
        let dist = median_depth * params.depth_fraction;
        let size = dist * params.size_fraction;
        let centre_cam = Vector3::new(0.0, 0.0, dist);
        let kinds = [
            TextureKind::Poster,
            TextureKind::Mosaic,
            TextureKind::Checker,
        ];
        let mut movers = Vec::new();
        for k in 0..params.objects {
            let m = scene.add_material(
                kinds[k % kinds.len()],
                128,
                [size * 3.0, size * 3.0],
                &mut rng,
            );
            let shape = if k % 2 == 0 {
                Shape::Box {
                    half: Vector3::new(
                        size * rng.random_range(0.7..1.2),
                        size * rng.random_range(0.7..1.2),
                        size * rng.random_range(0.7..1.2),
                    ),
                }
            } else {
                Shape::Sphere {
                    r: size * rng.random_range(0.8..1.2),
                }
            };
            // Motion box in the first camera's frame, mapped to the world.
            let offset = Vector3::new(
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.2..0.2),
                rng.random_range(-0.15..0.15),
            ) * dist;
            let centre = pose * Point3::from(centre_cam + offset);
            let amp_cam = Vector3::new(0.35 * dist, 0.2 * dist, 0.15 * dist);
            // Amplitudes along world axes: the camera box rotated, as absolute values.
            let r = pose.rotation.to_rotation_matrix();
            let amplitude = (r.matrix().abs()) * amp_cam;
            let spin = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(0.2..1.0),
            );
            movers.push(Mover {
                kind: MoverKind::Flyer {
                    shape,
                    centre: centre.coords,
                    amplitude,
                    omega: Vector3::new(
                        rng.random_range(0.6..1.1),
                        rng.random_range(0.5..0.9),
                        rng.random_range(0.4..0.8),
                    ),
                    phase: Vector3::new(
                        rng.random_range(0.0..std::f32::consts::TAU),
                        rng.random_range(0.0..std::f32::consts::TAU),
                        rng.random_range(0.0..std::f32::consts::TAU),
                    ),
                    spin: (spin, rng.random_range(0.5..1.2)),
                },
                look: PersonLook {
                    shirt: m,
                    trousers: m,
                    skin: m,
                    head: m,
                },
            });
        }
        Ok(Self {
            params,
            scene,
            movers,
        })
    }

    fn parts_at(&self, t: f64) -> Vec<Primitive> {
        let mut parts = Vec::new();
        for m in &self.movers {
            m.parts(t as f32, &mut parts);
        }
        parts
    }

    /// Composites the movers at time `t` (relative to the sequence start) into a real frame
    /// with camera-to-world pose `pose`, raw depth `depth` (units per metre `depth_factor`).
    /// `dt` is the frame period used for the moving/still decision.
    #[allow(clippy::too_many_arguments)]
    pub fn composite(
        &self,
        k: &Intrinsics,
        t: f64,
        dt: f64,
        pose: &Isometry3<f64>,
        rgb: &RgbImage,
        depth: &Gray16Image,
        depth_factor: f32,
    ) -> Composite {
        let parts = self.parts_at(t);
        let prev = self.parts_at(t - dt);
        let next = self.parts_at(t + dt);
        let cam = pose.cast::<f32>();
        let mut layers = Layers::default();
        render::render(
            &self.scene,
            &self.params.render,
            k,
            &cam,
            &parts,
            &mut layers,
        );
        let mut out_rgb = rgb.clone();
        let mut out_depth = depth.clone();
        let (w, h) = (k.width, k.height);
        let mut mask = GrayImage::new(w as u32, h as u32);
        let mut instance = Gray16Image::new(w as u32, h as u32);
        let rot = cam.rotation.to_rotation_matrix().into_inner();
        let centre = cam.translation.vector;
        let owner: Vec<u16> = {
            let mut o = Vec::new();
            for (mi, m) in self.movers.iter().enumerate() {
                o.extend(std::iter::repeat_n(mi as u16, m.part_count()));
            }
            o
        };
        for y in 0..h {
            for x in 0..w {
                let j = y * w + x;
                let id = layers.id[j];
                if id == NO_HIT || id & MOVER_BIT == 0 {
                    continue;
                }
                let z = layers.depth[j];
                let real = depth.get_pixel(x as u32, y as u32)[0];
                let real_z = real as f32 / depth_factor;
                if real != 0 && real_z <= z {
                    continue;
                }
                let part = (id & !MOVER_BIT) as usize;
                let c = layers.rgb[j];
                out_rgb.put_pixel(
                    x as u32,
                    y as u32,
                    image::Rgb(c.map(|v| (v * 255.0).round().clamp(0.0, 255.0) as u8)),
                );
                let raw = (z * depth_factor).round();
                out_depth.put_pixel(
                    x as u32,
                    y as u32,
                    image::Luma([if raw > 0.0 && raw <= u16::MAX as f32 {
                        raw as u16
                    } else {
                        0
                    }]),
                );
                let dc = Vector3::new((x as f32 - k.cx) / k.fx, (y as f32 - k.cy) / k.fy, 1.0);
                let xw = Point3::from(centre + rot * dc * z);
                let moving = match (parts.get(part), prev.get(part), next.get(part)) {
                    (Some(cur), Some(a), Some(b)) => {
                        let xl = cur.pose.inverse_transform_point(&xw);
                        ((a.pose * xl) - xw).norm() > self.params.moving_threshold
                            || ((b.pose * xl) - xw).norm() > self.params.moving_threshold
                    }
                    _ => false,
                };
                mask.put_pixel(
                    x as u32,
                    y as u32,
                    image::Luma([if moving { 255 } else { 128 }]),
                );
                instance.put_pixel(
                    x as u32,
                    y as u32,
                    image::Luma([owner.get(part).map_or(0, |&o| o + 1)]),
                );
            }
        }
        Composite {
            rgb: out_rgb,
            depth: out_depth,
            mask,
            instance,
        }
    }
}

/// Median of the valid (non-zero) raw depths, in metres.
pub fn median_depth(depth: &Gray16Image, depth_factor: f32) -> Option<f32> {
    let mut v: Vec<u16> = depth.as_raw().iter().copied().filter(|&d| d > 0).collect();
    let m = dynapix_geometry::stats::upper_median_by(&mut v, u16::cmp)?;
    Some(m as f32 / depth_factor)
}
