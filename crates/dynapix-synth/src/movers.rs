//! Moving objects: articulated walking people (torso, head, two-segment arms and legs that
//! swing with the gait), people who stand still and then walk, seated people who move only an
//! arm, flying textured boxes and spheres, and an object passing close in front of the camera.
//!
//! Every mover returns the same number of parts at every time, each a [`Primitive`] posed in
//! the world. Part `j` at time `t₁` and at `t₂` is the same rigid body, so the motion of any
//! surface point between two frames is `pose₂ · pose₁⁻¹` — used for exact ground-truth flow
//! and for the per-pixel "is moving" mask.

pub use crate::body::PersonLook;
use crate::body::{Pose, body_frame, dims as body, gait, iso, person_parts};
use crate::script::{CarriedBox, Script, Throw};
use crate::shape::{Primitive, Shape};
use nalgebra::{UnitQuaternion, Vector3};
use std::f32::consts::{FRAC_PI_2, PI, TAU};

/// A walking path on the floor.
#[derive(Clone, Debug)]
pub enum Path {
    /// Walk from `a` to `b`, turn on the spot, walk back, turn, repeat.
    PingPong {
        /// Start point (x, y) on the floor.
        a: [f32; 2],
        /// End point (x, y).
        b: [f32; 2],
    },
    /// Walk around an ellipse (counter-clockwise).
    Ellipse {
        /// Centre (x, y).
        centre: [f32; 2],
        /// Radii along x and y.
        radii: [f32; 2],
    },
}

/// What kind of motion a mover performs.
#[derive(Clone, Debug)]
pub enum MoverKind {
    /// A person walking along `path` at `speed` m/s after standing still for `start_delay` s.
    Walker {
        /// The path.
        path: Path,
        /// Walking speed (m/s).
        speed: f32,
        /// Seconds of standing still before starting to walk.
        start_delay: f32,
        /// Time offset into the path (s), to desynchronise walkers.
        offset: f32,
    },
    /// A person who walks from `a` to `b`, turns, sits down on a stool at `b`, stays seated
    /// for `sit` s, stands up, walks back to `a`, turns and repeats — the sitting down and
    /// getting up of the TUM fr3 walking sequences. The stool is part of the mover (still).
    SitStand {
        /// Start point (x, y) on the floor.
        a: [f32; 2],
        /// Stool position (x, y).
        b: [f32; 2],
        /// Walking speed (m/s).
        speed: f32,
        /// Seconds seated per cycle.
        sit: f32,
        /// Time offset into the cycle (s).
        offset: f32,
        /// Material of the stool.
        stool: usize,
    },
    /// A seated person moving one arm (lifting a cup): `period` s per lift, resting `rest`
    /// fraction of each period; everything else stays still.
    Sitter {
        /// Seat position (x, y) on the floor.
        seat: [f32; 2],
        /// Direction the person faces (radians, 0 = +x).
        heading: f32,
        /// Seconds per arm cycle.
        period: f32,
        /// Fraction of the cycle with the arm at rest.
        rest: f32,
        /// Phase offset (s).
        offset: f32,
    },
    /// A rigid flying object on a smooth Lissajous path with constant spin.
    Flyer {
        /// Its shape.
        shape: Shape,
        /// Centre of the motion.
        centre: Vector3<f32>,
        /// Amplitudes along x, y, z (m).
        amplitude: Vector3<f32>,
        /// Angular frequencies (rad/s).
        omega: Vector3<f32>,
        /// Phases (rad).
        phase: Vector3<f32>,
        /// Spin axis (unit) and rate (rad/s).
        spin: (Vector3<f32>, f32),
    },
    /// A rigid object that crosses from `a` to `b` in `cross` s, then stays out of view
    /// until the `period` elapses (occlusion close to the camera).
    Passer {
        /// Its shape.
        shape: Shape,
        /// Start point.
        a: Vector3<f32>,
        /// End point.
        b: Vector3<f32>,
        /// Seconds per crossing.
        cross: f32,
        /// Seconds per cycle (≥ cross).
        period: f32,
        /// Phase offset (s).
        offset: f32,
    },
    /// A person following a timed script (walking, standing, turning, carrying).
    Scripted(Script),
    /// A box resting on the floor or carried by a scripted person (`look.shirt` material).
    Carried(CarriedBox),
    /// An object thrown back and forth on a ballistic arc (`look.shirt` material).
    Thrown(Throw),
}

/// A mover: motion kind plus materials.
#[derive(Clone, Debug)]
pub struct Mover {
    /// What it does.
    pub kind: MoverKind,
    /// People: the look; rigid objects use `look.shirt` as their material.
    pub look: PersonLook,
}

/// Body pose on a path: floor position, heading (radians, direction of +y body axis) and
/// distance walked so far (for the gait phase). `tw` is the walking time.
pub(crate) fn on_path(path: &Path, speed: f32, tw: f32) -> ([f32; 2], f32, f32, f32) {
    match *path {
        Path::PingPong { a, b } => {
            let dx = b[0] - a[0];
            let dy = b[1] - a[1];
            let len = dx.hypot(dy).max(1e-3);
            // Whole number of strides per leg so that the turns start with both feet together.
            let strides = (len / body::STRIDE).round().max(1.0);
            let stride = len / strides;
            let walk = len / speed;
            let turn = 1.0;
            let cycle = 2.0 * (walk + turn);
            let tc = tw.rem_euclid(cycle);
            let fwd = dy.atan2(dx);
            let back = fwd + PI;
            // (position, heading, distance walked this cycle, gait amplitude)
            let (pos, head, dist, amp) = if tc < walk {
                let f = tc / walk;
                ([a[0] + dx * f, a[1] + dy * f], fwd, tc * speed, 1.0)
            } else if tc < walk + turn {
                let f = (tc - walk) / turn;
                let e = f * f * (3.0 - 2.0 * f);
                (b, fwd + PI * e, len, 0.0)
            } else if tc < 2.0 * walk + turn {
                let f = (tc - walk - turn) / walk;
                (
                    [b[0] - dx * f, b[1] - dy * f],
                    back,
                    len + (tc - walk - turn) * speed,
                    1.0,
                )
            } else {
                let f = (tc - 2.0 * walk - turn) / turn;
                let e = f * f * (3.0 - 2.0 * f);
                (a, back + PI * e, 2.0 * len, 0.0)
            };
            (pos, head, TAU * dist / stride, amp)
        }
        Path::Ellipse { centre, radii } => {
            let circ = PI
                * (3.0 * (radii[0] + radii[1])
                    - ((3.0 * radii[0] + radii[1]) * (radii[0] + 3.0 * radii[1])).sqrt());
            let strides = (circ / body::STRIDE).round().max(1.0);
            let theta = TAU * (tw * speed / circ);
            let pos = [
                centre[0] + radii[0] * theta.cos(),
                centre[1] + radii[1] * theta.sin(),
            ];
            let head = (radii[1] * theta.cos()).atan2(-radii[0] * theta.sin());
            (pos, head, theta * strides, 1.0)
        }
    }
}

/// Position, heading, gait phase, gait amplitude and sitting amount (0 standing, 1 seated)
/// of a [`MoverKind::SitStand`] person at time `t`.
fn sit_stand(
    a: [f32; 2],
    b: [f32; 2],
    speed: f32,
    sit: f32,
    t: f32,
) -> ([f32; 2], f32, f32, f32, f32) {
    let dx = b[0] - a[0];
    let dy = b[1] - a[1];
    let len = dx.hypot(dy).max(1e-3);
    let strides = (len / body::STRIDE).round().max(1.0);
    let stride = len / strides;
    let walk = len / speed;
    let (turn, down) = (1.0, 1.2);
    // walk a→b, turn, sit down, seated, get up, walk b→a, turn
    let cycle = 2.0 * walk + 2.0 * turn + 2.0 * down + sit;
    let tc = t.rem_euclid(cycle);
    let fwd = dy.atan2(dx);
    let back = fwd + PI;
    let smooth = |f: f32| f * f * (3.0 - 2.0 * f);
    let k = TAU / stride;
    let t1 = walk;
    let t2 = t1 + turn;
    let t3 = t2 + down;
    let t4 = t3 + sit;
    let t5 = t4 + down;
    let t6 = t5 + walk;
    if tc < t1 {
        let f = tc / walk;
        (
            [a[0] + dx * f, a[1] + dy * f],
            fwd,
            k * tc * speed,
            1.0,
            0.0,
        )
    } else if tc < t2 {
        (b, fwd + PI * smooth((tc - t1) / turn), k * len, 0.0, 0.0)
    } else if tc < t3 {
        (b, back, k * len, 0.0, smooth((tc - t2) / down))
    } else if tc < t4 {
        (b, back, k * len, 0.0, 1.0)
    } else if tc < t5 {
        (b, back, k * len, 0.0, 1.0 - smooth((tc - t4) / down))
    } else if tc < t6 {
        let f = (tc - t5) / walk;
        (
            [b[0] - dx * f, b[1] - dy * f],
            back,
            k * (len + (tc - t5) * speed),
            1.0,
            0.0,
        )
    } else {
        let f = (tc - t6) / turn;
        (a, back + PI * smooth(f), k * 2.0 * len, 0.0, 0.0)
    }
}

impl Mover {
    /// Number of parts this mover has at any time.
    pub fn part_count(&self) -> usize {
        match self.kind {
            MoverKind::Walker { .. } | MoverKind::Sitter { .. } | MoverKind::Scripted(_) => 10,
            MoverKind::SitStand { .. } => 11,
            MoverKind::Flyer { .. }
            | MoverKind::Passer { .. }
            | MoverKind::Carried(_)
            | MoverKind::Thrown(_) => 1,
        }
    }

    /// Appends the world-posed parts at time `t` (seconds) to `out`.
    pub fn parts(&self, t: f32, out: &mut Vec<Primitive>) {
        match &self.kind {
            MoverKind::Walker {
                path,
                speed,
                start_delay,
                offset,
            } => {
                let tw = (t - start_delay).max(0.0) + offset;
                let (pos, heading, phi, amp) = on_path(path, *speed, tw);
                let pose = gait(phi, amp);
                let bob = 0.015 * amp * (2.0 * phi).cos().abs();
                let mut body = body_frame(pos, heading);
                body.translation.vector.z += bob - 0.015 * amp;
                person_parts(&body, body::HIP_Z, &pose, &self.look, out);
            }
            MoverKind::SitStand {
                a,
                b,
                speed,
                sit,
                offset,
                stool,
            } => {
                let (pos, heading, phi, amp, s) = sit_stand(*a, *b, *speed, *sit, t + offset);
                let mut pose = gait(phi, amp);
                // Seated pose as for `Sitter`, blended in while sitting down / getting up.
                for side in 0..2 {
                    pose.hip[side] += s * FRAC_PI_2;
                    pose.knee[side] += s * (FRAC_PI_2 - pose.knee[side]);
                    pose.elbow[side] += s * 0.5;
                    pose.shoulder[side] += s * 0.2;
                }
                let hip_z = body::HIP_Z + s * (body::SEAT_Z + body::THIGH_R - body::HIP_Z);
                let bob = 0.015 * amp * (2.0 * phi).cos().abs();
                let mut bodyf = body_frame(pos, heading);
                bodyf.translation.vector.z += bob - 0.015 * amp;
                person_parts(&bodyf, hip_z, &pose, &self.look, out);
                // The stool stands at `b` behind the hips of the seated person.
                let h = body::SEAT_Z * 0.5;
                let stool_pose = body_frame(*b, heading)
                    * iso(Vector3::new(0.0, -0.2, h), UnitQuaternion::identity());
                out.push(Primitive::new(
                    Shape::Box {
                        half: Vector3::new(0.2, 0.14, h),
                    },
                    stool_pose,
                    *stool,
                ));
            }
            MoverKind::Sitter {
                seat,
                heading,
                period,
                rest,
                offset,
            } => {
                let tc = ((t + offset) / period).rem_euclid(1.0);
                let active = 1.0 - rest;
                // Smooth lift 0→1→0 during the active part of the cycle, still otherwise.
                let lift = if tc < active {
                    let f = tc / active;
                    (PI * f).sin().powi(2)
                } else {
                    0.0
                };
                let pose = Pose {
                    hip: [FRAC_PI_2, FRAC_PI_2],
                    knee: [FRAC_PI_2, FRAC_PI_2],
                    shoulder: [0.15 + 0.9 * lift, 0.25],
                    shoulder_out: [0.1, 0.12],
                    elbow: [0.5 + 1.4 * lift, 0.9],
                };
                let body = body_frame(*seat, *heading);
                person_parts(&body, body::SEAT_Z + body::THIGH_R, &pose, &self.look, out);
            }
            MoverKind::Flyer {
                shape,
                centre,
                amplitude,
                omega,
                phase,
                spin,
            } => {
                let p = Vector3::new(
                    centre.x + amplitude.x * (omega.x * t + phase.x).sin(),
                    centre.y + amplitude.y * (omega.y * t + phase.y).sin(),
                    centre.z + amplitude.z * (omega.z * t + phase.z).sin(),
                );
                let r = UnitQuaternion::from_axis_angle(
                    &nalgebra::Unit::new_normalize(spin.0),
                    spin.1 * t,
                );
                out.push(Primitive::new(*shape, iso(p, r), self.look.shirt));
            }
            MoverKind::Passer {
                shape,
                a,
                b,
                cross,
                period,
                offset,
            } => {
                let tc = (t + offset).rem_euclid(*period);
                let f = (tc / cross).clamp(0.0, 1.0);
                let p = a + (b - a) * f;
                let r = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.6 * f);
                out.push(Primitive::new(*shape, iso(p, r), self.look.shirt));
            }
            MoverKind::Scripted(s) => s.person_parts(t, &self.look, out),
            MoverKind::Carried(b) => b.parts(t, self.look.shirt, out),
            MoverKind::Thrown(th) => th.parts(t, self.look.shirt, out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn look() -> PersonLook {
        PersonLook {
            shirt: 0,
            trousers: 1,
            skin: 2,
            head: 3,
        }
    }

    #[test]
    fn walker_feet_stay_near_floor_and_part_count_is_constant() {
        let m = Mover {
            kind: MoverKind::Walker {
                path: Path::PingPong {
                    a: [-1.0, 0.5],
                    b: [1.0, 0.5],
                },
                speed: 0.8,
                start_delay: 0.0,
                offset: 0.0,
            },
            look: look(),
        };
        for i in 0..200 {
            let mut parts = Vec::new();
            m.parts(i as f32 / 30.0, &mut parts);
            assert_eq!(parts.len(), m.part_count());
            // Lowest point of the shins (parts 3 and 7) is within a few cm of the floor.
            let lowest = parts
                .iter()
                .flat_map(|p| p.world_corners())
                .map(|c| c.z)
                .fold(f32::INFINITY, f32::min);
            assert!(lowest > -0.12 && lowest < 0.1, "frame {i}: lowest {lowest}");
        }
    }

    #[test]
    fn sit_stander_sits_down_gets_up_and_keeps_feet_near_the_floor() {
        let m = Mover {
            kind: MoverKind::SitStand {
                a: [0.7, 1.1],
                b: [-0.3, -0.15],
                speed: 0.7,
                sit: 2.0,
                offset: 0.0,
                stool: 0,
            },
            look: look(),
        };
        let (mut low_head, mut high_head) = (f32::INFINITY, f32::NEG_INFINITY);
        for i in 0..400 {
            let mut parts = Vec::new();
            m.parts(i as f32 / 30.0, &mut parts);
            assert_eq!(parts.len(), m.part_count());
            // Person parts only (the stool is the last part and stands on the floor).
            let lowest = parts[..10]
                .iter()
                .flat_map(|p| p.world_corners())
                .map(|c| c.z)
                .fold(f32::INFINITY, f32::min);
            assert!(
                lowest > -0.12 && lowest < 0.12,
                "frame {i}: lowest {lowest}"
            );
            let head = parts[1].pose.translation.vector.z;
            low_head = low_head.min(head);
            high_head = high_head.max(head);
        }
        // Seated, the head is about 0.3 m lower than standing.
        assert!(high_head - low_head > 0.25, "head {low_head}..{high_head}");
    }

    #[test]
    fn sitter_moves_only_the_arm() {
        let m = Mover {
            kind: MoverKind::Sitter {
                seat: [0.0, 0.0],
                heading: 0.0,
                period: 4.0,
                rest: 0.3,
                offset: 0.0,
            },
            look: look(),
        };
        let mut a = Vec::new();
        let mut b = Vec::new();
        m.parts(0.5, &mut a);
        m.parts(0.6, &mut b);
        let moved: Vec<usize> = (0..a.len())
            .filter(|&j| (a[j].pose.to_homogeneous() - b[j].pose.to_homogeneous()).norm() > 1e-6)
            .collect();
        // Parts 4, 5 are the upper arm and forearm of the first side.
        assert_eq!(moved, vec![4, 5]);
    }
}
