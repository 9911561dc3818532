//! Scripted movers of the hard-scene presets: a person following timed keyframes (walking,
//! standing, turning, carrying), a box that rests on the floor or is carried by that person,
//! and an object thrown back and forth on a ballistic arc.
//!
//! Every function here is a pure function of time, so the same rigid part at two times gives
//! the exact motion between them (ground-truth flow and the per-pixel "moving" mask).

use crate::body::PersonLook;
use crate::body::{Pose, body_frame, dims, gait, person_parts};
use crate::shape::{Primitive, Shape};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use std::f32::consts::{FRAC_PI_2, PI, TAU};

/// Standard gravity (m/s²) of thrown objects.
pub const GRAVITY: f32 = 9.81;

/// One keyframe of a [`Script`]: where the person stands at time `t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Key {
    /// Time (s).
    pub t: f32,
    /// Floor position (x, y).
    pub pos: [f32; 2],
    /// Direction the person faces (radians, 0 = +x).
    pub heading: f32,
    /// How far the arms are in the carrying pose (0 = free, 1 = holding a box in front).
    pub carry: f32,
}

/// A person's timed path: positions, headings and arm poses interpolated linearly between
/// keys (the heading along the shorter way round); before the first key and after the last
/// the person stands at that key.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Script {
    /// Keys in increasing time.
    pub keys: Vec<Key>,
}

/// Where a script's person is at one time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScriptState {
    /// Floor position (x, y).
    pub pos: [f32; 2],
    /// Heading (radians).
    pub heading: f32,
    /// Gait phase (radians; one cycle per stride).
    pub phase: f32,
    /// Gait amplitude (0 standing, 1 walking).
    pub amp: f32,
    /// Carrying amount (0..1).
    pub carry: f32,
}

fn smooth(f: f32) -> f32 {
    let f = f.clamp(0.0, 1.0);
    f * f * (3.0 - 2.0 * f)
}

fn angle_diff(a: f32, b: f32) -> f32 {
    (b - a + PI).rem_euclid(TAU) - PI
}

/// Seconds over which the legs come to rest or start swinging at a stop.
const GAIT_RAMP: f32 = 0.3;

impl Script {
    /// Builds a script from `(t, [x, y], heading, carry)` tuples.
    pub fn from_keys(keys: &[(f32, [f32; 2], f32, f32)]) -> Self {
        Self {
            keys: keys
                .iter()
                .map(|&(t, pos, heading, carry)| Key {
                    t,
                    pos,
                    heading,
                    carry,
                })
                .collect(),
        }
    }

    fn seg_len(&self, i: usize) -> f32 {
        let (a, b) = (self.keys[i].pos, self.keys[i + 1].pos);
        (b[0] - a[0]).hypot(b[1] - a[1])
    }

    fn moving(&self, i: usize) -> bool {
        i + 1 < self.keys.len() && self.seg_len(i) > 1e-3
    }

    /// The person's state at time `t`.
    pub fn at(&self, t: f32) -> ScriptState {
        let Some(first) = self.keys.first() else {
            return ScriptState {
                pos: [0.0, 0.0],
                heading: 0.0,
                phase: 0.0,
                amp: 0.0,
                carry: 0.0,
            };
        };
        let k = TAU / dims::STRIDE;
        let mut walked = 0.0;
        for i in 0..self.keys.len().saturating_sub(1) {
            let (a, b) = (self.keys[i], self.keys[i + 1]);
            let len = self.seg_len(i);
            if t < b.t && t >= a.t {
                let f = ((t - a.t) / (b.t - a.t).max(1e-6)).clamp(0.0, 1.0);
                let mut amp: f32 = if self.moving(i) { 1.0 } else { 0.0 };
                if self.moving(i) {
                    if i == 0 || !self.moving(i - 1) {
                        amp = amp.min((t - a.t) / GAIT_RAMP);
                    }
                    if !self.moving(i + 1) {
                        amp = amp.min((b.t - t) / GAIT_RAMP);
                    }
                }
                return ScriptState {
                    pos: [
                        a.pos[0] + (b.pos[0] - a.pos[0]) * f,
                        a.pos[1] + (b.pos[1] - a.pos[1]) * f,
                    ],
                    heading: a.heading + angle_diff(a.heading, b.heading) * smooth(f),
                    phase: k * (walked + len * f),
                    amp: amp.clamp(0.0, 1.0),
                    carry: a.carry + (b.carry - a.carry) * smooth(f),
                };
            }
            walked += len;
        }
        let last = if t < first.t {
            walked = 0.0;
            first
        } else {
            self.keys.last().unwrap_or(first)
        };
        ScriptState {
            pos: last.pos,
            heading: last.heading,
            phase: k * walked,
            amp: 0.0,
            carry: last.carry,
        }
    }

    /// Appends the person's ten parts at time `t`.
    pub fn person_parts(&self, t: f32, look: &PersonLook, out: &mut Vec<Primitive>) {
        let s = self.at(t);
        let mut pose: Pose = gait(s.phase, s.amp);
        // Holding a box in front: upper arms forward and out, forearms bent to the box's sides.
        for side in 0..2 {
            pose.shoulder[side] += s.carry * (0.7 - pose.shoulder[side]);
            pose.shoulder_out[side] += s.carry * (0.3 - pose.shoulder_out[side]);
            pose.elbow[side] += s.carry * (0.8 - pose.elbow[side]);
        }
        let bob = 0.015 * s.amp * (2.0 * s.phase).cos().abs();
        let mut body = body_frame(s.pos, s.heading);
        body.translation.vector.z += bob - 0.015 * s.amp;
        person_parts(&body, dims::HIP_Z, &pose, look, out);
    }

    /// Pose of a box of half extents `half` held in front of the person at time `t`.
    pub fn held_pose(&self, t: f32, half: &Vector3<f32>) -> Isometry3<f32> {
        let s = self.at(t);
        body_frame(s.pos, s.heading) * Isometry3::translation(0.0, 0.14 + half.y, dims::HIP_Z + 0.1)
    }

    /// The floor pose of a box of half extents `half` set down straight below where the
    /// person holds it at time `t`.
    pub fn floor_below_hands(&self, t: f32, half: &Vector3<f32>) -> BoxPlace {
        let p = self.held_pose(t, half);
        BoxPlace::Floor {
            pos: [p.translation.vector.x, p.translation.vector.y],
            yaw: self.at(t).heading - FRAC_PI_2,
        }
    }
}

/// Where a [`CarriedBox`] is at one of its keys.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BoxPlace {
    /// Resting on the floor at `pos` (x, y), turned by `yaw` about the vertical.
    Floor {
        /// Centre on the floor.
        pos: [f32; 2],
        /// Rotation about z (radians).
        yaw: f32,
    },
    /// Held by the carrier (see [`Script::held_pose`]).
    Held,
}

/// A rigid box that rests on the floor or is held by a scripted person. Between two keys of
/// different places it is blended smoothly from one to the other (lifted, set down, or
/// pushed along the floor); between two `Held` keys it follows the carrier.
#[derive(Clone, Debug, PartialEq)]
pub struct CarriedBox {
    /// Half extents (m).
    pub half: Vector3<f32>,
    /// The person who carries it.
    pub carrier: Script,
    /// `(time, place)` in increasing time.
    pub keys: Vec<(f32, BoxPlace)>,
}

impl CarriedBox {
    fn place_pose(&self, place: BoxPlace, t: f32) -> Isometry3<f32> {
        match place {
            BoxPlace::Floor { pos, yaw } => Isometry3::from_parts(
                Translation3::new(pos[0], pos[1], self.half.z),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
            ),
            BoxPlace::Held => self.carrier.held_pose(t, &self.half),
        }
    }

    /// The box's pose at time `t`.
    pub fn pose(&self, t: f32) -> Isometry3<f32> {
        let Some(&(_, first)) = self.keys.first() else {
            return Isometry3::translation(0.0, 0.0, self.half.z);
        };
        for w in self.keys.windows(2) {
            let ((ta, a), (tb, b)) = (w[0], w[1]);
            if t >= ta && t < tb {
                if a == b {
                    return self.place_pose(a, t);
                }
                let f = smooth((t - ta) / (tb - ta).max(1e-6));
                let (pa, pb) = (self.place_pose(a, t), self.place_pose(b, t));
                let tr = pa.translation.vector.lerp(&pb.translation.vector, f);
                let rot = pa.rotation.slerp(&pb.rotation, f);
                return Isometry3::from_parts(Translation3::from(tr), rot);
            }
        }
        let place = match self.keys.last() {
            Some(&(tl, p)) if t >= tl => p,
            _ => first,
        };
        self.place_pose(place, t)
    }

    /// Appends the box (one part) at time `t`.
    pub fn parts(&self, t: f32, material: usize, out: &mut Vec<Primitive>) {
        out.push(Primitive::new(
            Shape::Box { half: self.half },
            self.pose(t),
            material,
        ));
    }
}

/// An object thrown back and forth between `a` and `b` (say by two people out of view): held
/// still at `a` for `hold` s, flies to `b` in `flight` s on a ballistic arc, held at `b`,
/// flies back, and so on. It spins about `spin_axis` only while in the air.
#[derive(Clone, Debug, PartialEq)]
pub struct Throw {
    /// Its shape.
    pub shape: Shape,
    /// One end.
    pub a: Vector3<f32>,
    /// The other end.
    pub b: Vector3<f32>,
    /// Seconds in the air per throw.
    pub flight: f32,
    /// Seconds held at each end.
    pub hold: f32,
    /// Time offset into the cycle (s).
    pub offset: f32,
    /// Spin axis (need not be unit).
    pub spin_axis: Vector3<f32>,
    /// Spin rate in the air (rad/s).
    pub spin: f32,
}

impl Throw {
    /// Position at time `t` and the time spent in the air so far (for the spin).
    fn state(&self, t: f32) -> (Vector3<f32>, f32) {
        let cycle = 2.0 * (self.hold + self.flight);
        let tt = t + self.offset;
        let n = (tt / cycle).floor();
        let tc = tt - n * cycle;
        let base_air = n * 2.0 * self.flight;
        let arc = |from: &Vector3<f32>, to: &Vector3<f32>, tau: f32| {
            let f = tau / self.flight;
            from + (to - from) * f + Vector3::z() * (0.5 * GRAVITY * tau * (self.flight - tau))
        };
        if tc < self.hold {
            (self.a, base_air)
        } else if tc < self.hold + self.flight {
            let tau = tc - self.hold;
            (arc(&self.a, &self.b, tau), base_air + tau)
        } else if tc < 2.0 * self.hold + self.flight {
            (self.b, base_air + self.flight)
        } else {
            let tau = tc - 2.0 * self.hold - self.flight;
            (arc(&self.b, &self.a, tau), base_air + self.flight + tau)
        }
    }

    /// The object's pose at time `t`.
    pub fn pose(&self, t: f32) -> Isometry3<f32> {
        let (p, air) = self.state(t);
        let axis = nalgebra::Unit::try_new(self.spin_axis, 1e-6).unwrap_or(Vector3::z_axis());
        Isometry3::from_parts(
            Translation3::from(p),
            UnitQuaternion::from_axis_angle(&axis, self.spin * air),
        )
    }

    /// Appends the object (one part) at time `t`.
    pub fn parts(&self, t: f32, material: usize, out: &mut Vec<Primitive>) {
        out.push(Primitive::new(self.shape, self.pose(t), material));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn walk_stop_walk() -> Script {
        Script::from_keys(&[
            (1.0, [0.0, 0.0], 0.0, 0.0),
            (3.0, [2.0, 0.0], 0.0, 0.0),
            (4.0, [2.0, 0.0], FRAC_PI_2, 1.0),
            (6.0, [2.0, 2.0], FRAC_PI_2, 1.0),
        ])
    }

    #[test]
    fn script_interpolates_and_holds_its_ends() {
        let s = walk_stop_walk();
        let a = s.at(0.0);
        assert_eq!((a.pos, a.amp), ([0.0, 0.0], 0.0));
        let m = s.at(2.0);
        assert!((m.pos[0] - 1.0).abs() < 1e-5 && m.amp == 1.0, "{m:?}");
        // Phase = walked distance in strides; standing keeps it.
        let st = s.at(3.5);
        assert!((st.phase - TAU * 2.0 / dims::STRIDE).abs() < 1e-4 && st.amp == 0.0);
        assert!(st.heading > 0.1 && st.heading < FRAC_PI_2 - 0.1 && st.carry > 0.0);
        let e = s.at(10.0);
        assert_eq!((e.pos, e.heading, e.carry), ([2.0, 2.0], FRAC_PI_2, 1.0));
        // Legs come to rest smoothly before a stop.
        assert!(s.at(2.95).amp < 0.3);
        let mut parts = Vec::new();
        let look = PersonLook {
            shirt: 0,
            trousers: 0,
            skin: 0,
            head: 0,
        };
        s.person_parts(5.0, &look, &mut parts);
        assert_eq!(parts.len(), 10);
    }

    #[test]
    fn carried_box_rests_follows_the_carrier_and_is_continuous() {
        let half = Vector3::new(0.25, 0.25, 0.25);
        let s = walk_stop_walk();
        let floor = s.floor_below_hands(3.0, &half);
        let b = CarriedBox {
            half,
            carrier: s.clone(),
            keys: vec![(3.0, floor), (4.0, BoxPlace::Held)],
        };
        // Resting before the pick-up, on the floor under the hands.
        let p0 = b.pose(0.0);
        let p1 = b.pose(2.9);
        assert_eq!(p0, p1);
        assert!((p0.translation.vector.z - 0.25).abs() < 1e-6);
        // Held: follows the carrier exactly.
        let held = s.held_pose(5.0, &half);
        assert!((b.pose(5.0).translation.vector - held.translation.vector).norm() < 1e-6);
        // No jumps between frames at 30 Hz (the fastest: swung round while the person turns).
        let mut prev = b.pose(0.0);
        for i in 1..240 {
            let p = b.pose(i as f32 / 30.0);
            let d = (p.translation.vector - prev.translation.vector).norm();
            assert!(d < 0.1, "frame {i}: jump {d}");
            prev = p;
        }
    }

    #[test]
    fn throw_follows_a_ballistic_arc_between_its_ends() {
        let th = Throw {
            shape: Shape::Sphere { r: 0.1 },
            a: Vector3::new(-1.0, 0.0, 1.0),
            b: Vector3::new(1.0, 0.0, 1.0),
            flight: 0.5,
            hold: 1.0,
            offset: 0.0,
            spin_axis: Vector3::x(),
            spin: 3.0,
        };
        assert_eq!(th.pose(0.5).translation.vector, th.a);
        let land = th.pose(1.5 + 1e-4).translation.vector;
        assert!((land - th.b).norm() < 1e-2);
        // Apex at mid-flight: g T² / 8 above the ends.
        let apex = th.pose(1.25).translation.vector;
        assert!(
            (apex.z - 1.0 - GRAVITY * 0.25 / 8.0).abs() < 1e-4,
            "{apex:?}"
        );
        // Horizontal speed 2 m / 0.5 s.
        let v = (th.pose(1.3).translation.vector - th.pose(1.2).translation.vector) / 0.1;
        assert!((v.x - 4.0).abs() < 1e-3);
        // Flying back after the second hold.
        let back = th.pose(2.5 + 0.25).translation.vector;
        assert!(back.x.abs() < 1e-3 && back.z > 1.2);
    }
}
