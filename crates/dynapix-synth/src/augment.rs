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
//! Placement: the real scene's floor is unknown, so movers are placed relative to the first
//! ground-truth camera, in front of it at a fraction `d` of the median depth of the first
//! frame: flying textured boxes and spheres moving within a box a few decimetres wide, and
//! optionally the hard-scene kinds of issue 33 (see [`crate::hard`]): boxes that rest on the
//! optical axis for `box_rest` s and are then pushed sideways across the view and rest again
//! (back and forth), balls thrown across the view (3.5 m/s) and a crowd of people walking
//! across the view at 1–2 `d`. These use a level "stage" frame: up is the world's +z when the
//! camera's down axis points mostly along −z (TUM's motion-capture frame), else the camera's
//! −y; people stand on a floor 1.35 m below the first camera.

use crate::SynthError;
use crate::movers::{Mover, MoverKind, Path, PersonLook};
use crate::render::{self, Intrinsics, Layers, MOVER_BIT, NO_HIT, RenderParams};
use crate::scene::{Light, Scene};
use crate::script::{BoxPlace, CarriedBox, Script, Throw};
use crate::sequence::Gray16Image;
use crate::shape::{Primitive, Shape};
use crate::texture::TextureKind;
use image::{GrayImage, RgbImage};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
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
    /// Number of boxes that rest and are then pushed across the view (and back).
    pub boxes: usize,
    /// Seconds a box rests between pushes.
    pub box_rest: f32,
    /// Number of balls thrown back and forth across the view.
    pub balls: usize,
    /// Number of people walking across the view (a crowd close to the camera).
    pub crowd: usize,
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
            boxes: 0,
            box_rest: 3.0,
            balls: 0,
            crowd: 0,
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
    /// Per mover: its frame (stage) to world; the flying objects are posed in the world.
    stages: Vec<Isometry3<f32>>,
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
        let mut stages = vec![Isometry3::identity(); movers.len()];
        let stage_rot = level_frame(&pose);
        let hard = HardMovers {
            dist,
            half_width: dist * 0.5 * k_width_ratio(),
        };
        hard.add(
            &params,
            &mut rng,
            &mut scene,
            &pose,
            stage_rot,
            &mut movers,
            &mut stages,
        );
        Ok(Self {
            params,
            scene,
            movers,
            stages,
        })
    }

    fn parts_at(&self, t: f64) -> Vec<Primitive> {
        let mut parts = Vec::new();
        for (m, stage) in self.movers.iter().zip(&self.stages) {
            let from = parts.len();
            m.parts(t as f32, &mut parts);
            for p in &mut parts[from..] {
                p.pose = stage * p.pose;
            }
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

/// Width of the view at 1 m from the camera, assumed for placing the hard-scene movers (a
/// 60° field of view, about TUM's 62°; the placement only needs to cross the view).
fn k_width_ratio() -> f32 {
    2.0 * (30f32).to_radians().tan()
}

/// The level stage frame's rotation at camera pose `pose`: columns side, forward, up.
fn level_frame(pose: &Isometry3<f32>) -> UnitQuaternion<f32> {
    let cam_y = pose.rotation * Vector3::y();
    let cam_z = pose.rotation * Vector3::z();
    let up = if cam_y.z < -0.5 { Vector3::z() } else { -cam_y };
    let fwd = (cam_z - up * cam_z.dot(&up))
        .try_normalize(1e-6)
        .unwrap_or(cam_z);
    let side = fwd.cross(&up);
    crate::scene::frame_from_axes(side, fwd, up)
}

/// Placement of the hard-scene movers at distance `dist` in front of the first camera.
struct HardMovers {
    dist: f32,
    half_width: f32,
}

impl HardMovers {
    #[allow(clippy::too_many_arguments)]
    fn add(
        &self,
        p: &AugmentParams,
        rng: &mut ChaCha8Rng,
        scene: &mut Scene,
        cam: &Isometry3<f32>,
        rot: UnitQuaternion<f32>,
        movers: &mut Vec<Mover>,
        stages: &mut Vec<Isometry3<f32>>,
    ) {
        let d = self.dist;
        let on_axis = cam.translation.vector + cam.rotation * Vector3::z() * d;
        let up = rot * Vector3::z();
        let object = |scene: &mut Scene, rng: &mut ChaCha8Rng, k: usize| {
            let kinds = [
                TextureKind::Checker,
                TextureKind::Poster,
                TextureKind::Mosaic,
            ];
            let m = scene.add_material(kinds[k % 3], 128, [0.3 * d, 0.3 * d], rng);
            PersonLook {
                shirt: m,
                trousers: m,
                skin: m,
                head: m,
            }
        };
        for k in 0..p.boxes {
            let h = d * rng.random_range(0.12..0.18);
            let half = Vector3::new(h, h, h);
            // Rests on the axis (boxes after the first a little aside), pushed across.
            let x0 = (k as f32) * 2.5 * h * if k % 2 == 0 { 1.0 } else { -1.0 };
            let x1 = x0 + if k % 2 == 0 { 1.0 } else { -1.0 } * self.half_width * 0.9;
            let places = [
                BoxPlace::Floor {
                    pos: [x0, 0.0],
                    yaw: 0.0,
                },
                BoxPlace::Floor {
                    pos: [x1, 0.0],
                    yaw: rng.random_range(-0.5..0.5),
                },
            ];
            let (rest, push) = (p.box_rest.max(0.1), 2.0);
            let keys = (0..40)
                .flat_map(|c| {
                    let t = c as f32 * (rest + push) + rest;
                    [(t, places[c % 2]), (t + push, places[(c + 1) % 2])]
                })
                .collect();
            let look = object(scene, rng, k);
            movers.push(Mover {
                kind: MoverKind::Carried(CarriedBox {
                    half,
                    carrier: Script::default(),
                    keys,
                }),
                look,
            });
            let origin = on_axis - up * (h + (k as f32) * 0.3 * h);
            stages.push(Isometry3::from_parts(Translation3::from(origin), rot));
        }
        for k in 0..p.balls {
            let l = 2.4 * self.half_width;
            let look = object(scene, rng, k + 1);
            movers.push(Mover {
                kind: MoverKind::Thrown(Throw {
                    shape: Shape::Sphere {
                        r: d * rng.random_range(0.07..0.1),
                    },
                    a: Vector3::new(-l / 2.0, 0.0, 0.0),
                    b: Vector3::new(l / 2.0, 0.0, 0.0),
                    flight: l / 3.5,
                    hold: rng.random_range(1.0..2.0),
                    offset: rng.random_range(0.0..2.0),
                    spin_axis: Vector3::new(rng.random_range(-1.0..1.0), 0.3, 1.0),
                    spin: rng.random_range(4.0..8.0),
                }),
                look,
            });
            let origin = on_axis + up * (k as f32 * 0.2 * d - 0.1 * d);
            stages.push(Isometry3::from_parts(Translation3::from(origin), rot));
        }
        // People walk on a floor 1.35 m below the camera, crossing at 1–2 d, alternately
        // from the left and from the right.
        let floor = cam.translation.vector - up * 1.35;
        for k in 0..p.crowd {
            let (shirt, trousers, skin, head) = (
                scene.add_material(TextureKind::Fabric, 128, [0.35, 0.35], rng),
                scene.add_material(TextureKind::Fabric, 128, [0.3, 0.3], rng),
                scene.add_material(TextureKind::Skin, 128, [0.3, 0.3], rng),
                scene.add_material(
                    TextureKind::Head,
                    128,
                    [std::f32::consts::TAU * 0.115, std::f32::consts::PI * 0.115],
                    rng,
                ),
            );
            let y = d * (1.0 + k as f32 / p.crowd.max(1) as f32);
            let x = y * 0.5 * k_width_ratio() + 0.5;
            let (a, b) = if k % 2 == 0 {
                ([-x, y], [x, y])
            } else {
                ([x, y], [-x, y])
            };
            movers.push(Mover {
                kind: MoverKind::Walker {
                    path: Path::PingPong { a, b },
                    speed: rng.random_range(0.8..1.0),
                    start_delay: 0.0,
                    offset: rng.random_range(0.0..3.0),
                },
                look: PersonLook {
                    shirt,
                    trousers,
                    skin,
                    head,
                },
            });
            stages.push(Isometry3::from_parts(Translation3::from(floor), rot));
        }
    }
}

/// Median of the valid (non-zero) raw depths, in metres.
pub fn median_depth(depth: &Gray16Image, depth_factor: f32) -> Option<f32> {
    let mut v: Vec<u16> = depth.as_raw().iter().copied().filter(|&d| d > 0).collect();
    let m = dynapix_geometry::stats::upper_median_by(&mut v, u16::cmp)?;
    Some(m as f32 / depth_factor)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    /// fr1_xyz (real, static) with a resting-then-pushed box, a thrown ball and three people:
    /// per-frame statistics from the composited masks and instance ids.
    #[test]
    fn fr1_xyz_gets_a_resting_box_a_thrown_ball_and_a_crowd() {
        let dir = std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../../shared/data/tum/rgbd_dataset_freiburg1_xyz"
        ));
        if !dir.is_dir() {
            eprintln!("skipping: {} not found", dir.display());
            return;
        }
        let opts = dynapix_io::SequenceOptions {
            pairing: dynapix_io::Pairing::OneToOne,
            ..Default::default()
        };
        let seq = dynapix_io::Sequence::open_with(dir, &opts).expect("fr1_xyz");
        let cam = seq.settings().expect("settings").camera();
        let k = Intrinsics::from(&cam);
        let factor = seq.depth_factor as f32;
        let frames: Vec<_> = seq
            .frames
            .iter()
            .filter_map(|f| seq.gt_pose_at(f.t).map(|p| (f, p)))
            .take(240)
            .collect();
        let (first, first_pose) = &frames[0];
        let d0 = dynapix_io::images::read_depth_raw(&first.depth).expect("depth");
        let med = median_depth(&d0, factor).expect("median");
        let params = AugmentParams {
            seed: 1,
            objects: 0,
            boxes: 1,
            balls: 1,
            crowd: 3,
            ..Default::default()
        };
        let aug = Augmenter::new(params, first_pose, med).expect("augmenter");
        let (w, h) = (k.width, k.height);
        let t0 = first.t;
        // Per frame: (time, [px, moving px, centroid x] per mover, moving share).
        type PerMover = Vec<(usize, usize, f64)>;
        let stats: Vec<(f64, PerMover, f64)> = frames
            .par_iter()
            .map(|(info, pose)| {
                let rgb = dynapix_io::images::read_rgb(&info.rgb).expect("rgb");
                let depth = dynapix_io::images::read_depth_raw(&info.depth).expect("depth");
                let c = aug.composite(&k, info.t - t0, 1.0 / 30.0, pose, &rgb, &depth, factor);
                let mut per = vec![(0usize, 0usize, 0.0f64); 5];
                let mut moving = 0usize;
                for (j, (&m, &id)) in c.mask.as_raw().iter().zip(c.instance.as_raw()).enumerate() {
                    if m == 0 {
                        assert_eq!(
                            c.rgb.as_raw()[3 * j..3 * j + 3],
                            rgb.as_raw()[3 * j..3 * j + 3]
                        );
                        continue;
                    }
                    moving += (m == 255) as usize;
                    let o = &mut per[id as usize - 1];
                    o.0 += 1;
                    o.1 += (m == 255) as usize;
                    o.2 += (j % w) as f64;
                }
                for o in &mut per {
                    o.2 /= o.0.max(1) as f64;
                }
                (info.t - t0, per, moving as f64 / (w * h) as f64)
            })
            .collect();
        // Box (mover 0): visible and still for the first seconds, then pushed (moving).
        let still_until = stats
            .iter()
            .take_while(|s| s.1[0].0 > 100 && s.1[0].1 == 0)
            .last()
            .map_or(0.0, |s| s.0);
        let pushed = stats.iter().filter(|s| s.1[0].1 > 100).count();
        // Ball (mover 1): crosses the view in flight.
        let xs: Vec<f64> = stats
            .iter()
            .filter(|s| s.1[1].1 > 10)
            .map(|s| s.1[1].2)
            .collect();
        let (x0, x1) = xs
            .iter()
            .fold((f64::MAX, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
        // Crowd (movers 2..5): moving share of the image.
        let people: Vec<usize> = (2..5)
            .map(|m| stats.iter().filter(|s| s.1[m].1 > 500).count())
            .collect();
        let big = stats.iter().filter(|s| s.2 > 0.3).count();
        eprintln!(
            "fr1_xyz augmented, {} frames: box still until {still_until:.1} s then moving in \
             {pushed} frames; ball in flight in view in {} frames, x {x0:.0}..{x1:.0} px; \
             people moving in view in {people:?} frames; moving share > 30 % in {big} frames",
            stats.len(),
            xs.len(),
        );
        assert!(still_until >= 2.5, "box still until {still_until}");
        assert!(pushed >= 20, "box pushed in {pushed} frames");
        assert!(x0 < w as f64 * 0.25 && x1 > w as f64 * 0.75, "{x0}..{x1}");
        assert!(people.iter().all(|&n| n >= 10), "{people:?}");
        assert!(big >= 10, "{big}");
        let _ = h;
    }
}
