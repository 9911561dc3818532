//! Named presets and the frame generator: camera motion + movers + scene → per-frame images
//! (rgb, background, depth, depth_bg, mask, instance ids) and ground-truth optical flow.
//!
//! Mask convention (DynaPix folder layout): 0 = static scene, 128 = pixel of a mover that is
//! not moving at this frame, 255 = moving pixel. "Moving" is decided per pixel: the surface
//! point seen there moves by more than `moving_threshold` metres to the previous or next frame
//! (so a seated person lifting an arm is 255 on the arm and 128 elsewhere).

use crate::SynthError;
use crate::hard;
use crate::movers::{Mover, MoverKind, Path, PersonLook};
use crate::render::{self, Intrinsics, Layers, MOVER_BIT, NO_HIT, RenderParams};
use crate::scene::{Scene, SceneParams};
use crate::sensor::{self, SensorParams};
use crate::shape::{Primitive, Shape};
use crate::trajectory::{CameraMotion, MotionKind, Rig};
use dynapix_geometry::PinholeCamera;
use image::{GrayImage, ImageBuffer, Luma, RgbImage};
use nalgebra::{Isometry3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::f32::consts::{FRAC_PI_2, PI};
use std::sync::Arc;

/// 16-bit single-channel image (depth, instance ids).
pub type Gray16Image = ImageBuffer<Luma<u16>, Vec<u16>>;

/// Depth PNG scale: stored value = metres × 5000 (TUM convention).
pub const DEPTH_FACTOR: f32 = 5000.0;
/// Middlebury `.flo` value meaning "unknown flow".
pub const UNKNOWN_FLOW: f32 = 1e10;

/// Named scenarios, shaped like the TUM dynamic sequences and GRADE's F / WO sequences.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Preset {
    /// Static room, hand-held camera, no movers.
    Static,
    /// Two people close to the camera (1–2.5 m, TUM-like share of the image): one walks
    /// back and forth across the view, one walks up, sits down on a stool and gets up; camera `xyz`.
    WalkingXyz,
    /// As `WalkingXyz` with a nearly static camera.
    WalkingStatic,
    /// As `WalkingXyz` with camera `rpy`.
    WalkingRpy,
    /// As `WalkingXyz` with camera `halfsphere`.
    WalkingHalfsphere,
    /// Two seated people moving an arm each; slow hand-held camera.
    Sitting,
    /// Flying textured boxes and spheres; hand-held camera.
    Flying,
    /// A box passing close in front of a nearly static camera, plus a walker.
    Occlusion,
    /// Camera loop through the room back to its start and on for half a lap more (period =
    /// max(10 s, sequence length / 1.5), so a sequence of ≥ 450 frames revisits the views of its
    /// first seconds, which a loop closure needs, and then keeps re-observing the mapped room),
    /// a walker and a seated person.
    Loop,
    /// The camera follows one walker around the room from behind, 1–2 m away: the person
    /// stays near the image centre while the room moves.
    PersonTracking,
    /// Six people walking 1–3 m in front of the camera, covering over half of the image at
    /// times; camera `xyz`.
    Crowd,
    /// A box rests in view, is picked up, carried 1.7 m and set down again; camera `xyz`.
    MovingBox,
    /// A person carries a box in, sets it down, walks away, later comes back and carries it
    /// off (450 frames by default); camera `xyz`.
    PlacingBox,
    /// A ball thrown back and forth across the view 1.5 m away at 3.5–4.9 m/s, and a walker;
    /// camera `xyz`.
    Balloon,
}

impl Preset {
    /// All presets in a fixed order.
    pub const ALL: [Preset; 14] = [
        Preset::Static,
        Preset::WalkingXyz,
        Preset::WalkingStatic,
        Preset::WalkingRpy,
        Preset::WalkingHalfsphere,
        Preset::Sitting,
        Preset::Flying,
        Preset::Occlusion,
        Preset::Loop,
        Preset::PersonTracking,
        Preset::Crowd,
        Preset::MovingBox,
        Preset::PlacingBox,
        Preset::Balloon,
    ];

    /// The hard-scene presets of issue 33 (each cue of the motion method has a blind spot).
    pub const HARD: [Preset; 5] = [
        Preset::PersonTracking,
        Preset::Crowd,
        Preset::MovingBox,
        Preset::PlacingBox,
        Preset::Balloon,
    ];

    /// Default number of frames (30 Hz): 300, except `placing_box` (450, so that the box
    /// rests 8 s between being set down and picked up).
    pub fn default_frames(self) -> usize {
        match self {
            Preset::PlacingBox => crate::hard::PLACING_BOX_FRAMES,
            _ => 300,
        }
    }

    /// The command-line name.
    pub fn name(self) -> &'static str {
        match self {
            Preset::Static => "static",
            Preset::WalkingXyz => "walking_xyz",
            Preset::WalkingStatic => "walking_static",
            Preset::WalkingRpy => "walking_rpy",
            Preset::WalkingHalfsphere => "walking_halfsphere",
            Preset::Sitting => "sitting",
            Preset::Flying => "flying",
            Preset::Occlusion => "occlusion",
            Preset::Loop => "loop",
            Preset::PersonTracking => "person_tracking",
            Preset::Crowd => "crowd",
            Preset::MovingBox => "moving_box",
            Preset::PlacingBox => "placing_box",
            Preset::Balloon => "balloon",
        }
    }

    /// Parses a command-line name.
    pub fn from_name(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.name() == s)
    }

    /// Camera motion of the preset.
    pub fn motion(self) -> MotionKind {
        match self {
            Preset::Static | Preset::Flying | Preset::Sitting => MotionKind::Handheld,
            Preset::WalkingXyz
            | Preset::Crowd
            | Preset::MovingBox
            | Preset::PlacingBox
            | Preset::Balloon => MotionKind::Xyz,
            Preset::PersonTracking => MotionKind::Follow,
            Preset::WalkingStatic | Preset::Occlusion => MotionKind::Static,
            Preset::WalkingRpy => MotionKind::Rpy,
            Preset::WalkingHalfsphere => MotionKind::Halfsphere,
            Preset::Loop => MotionKind::Loop,
        }
    }

    fn rig(self) -> Rig {
        match self {
            Preset::Sitting => Rig {
                eye: Point3::new(-0.6, -0.5, 1.35),
                target: Point3::new(-1.35, 1.9, 0.85),
            },
            _ => Rig::default(),
        }
    }
}

impl std::str::FromStr for Preset {
    type Err = SynthError;
    fn from_str(s: &str) -> Result<Self, SynthError> {
        Self::from_name(s).ok_or_else(|| SynthError::UnknownPreset {
            name: s.to_string(),
            known: Self::ALL
                .iter()
                .map(|p| p.name())
                .collect::<Vec<_>>()
                .join(", "),
        })
    }
}

/// Everything that defines a synthetic sequence.
#[derive(Clone, Debug)]
pub struct SynthParams {
    /// Scenario.
    pub preset: Preset,
    /// Number of frames.
    pub frames: usize,
    /// Seed of all random choices.
    pub seed: u64,
    /// Camera intrinsics (distortion ignored: rendered images are ideal pinhole).
    pub camera: PinholeCamera,
    /// Frame rate (Hz).
    pub fps: f64,
    /// Sensor simulation.
    pub sensor: SensorParams,
    /// Renderer settings.
    pub render: RenderParams,
    /// Scene generator settings.
    pub scene: SceneParams,
    /// Per-frame displacement (m) above which a mover pixel counts as moving.
    pub moving_threshold: f32,
}

impl SynthParams {
    /// `frames` frames of `preset` with `seed`, seen by the default camera resized to
    /// `width × height` (see [`PinholeCamera::resized`]) with the scene detail of that width;
    /// everything else default.
    pub fn at_size(preset: Preset, frames: usize, seed: u64, width: u32, height: u32) -> Self {
        let camera = PinholeCamera::tum_fr3().resized(width, height);
        Self {
            preset,
            frames,
            seed,
            scene: SceneParams::for_width(width),
            camera,
            ..Self::default()
        }
    }
}

impl Default for SynthParams {
    fn default() -> Self {
        Self {
            preset: Preset::WalkingXyz,
            frames: 300,
            seed: 0,
            camera: PinholeCamera::tum_fr3(),
            fps: 30.0,
            sensor: SensorParams::default(),
            render: RenderParams::default(),
            scene: SceneParams::default(),
            moving_threshold: 0.0005,
        }
    }
}

/// One generated frame.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Index in the sequence.
    pub index: usize,
    /// Timestamp (s).
    pub time: f64,
    /// Camera-to-world pose.
    pub pose: Isometry3<f64>,
    /// Colour image with movers.
    pub rgb: RgbImage,
    /// Colour image without movers.
    pub background: RgbImage,
    /// Depth with movers (metres × 5000, 0 = no depth).
    pub depth: Gray16Image,
    /// Depth without movers.
    pub depth_bg: Gray16Image,
    /// Motion mask (0 / 128 / 255).
    pub mask: GrayImage,
    /// Instance ids: 0 = static scene, `k + 1` = mover `k`.
    pub instance: Gray16Image,
}

impl Frame {
    /// The depth with movers in metres (`depth / DEPTH_FACTOR`, 0 = no depth), as the SLAM
    /// and motion crates take it.
    pub fn depth_metres(&self) -> ImageBuffer<Luma<f32>, Vec<f32>> {
        let data = self
            .depth
            .as_raw()
            .iter()
            .map(|&d| d as f32 / DEPTH_FACTOR)
            .collect();
        ImageBuffer::from_raw(self.depth.width(), self.depth.height(), data)
            .unwrap_or_else(|| ImageBuffer::new(self.depth.width(), self.depth.height()))
    }
}

/// A dense flow field, row-major `[u, v]` per pixel ([`UNKNOWN_FLOW`] where undefined).
pub type Flow = dynapix_flow::FlowField;

/// The generator of one sequence.
#[derive(Clone, Debug)]
pub struct Sequence {
    /// Parameters.
    pub params: SynthParams,
    /// The room (shared between sequences of the same seed, e.g. for previews).
    pub scene: Arc<Scene>,
    /// Movers.
    pub movers: Vec<Mover>,
    /// Camera motion.
    pub motion: CameraMotion,
    k: Intrinsics,
}

/// Movers of a preset, with seeded variations of speeds and phases.
pub fn preset_movers(preset: Preset, scene: &Scene, seed: u64) -> Vec<Mover> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x30BE_0000_0000_0003);
    let looks: Vec<PersonLook> = if scene.people.is_empty() {
        vec![
            PersonLook {
                shirt: 0,
                trousers: 0,
                skin: 0,
                head: 0
            };
            4
        ]
    } else {
        (0..4)
            .map(|k| scene.people[k % scene.people.len()])
            .collect()
    };
    let obj = |k: usize| {
        scene
            .objects
            .get(k % scene.objects.len().max(1))
            .copied()
            .unwrap_or(0)
    };
    let look_of = |m: usize| PersonLook {
        shirt: m,
        trousers: m,
        skin: m,
        head: m,
    };
    let walker1 = |rng: &mut ChaCha8Rng, a: [f32; 2], b: [f32; 2]| Mover {
        kind: MoverKind::Walker {
            path: Path::PingPong { a, b },
            speed: rng.random_range(0.7..0.9),
            start_delay: 0.0,
            offset: rng.random_range(0.0..3.0),
        },
        look: looks[0],
    };
    // TUM fr3 walking: two people 1–2.5 m in front of the camera (base eye at y = -1.5,
    // looking along +y), one crossing the view back and forth, one walking towards the
    // camera, sitting down on a stool and getting up again.
    let sit_stander = |rng: &mut ChaCha8Rng, stool: usize| Mover {
        kind: MoverKind::SitStand {
            a: [0.7, 1.1],
            b: [-0.3, -0.15],
            speed: rng.random_range(0.6..0.8),
            sit: rng.random_range(2.0..3.5),
            offset: rng.random_range(0.0..4.0),
            stool,
        },
        look: looks[1],
    };
    let sitter = |rng: &mut ChaCha8Rng, x: f32, look: PersonLook| Mover {
        kind: MoverKind::Sitter {
            seat: [x, 2.05],
            heading: -FRAC_PI_2,
            period: rng.random_range(3.5..5.0),
            rest: rng.random_range(0.3..0.5),
            offset: rng.random_range(0.0..4.0),
        },
        look,
    };
    match preset {
        Preset::Static => Vec::new(),
        Preset::WalkingXyz
        | Preset::WalkingStatic
        | Preset::WalkingRpy
        | Preset::WalkingHalfsphere => vec![
            walker1(&mut rng, [-1.2, 0.05], [1.15, 0.4]),
            sit_stander(&mut rng, obj(1)),
        ],
        Preset::Sitting => vec![
            sitter(&mut rng, -1.8, looks[2]),
            sitter(&mut rng, -1.0, looks[3]),
        ],
        Preset::Flying => (0..5)
            .map(|k| {
                let shape = if k % 2 == 0 {
                    Shape::Box {
                        half: Vector3::new(
                            rng.random_range(0.1..0.22),
                            rng.random_range(0.1..0.22),
                            rng.random_range(0.1..0.22),
                        ),
                    }
                } else {
                    Shape::Sphere {
                        r: rng.random_range(0.12..0.22),
                    }
                };
                let spin = Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(0.2..1.0),
                );
                Mover {
                    kind: MoverKind::Flyer {
                        shape,
                        centre: Vector3::new(
                            0.3 + rng.random_range(-0.4..0.4),
                            1.0 + rng.random_range(-0.3..0.3),
                            1.2,
                        ),
                        amplitude: Vector3::new(
                            rng.random_range(0.5..0.9),
                            rng.random_range(0.3..0.6),
                            rng.random_range(0.2..0.45),
                        ),
                        omega: Vector3::new(
                            rng.random_range(0.5..0.9),
                            rng.random_range(0.4..0.8),
                            rng.random_range(0.6..1.1),
                        ),
                        phase: Vector3::new(
                            rng.random_range(0.0..2.0 * PI),
                            rng.random_range(0.0..2.0 * PI),
                            rng.random_range(0.0..2.0 * PI),
                        ),
                        spin: (spin, rng.random_range(0.6..1.5)),
                    },
                    look: look_of(obj(k)),
                }
            })
            .collect(),
        Preset::Occlusion => {
            let rig = preset.rig();
            let y = rig.eye.y as f32 + 0.75;
            vec![
                Mover {
                    kind: MoverKind::Passer {
                        shape: Shape::Box {
                            half: Vector3::new(0.22, 0.18, 0.4),
                        },
                        a: Vector3::new(-1.6, y, 1.15),
                        b: Vector3::new(1.6, y, 1.15),
                        cross: 4.0,
                        period: 6.0,
                        offset: rng.random_range(0.0..1.0),
                    },
                    look: look_of(obj(0)),
                },
                walker1(&mut rng, [-1.7, 0.45], [1.3, 0.85]),
            ]
        }
        Preset::Loop => vec![
            walker1(&mut rng, [-0.4, 1.75], [1.4, 1.75]),
            sitter(&mut rng, -1.8, looks[2]),
        ],
        Preset::PersonTracking => hard::person_tracking(&mut rng, looks[0]).0,
        Preset::Crowd => hard::crowd(&mut rng, &[looks[0], looks[1], looks[2], looks[3]]),
        Preset::MovingBox => hard::moving_box(&mut rng, looks[1], obj(2)),
        Preset::PlacingBox => hard::placing_box(&mut rng, looks[2], obj(4)),
        Preset::Balloon => hard::balloon(&mut rng, looks[0], obj(1)),
    }
}

impl Sequence {
    /// Builds the scene from the seed and sets up the preset.
    pub fn new(params: SynthParams) -> Result<Self, SynthError> {
        let scene = Arc::new(Scene::generate(params.seed, &params.scene));
        Self::with_scene(params, scene)
    }

    /// Sets up the preset on an existing scene (to share one room between sequences).
    pub fn with_scene(params: SynthParams, scene: Arc<Scene>) -> Result<Self, SynthError> {
        if params.frames == 0 {
            return Err(SynthError::InvalidParams(
                "frames must be at least 1".into(),
            ));
        }
        if params.camera.width == 0
            || params.camera.height == 0
            || params.camera.fx <= 0.0
            || params.camera.fy <= 0.0
        {
            let c = &params.camera;
            return Err(SynthError::InvalidParams(format!(
                "the camera needs a positive size and focal length, got {}×{} px with fx {} \
                 and fy {} (check --width/--height/--fx/--fy)",
                c.width, c.height, c.fx, c.fy
            )));
        }
        if params.fps <= 0.0 || !params.fps.is_finite() {
            return Err(SynthError::InvalidParams(format!(
                "invalid fps {}",
                params.fps
            )));
        }
        let movers = preset_movers(params.preset, &scene, params.seed);
        let mut motion =
            CameraMotion::new(params.preset.motion(), params.preset.rig(), params.seed);
        if params.preset == Preset::PersonTracking {
            let mut rng = ChaCha8Rng::seed_from_u64(params.seed ^ 0x30BE_0000_0000_0003);
            motion.follow = Some(hard::person_tracking(&mut rng, PersonLook::default()).1);
        }
        // The loop closes before the end of the sequence (which overlaps the start by
        // LOOP_LAPS − 1 of a lap) when it is long enough for a walking pace.
        motion.loop_period = motion
            .loop_period
            .max(params.frames as f64 / params.fps / crate::trajectory::LOOP_LAPS);
        let k = Intrinsics::from(&params.camera);
        Ok(Self {
            params,
            scene,
            movers,
            motion,
            k,
        })
    }

    /// Time of frame `i` (s).
    pub fn time(&self, i: usize) -> f64 {
        i as f64 / self.params.fps
    }

    /// Timestamp string of frame `i` (6 decimals, as in TUM file names).
    pub fn timestamp(&self, i: usize) -> String {
        format!("{:.6}", self.time(i))
    }

    /// Camera-to-world pose at time `t`.
    pub fn pose_at(&self, t: f64) -> Isometry3<f64> {
        self.motion.pose(t)
    }

    /// Camera-to-world pose of frame `i`.
    pub fn pose(&self, i: usize) -> Isometry3<f64> {
        self.pose_at(self.time(i))
    }

    /// Mover parts at time `t` and, per part, the index of its mover.
    pub fn parts_at(&self, t: f64) -> (Vec<Primitive>, Vec<u16>) {
        let mut parts = Vec::new();
        let mut owner = Vec::new();
        for (m, mover) in self.movers.iter().enumerate() {
            let before = parts.len();
            mover.parts(t as f32, &mut parts);
            owner.extend(std::iter::repeat_n(m as u16, parts.len() - before));
        }
        (parts, owner)
    }

    /// Intrinsics used for rendering.
    pub fn intrinsics(&self) -> Intrinsics {
        self.k
    }

    /// Renders both versions of the view at time `t` (no sensor effects).
    pub fn render_at(&self, t: f64, layers: &mut Layers) -> Vec<Primitive> {
        let (parts, _) = self.parts_at(t);
        let pose = self.pose_at(t).cast::<f32>();
        render::render(
            &self.scene,
            &self.params.render,
            &self.k,
            &pose,
            &parts,
            layers,
        );
        parts
    }

    /// Generates frame `i`; with `flow_step = Some(k)` also the ground-truth flow to frame `i + k`.
    pub fn frame(&self, i: usize, flow_step: Option<usize>) -> (Frame, Option<Flow>) {
        let p = &self.params;
        let t = self.time(i);
        let (w, h) = (self.k.width, self.k.height);
        let mut layers = Layers::default();
        let parts = self.render_at(t, &mut layers);
        let (_, owner) = self.parts_at(t);

        // Motion blur: average sub-frame renders over the exposure time ending at t; a pixel
        // touched by a mover in any sub-frame belongs to that mover (keeps rgb == background
        // on mask-0 pixels).
        let mut blur_owner: Vec<u32> = Vec::new();
        if p.sensor.blur_samples > 1 {
            let n = p.sensor.blur_samples as usize;
            let mut sub = Layers::default();
            let mut acc_bg = layers.bg_rgb.clone();
            let mut acc = layers.rgb.clone();
            blur_owner = vec![NO_HIT; w * h];
            for s in 1..n {
                let ts = t - p.sensor.blur_time as f64 * s as f64 / (n - 1) as f64;
                let sub_parts = self.render_at(ts, &mut sub);
                let _ = sub_parts;
                for j in 0..w * h {
                    for c in 0..3 {
                        acc_bg[j][c] += sub.bg_rgb[j][c];
                        acc[j][c] += sub.rgb[j][c];
                    }
                    if sub.id[j] != NO_HIT && sub.id[j] & MOVER_BIT != 0 {
                        blur_owner[j] = sub.id[j] & !MOVER_BIT;
                    }
                }
            }
            let inv = 1.0 / n as f32;
            for j in 0..w * h {
                for c in 0..3 {
                    acc_bg[j][c] *= inv;
                    acc[j][c] *= inv;
                }
                // Outside every sub-frame's movers, the two images must agree exactly.
                let mover_now = layers.id[j] != NO_HIT && layers.id[j] & MOVER_BIT != 0;
                if !mover_now && blur_owner[j] == NO_HIT {
                    acc[j] = acc_bg[j];
                }
            }
            layers.bg_rgb = acc_bg;
            layers.rgb = acc;
        }

        let gain = sensor::exposure_gain(&p.sensor, p.seed, t);
        let mut rgb = vec![0u8; w * h * 3];
        let mut bg = vec![0u8; w * h * 3];
        let mut depth = vec![0u16; w * h];
        let mut depth_bg = vec![0u16; w * h];
        let fi = i as u64;
        rayon::join(
            || {
                rayon::join(
                    || sensor::to_rgb8(&p.sensor, p.seed, fi, gain, &layers.rgb, &mut rgb),
                    || sensor::to_rgb8(&p.sensor, p.seed, fi, gain, &layers.bg_rgb, &mut bg),
                )
            },
            || {
                rayon::join(
                    || {
                        sensor::to_depth16(
                            &p.sensor,
                            p.seed,
                            fi,
                            DEPTH_FACTOR,
                            w,
                            &layers.depth,
                            &mut depth,
                        )
                    },
                    || {
                        sensor::to_depth16(
                            &p.sensor,
                            p.seed,
                            fi,
                            DEPTH_FACTOR,
                            w,
                            &layers.bg_depth,
                            &mut depth_bg,
                        )
                    },
                )
            },
        );

        // Mask and instances.
        let dt = 1.0 / p.fps;
        let (prev, _) = self.parts_at(t - dt);
        let (next, _) = self.parts_at(t + dt);
        let cam = self.pose_at(t).cast::<f32>();
        let rot = cam.rotation.to_rotation_matrix().into_inner();
        let centre = cam.translation.vector;
        let k = self.k;
        let thr = p.moving_threshold;
        let mut mask = vec![0u8; w * h];
        let mut inst = vec![0u16; w * h];
        mask.par_chunks_mut(w)
            .zip(inst.par_chunks_mut(w))
            .enumerate()
            .for_each(|(y, (mrow, irow))| {
                for x in 0..w {
                    let j = y * w + x;
                    let id = layers.id[j];
                    if id != NO_HIT && id & MOVER_BIT != 0 {
                        let part = (id & !MOVER_BIT) as usize;
                        let dc =
                            Vector3::new((x as f32 - k.cx) / k.fx, (y as f32 - k.cy) / k.fy, 1.0);
                        let xw = Point3::from(centre + rot * dc * layers.depth[j]);
                        let moving = match (parts.get(part), prev.get(part), next.get(part)) {
                            (Some(cur), Some(a), Some(b)) => {
                                let xl = cur.pose.inverse_transform_point(&xw);
                                ((a.pose * xl) - xw).norm() > thr
                                    || ((b.pose * xl) - xw).norm() > thr
                            }
                            _ => false,
                        };
                        mrow[x] = if moving { 255 } else { 128 };
                        irow[x] = owner.get(part).map_or(0, |&o| o + 1);
                    } else if let Some(&b) = blur_owner.get(j)
                        && b != NO_HIT
                    {
                        // Blurred-in mover: it moved during the exposure.
                        mrow[x] = 255;
                        irow[x] = owner.get(b as usize).map_or(0, |&o| o + 1);
                    }
                }
            });

        let flow = flow_step.map(|step| self.flow_from_layers(i, step, &layers, &parts));
        let (wu, hu) = (w as u32, h as u32);
        let frame = Frame {
            index: i,
            time: t,
            pose: self.pose(i),
            rgb: RgbImage::from_raw(wu, hu, rgb).unwrap_or_default(),
            background: RgbImage::from_raw(wu, hu, bg).unwrap_or_default(),
            depth: Gray16Image::from_raw(wu, hu, depth).unwrap_or_default(),
            depth_bg: Gray16Image::from_raw(wu, hu, depth_bg).unwrap_or_default(),
            mask: GrayImage::from_raw(wu, hu, mask).unwrap_or_default(),
            instance: Gray16Image::from_raw(wu, hu, inst).unwrap_or_default(),
        };
        (frame, flow)
    }

    /// Ground-truth flow from frame `i` to frame `i + step` given frame `i`'s render: each
    /// pixel's visible surface point (moved rigidly with its mover part) projected into the
    /// camera of frame `i + step`.
    fn flow_from_layers(
        &self,
        i: usize,
        step: usize,
        layers: &Layers,
        parts: &[Primitive],
    ) -> Flow {
        let (w, h) = (self.k.width, self.k.height);
        let k = self.k;
        let cam = self.pose(i).cast::<f32>();
        let rot = cam.rotation.to_rotation_matrix().into_inner();
        let centre = cam.translation.vector;
        let (later, _) = self.parts_at(self.time(i + step));
        let cw2 = self.pose(i + step).inverse().cast::<f32>();
        // Per-part motion from frame i to i + step.
        let moves: Vec<Isometry3<f32>> = parts
            .iter()
            .zip(&later)
            .map(|(a, b)| b.pose * a.pose.inverse())
            .collect();
        let mut data = vec![[UNKNOWN_FLOW; 2]; w * h];
        data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, f) in row.iter_mut().enumerate() {
                let j = y * w + x;
                let z = layers.depth[j];
                let id = layers.id[j];
                if !z.is_finite() || id == NO_HIT {
                    continue;
                }
                let dc = Vector3::new((x as f32 - k.cx) / k.fx, (y as f32 - k.cy) / k.fy, 1.0);
                let mut xw = Point3::from(centre + rot * dc * z);
                if id & MOVER_BIT != 0 {
                    match moves.get((id & !MOVER_BIT) as usize) {
                        Some(m) => xw = m * xw,
                        None => continue,
                    }
                }
                let pc = cw2 * xw;
                if pc.z <= 1e-6 {
                    continue;
                }
                let u = k.fx * pc.x / pc.z + k.cx;
                let v = k.fy * pc.y / pc.z + k.cy;
                *f = [u - x as f32, v - y as f32];
            }
        });
        Flow {
            width: w as u32,
            height: h as u32,
            data,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Small, fast parameters: 160×120 (TUM fr3 intrinsics scaled by 1/4), small textures.
    fn small(preset: Preset, seed: u64, sensor: SensorParams) -> SynthParams {
        let c = PinholeCamera::tum_fr3();
        SynthParams {
            preset,
            frames: 40,
            seed,
            camera: PinholeCamera::new(160, 120, c.fx / 4.0, c.fy / 4.0, c.cx / 4.0, c.cy / 4.0),
            sensor,
            scene: SceneParams::for_width(160),
            ..SynthParams::default()
        }
    }

    #[test]
    fn a_zero_size_camera_is_a_readable_error() {
        let mut p = small(Preset::WalkingXyz, 0, SensorParams::default());
        p.camera.width = 0;
        let e = Sequence::new(p)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(
            e.contains("0×120 px") && !e.contains("PinholeCamera"),
            "{e}"
        );
    }

    #[test]
    fn rgb_equals_background_outside_movers() {
        for (preset, sensor) in [
            (Preset::WalkingXyz, SensorParams::default()),
            (Preset::Flying, SensorParams::full()),
            (Preset::Occlusion, SensorParams::default()),
        ] {
            let seq = Sequence::new(small(preset, 3, sensor)).expect("sequence");
            let mut mover_px = 0;
            for i in [0, 20, 39] {
                let (f, _) = seq.frame(i, None);
                for (j, m) in f.mask.as_raw().iter().enumerate() {
                    if *m == 0 {
                        assert_eq!(
                            f.rgb.as_raw()[3 * j..3 * j + 3],
                            f.background.as_raw()[3 * j..3 * j + 3],
                            "{preset:?} frame {i} px {j}"
                        );
                        assert_eq!(f.instance.as_raw()[j], 0);
                    } else {
                        mover_px += 1;
                        assert!(f.instance.as_raw()[j] > 0);
                    }
                }
            }
            assert!(
                mover_px > 100,
                "{preset:?}: movers barely visible ({mover_px} px)"
            );
        }
    }

    #[test]
    fn flow_matches_reprojection_through_depth_and_poses() {
        let seq =
            Sequence::new(small(Preset::WalkingRpy, 5, SensorParams::clean())).expect("sequence");
        let k = seq.intrinsics();
        let step = 3;
        let i = 10;
        let (f, flow) = seq.frame(i, Some(step));
        let flow = flow.expect("flow");
        let (w, h) = (k.width, k.height);
        let t1 = seq.pose(i);
        let t2 = seq.pose(i + step);
        let rel = t2.inverse() * t1;
        let (mut checked, mut mover_diff) = (0, 0);
        for y in 0..h {
            for x in 0..w {
                let j = y * w + x;
                let d = f.depth.as_raw()[j];
                if d == 0 {
                    continue;
                }
                let z = d as f64 / DEPTH_FACTOR as f64;
                let p = Point3::new(
                    (x as f64 - k.cx as f64) / k.fx as f64 * z,
                    (y as f64 - k.cy as f64) / k.fy as f64 * z,
                    z,
                );
                let q = rel * p;
                let u = k.fx as f64 * q.x / q.z + k.cx as f64 - x as f64;
                let v = k.fy as f64 * q.y / q.z + k.cy as f64 - y as f64;
                let [fu, fv] = flow.data[j];
                let err = (fu as f64 - u).hypot(fv as f64 - v);
                if f.mask.as_raw()[j] == 0 {
                    // Depth is quantised to 0.2 mm, so agreement is far below a pixel.
                    assert!(
                        err < 0.02,
                        "static pixel ({x},{y}): flow {fu},{fv} vs {u},{v}"
                    );
                    checked += 1;
                } else if f.mask.as_raw()[j] == 255 && err > 0.1 {
                    mover_diff += 1;
                }
            }
        }
        assert!(checked > w * h / 2, "only {checked} static pixels");
        // Moving pixels do not follow the camera-only reprojection.
        assert!(mover_diff > 20, "{mover_diff}");
    }

    #[test]
    fn flow_warps_next_frame_onto_this_one_on_moving_pixels() {
        // Independent of the geometry used to compute it: sampling frame t+1 at x + flow must
        // reproduce frame t's colour (clean sensor, pixels still visible at t+1).
        let seq = Sequence::new(small(Preset::WalkingStatic, 4, SensorParams::clean()))
            .expect("sequence");
        let (w, h) = (seq.intrinsics().width, seq.intrinsics().height);
        let (mut err_flow, mut err_zero, mut n) = (0.0f64, 0.0f64, 0usize);
        for i in [70, 100, 130] {
            let (f0, flow) = seq.frame(i, Some(1));
            let flow = flow.expect("flow");
            let (f1, _) = seq.frame(i + 1, None);
            let g = |img: &RgbImage, x: usize, y: usize| {
                let p = img.get_pixel(x as u32, y as u32);
                (p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0
            };
            for y in 2..h - 2 {
                for x in 2..w - 2 {
                    let j = y * w + x;
                    if f0.mask.as_raw()[j] != 255 {
                        continue;
                    }
                    let [u, v] = flow.data[j];
                    let (tx, ty) = (x as f32 + u, y as f32 + v);
                    if !(1.0..(w - 2) as f32).contains(&tx) || !(1.0..(h - 2) as f32).contains(&ty)
                    {
                        continue;
                    }
                    let (xi, yi) = (tx.round() as usize, ty.round() as usize);
                    // Same mover visible there at t+1 (not occluded), away from its silhouette.
                    let inst = f0.instance.as_raw()[j];
                    if (0..9).any(|k| {
                        f1.instance.as_raw()[(yi + k / 3 - 1) * w + xi + k % 3 - 1] != inst
                    }) {
                        continue;
                    }
                    // Bilinear sample of frame t+1.
                    let (x0, y0) = (tx.floor() as usize, ty.floor() as usize);
                    let (ax, ay) = ((tx - x0 as f32) as f64, (ty - y0 as f32) as f64);
                    let s = g(&f1.rgb, x0, y0) * (1.0 - ax) * (1.0 - ay)
                        + g(&f1.rgb, x0 + 1, y0) * ax * (1.0 - ay)
                        + g(&f1.rgb, x0, y0 + 1) * (1.0 - ax) * ay
                        + g(&f1.rgb, x0 + 1, y0 + 1) * ax * ay;
                    let c = g(&f0.rgb, x, y);
                    err_flow += (s - c).abs();
                    err_zero += (g(&f1.rgb, x, y) - c).abs();
                    n += 1;
                }
            }
        }
        assert!(n > 300, "only {n} moving pixels checked");
        let (ef, ez) = (err_flow / n as f64, err_zero / n as f64);
        eprintln!(
            "moving pixels {n}: warp error {ef:.2} grey levels with GT flow, {ez:.2} with zero flow"
        );
        assert!(
            ef < 5.0 && ef < 0.5 * ez,
            "mean |I1(x+f) - I0(x)| = {ef:.2} vs {ez:.2} with zero flow"
        );
    }

    #[test]
    fn same_seed_same_frames_different_seed_differs() {
        let a = Sequence::new(small(Preset::Flying, 9, SensorParams::full())).expect("a");
        let b = Sequence::new(small(Preset::Flying, 9, SensorParams::full())).expect("b");
        let c = Sequence::new(small(Preset::Flying, 10, SensorParams::full())).expect("c");
        let (fa, qa) = a.frame(7, Some(1));
        let (fb, qb) = b.frame(7, Some(1));
        let (fc, _) = c.frame(7, None);
        assert_eq!(fa.rgb, fb.rgb);
        assert_eq!(fa.depth, fb.depth);
        assert_eq!(fa.mask, fb.mask);
        assert_eq!(qa, qb);
        assert_ne!(fa.rgb, fc.rgb);
    }

    #[test]
    fn walking_presets_cover_a_tum_like_share_of_the_image() {
        // TUM fr3 walking: two people 1–2.5 m away, often 20–50 % of the image. Averaged over
        // 6 s the moving pixels (255) must cover roughly 15–40 %.
        for preset in [Preset::WalkingXyz, Preset::WalkingHalfsphere] {
            let mut p = small(preset, 0, SensorParams::clean());
            p.frames = 180;
            let seq = Sequence::new(p).expect("sequence");
            let (mut moving, mut total) = (0usize, 0usize);
            for i in (0..180).step_by(12) {
                let (f, _) = seq.frame(i, None);
                moving += f.mask.as_raw().iter().filter(|&&m| m == 255).count();
                total += f.mask.as_raw().len();
            }
            let share = moving as f64 / total as f64;
            assert!(
                (0.12..0.45).contains(&share),
                "{}: moving share {share}",
                preset.name()
            );
        }
    }

    #[test]
    fn mask_marks_still_parts_128_and_moving_parts_255() {
        // Seated people move only an arm: over a few seconds both labels must occur on them.
        let seq =
            Sequence::new(small(Preset::Sitting, 2, SensorParams::clean())).expect("sequence");
        let (mut still, mut moving) = (0, 0);
        for i in (0..150).step_by(10) {
            let (f, _) = seq.frame(i, None);
            still += f.mask.as_raw().iter().filter(|&&m| m == 128).count();
            moving += f.mask.as_raw().iter().filter(|&&m| m == 255).count();
        }
        assert!(
            still > 1000 && moving > 20,
            "still {still}, moving {moving}"
        );
        assert!(still > moving, "most of a seated person is still");
        // Static preset: no movers at all.
        let seq = Sequence::new(small(Preset::Static, 2, SensorParams::clean())).expect("sequence");
        let (f, _) = seq.frame(5, None);
        assert!(f.mask.as_raw().iter().all(|&m| m == 0));
        assert_eq!(f.rgb, f.background);
    }

    #[test]
    fn depth_in_metres_divides_by_the_depth_factor() {
        let seq =
            Sequence::new(small(Preset::WalkingXyz, 1, SensorParams::default())).expect("sequence");
        let (f, _) = seq.frame(3, None);
        let m = f.depth_metres();
        assert_eq!(m.dimensions(), f.depth.dimensions());
        for (&d, &z) in f.depth.as_raw().iter().zip(m.as_raw()) {
            assert_eq!(z, d as f32 / DEPTH_FACTOR);
        }
        // A room seen from inside: metric depths, holes stay 0.
        assert!(m.as_raw().iter().any(|&z| z > 0.5 && z < 10.0));
    }
}

/// Checks that the rendered images suit ORB: FAST corners (threshold 20, as ORB-SLAM2's
/// `iniThFAST`) spread over the image, and re-detected in the next frame where the ground
/// truth flow says they went (no texture shimmer).
#[cfg(test)]
mod orb_suitability {
    use super::*;

    const CIRCLE: [(i32, i32); 16] = [
        (0, -3),
        (1, -3),
        (2, -2),
        (3, -1),
        (3, 0),
        (3, 1),
        (2, 2),
        (1, 3),
        (0, 3),
        (-1, 3),
        (-2, 2),
        (-3, 1),
        (-3, 0),
        (-3, -1),
        (-2, -2),
        (-1, -3),
    ];

    fn grey(img: &RgbImage) -> Vec<i32> {
        img.pixels()
            .map(|p| (p[0] as i32 * 299 + p[1] as i32 * 587 + p[2] as i32 * 114 + 500) / 1000)
            .collect()
    }

    /// FAST-9 corners with 3×3 non-maximum suppression on a simple score.
    fn fast(g: &[i32], w: usize, h: usize, th: i32) -> Vec<(usize, usize)> {
        let mut score = vec![0i32; w * h];
        for y in 3..h - 3 {
            for x in 3..w - 3 {
                let c = g[y * w + x];
                let ring: Vec<i32> = CIRCLE
                    .iter()
                    .map(|&(dx, dy)| g[(y as i32 + dy) as usize * w + (x as i32 + dx) as usize])
                    .collect();
                let mut best = 0;
                for sign in [1, -1] {
                    let mut run = 0;
                    let mut s = 0;
                    for k in 0..32 {
                        let d = sign * (ring[k % 16] - c);
                        if d > th {
                            run += 1;
                            s += d - th;
                            if run >= 9 {
                                best = best.max(s);
                            }
                        } else {
                            run = 0;
                            s = 0;
                        }
                    }
                }
                score[y * w + x] = best;
            }
        }
        let mut out = Vec::new();
        for y in 4..h - 4 {
            for x in 4..w - 4 {
                let s = score[y * w + x];
                if s == 0 {
                    continue;
                }
                let mut is_max = true;
                for dy in -1i32..=1 {
                    for dx in -1i32..=1 {
                        let n = score[(y as i32 + dy) as usize * w + (x as i32 + dx) as usize];
                        if (dx, dy) != (0, 0)
                            && (n > s || (n == s && (dy < 0 || (dy == 0 && dx < 0))))
                        {
                            is_max = false;
                        }
                    }
                }
                if is_max {
                    out.push((x, y));
                }
            }
        }
        out
    }

    #[test]
    fn fast_corners_are_spread_and_repeatable() {
        for preset in [Preset::WalkingXyz, Preset::Sitting] {
            let params = SynthParams {
                preset,
                frames: 40,
                seed: 1,
                sensor: SensorParams::default(),
                ..SynthParams::default()
            };
            let seq = Sequence::new(params).expect("sequence");
            let (w, h) = (640usize, 480usize);
            let i = 30;
            let (f0, flow) = seq.frame(i, Some(1));
            let flow = flow.expect("flow");
            let (f1, _) = seq.frame(i + 1, None);
            let c0 = fast(&grey(&f0.background), w, h, 20);
            let c1 = fast(&grey(&f1.background), w, h, 20);
            // Spread: corners in most cells of an 8×6 grid.
            let mut cells = [false; 48];
            for &(x, y) in &c0 {
                cells[(y * 6 / h) * 8 + x * 8 / w] = true;
            }
            let covered = cells.iter().filter(|&&c| c).count();
            // Repeatability: a corner of frame i re-detected within 1.5 px of its flow target.
            let mut grid = vec![false; w * h];
            for &(x, y) in &c1 {
                grid[y * w + x] = true;
            }
            let mut found = 0;
            let mut tried = 0;
            for &(x, y) in &c0 {
                if f0.mask.as_raw()[y * w + x] != 0 {
                    continue;
                }
                let [u, v] = flow.data[y * w + x];
                let (tx, ty) = (x as f32 + u, y as f32 + v);
                if !(5.0..w as f32 - 5.0).contains(&tx) || !(5.0..h as f32 - 5.0).contains(&ty) {
                    continue;
                }
                tried += 1;
                let hit = (-1i32..=1).any(|dy| {
                    (-1i32..=1).any(|dx| {
                        let (px, py) = (
                            (tx.round() as i32 + dx) as usize,
                            (ty.round() as i32 + dy) as usize,
                        );
                        grid[py * w + px]
                    })
                });
                if hit {
                    found += 1;
                }
            }
            let rep = found as f64 / tried.max(1) as f64;
            eprintln!(
                "{preset:?}: {} corners, {covered}/48 cells, repeatability {rep:.2} ({found}/{tried})",
                c0.len()
            );
            assert!(
                c0.len() > 1000,
                "{preset:?}: only {} FAST corners",
                c0.len()
            );
            assert!(
                covered >= 40,
                "{preset:?}: corners in only {covered}/48 cells"
            );
            assert!(rep > 0.6, "{preset:?}: repeatability {rep}");
        }
    }
}
