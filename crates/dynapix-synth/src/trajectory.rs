//! Camera motions shaped like the TUM RGB-D walking sequences (`xyz`, `rpy`, `halfsphere`,
//! `static`), smooth random hand-held motion and a closed loop through the room. Poses are
//! camera-to-world (camera: x right, y down, z forward), smooth functions of time with
//! realistic speeds (≤ 0.5 m/s, ≤ 40°/s; checked by a test).

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{PI, TAU};

/// A base viewpoint: camera position and the point it looks at.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rig {
    /// Camera centre (world).
    pub eye: Point3<f64>,
    /// Point the optical axis goes through.
    pub target: Point3<f64>,
}

impl Default for Rig {
    fn default() -> Self {
        Self {
            eye: Point3::new(0.0, -1.5, 1.35),
            target: Point3::new(0.1, 1.3, 0.9),
        }
    }
}

/// Rotation (camera-to-world) of a camera at `eye` looking at `target`, world z up.
pub fn look_at(eye: &Point3<f64>, target: &Point3<f64>) -> UnitQuaternion<f64> {
    let f = (target - eye).normalize();
    let mut x = f.cross(&Vector3::z());
    if x.norm() < 1e-9 {
        x = Vector3::x();
    }
    let x = x.normalize();
    let y = f.cross(&x);
    let m = Matrix3::from_columns(&[x, y, f]);
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m))
}

/// Shortest loop period (s) that keeps the loop within walking speed (≤ 0.5 m/s, ≤ 40°/s).
pub const MIN_LOOP_PERIOD: f64 = 10.0;

/// Laps of the `loop` preset's camera in a long sequence: the camera passes its start,
/// re-observes the first views (several keyframes), as a loop closure needs, and goes on through
/// the mapped room for half a lap, where a closed loop pays off and an open one keeps drifting.
pub const LOOP_LAPS: f64 = 1.5;

/// Kind of camera motion.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MotionKind {
    /// Nearly static camera: a few millimetres and tenths of a degree of jitter.
    Static,
    /// Translation oscillating along x, y and z (±0.3 m), fixed orientation.
    Xyz,
    /// Rotation about roll, pitch and yaw (±15–20°) at a fixed position.
    Rpy,
    /// On a half sphere of ~1 m diameter behind the base position, looking at the target.
    Halfsphere,
    /// Smooth random hand-held motion.
    Handheld,
    /// A closed loop through the room that returns to the start after `period` seconds.
    Loop,
    /// Following a person around the room from behind ([`CameraMotion::follow`]).
    Follow,
}

/// A camera following a person who walks counter-clockwise around an ellipse (the
/// [`crate::movers::Path::Ellipse`] walker with the same centre, radii, speed and offset): it
/// trails the person by `lag` radians of the ellipse, on an ellipse `widen` metres larger, at
/// height `eye_z`, and looks at the person's body at height `aim_z`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Follow {
    /// Centre of the walker's ellipse (x, y).
    pub centre: [f64; 2],
    /// Radii of the walker's ellipse along x and y.
    pub radii: [f64; 2],
    /// Walking speed (m/s).
    pub speed: f64,
    /// The walker's time offset into the path (s).
    pub offset: f64,
    /// Angle (radians of the ellipse parameter) by which the camera trails the walker.
    pub lag: f64,
    /// Metres added to both radii for the camera's ellipse.
    pub widen: f64,
    /// Camera height (m).
    pub eye_z: f64,
    /// Height of the point looked at on the walker (m).
    pub aim_z: f64,
}

impl Follow {
    /// Ellipse parameter of the walker at time `t`, as [`crate::movers::Path::Ellipse`]
    /// computes it (Ramanujan's perimeter, uniform in the parameter).
    pub fn walker_angle(&self, t: f64) -> f64 {
        let [a, b] = self.radii;
        let circ = PI * (3.0 * (a + b) - ((3.0 * a + b) * (a + 3.0 * b)).sqrt());
        TAU * ((t + self.offset) * self.speed / circ)
    }

    /// The walker's floor position at time `t`.
    pub fn walker(&self, t: f64) -> [f64; 2] {
        let th = self.walker_angle(t);
        [
            self.centre[0] + self.radii[0] * th.cos(),
            self.centre[1] + self.radii[1] * th.sin(),
        ]
    }

    /// Camera centre and the point it looks at, at time `t`.
    pub fn eye_target(&self, t: f64) -> (Point3<f64>, Point3<f64>) {
        let th = self.walker_angle(t) - self.lag;
        let eye = Point3::new(
            self.centre[0] + (self.radii[0] + self.widen) * th.cos(),
            self.centre[1] + (self.radii[1] + self.widen) * th.sin(),
            self.eye_z,
        );
        let w = self.walker(t);
        (eye, Point3::new(w[0], w[1], self.aim_z))
    }
}

/// A camera motion: kind, base rig, random phases (from the seed) and loop period.
#[derive(Clone, Debug)]
pub struct CameraMotion {
    /// Motion kind.
    pub kind: MotionKind,
    /// Base viewpoint.
    pub rig: Rig,
    /// Loop period in seconds (only [`MotionKind::Loop`]).
    pub loop_period: f64,
    /// The person followed ([`MotionKind::Follow`]; without it that kind stands at the rig).
    pub follow: Option<Follow>,
    /// Random sinusoid components: per channel (x, y, z, target x/y/z, roll) lists of
    /// (amplitude, angular frequency, phase).
    waves: Vec<Vec<(f64, f64, f64)>>,
}

fn waves(rng: &mut ChaCha8Rng, n: usize, amp: f64, f_lo: f64, f_hi: f64) -> Vec<(f64, f64, f64)> {
    (0..n)
        .map(|k| {
            let a = amp / (k as f64 + 1.0);
            let f = rng.random_range(f_lo..f_hi);
            (a, TAU * f, rng.random_range(0.0..TAU))
        })
        .collect()
}

fn eval(w: &[(f64, f64, f64)], t: f64) -> f64 {
    w.iter().map(|&(a, om, ph)| a * (om * t + ph).sin()).sum()
}

impl CameraMotion {
    /// A motion of `kind` around `rig`, random parts drawn from `seed`.
    pub fn new(kind: MotionKind, rig: Rig, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xCA3E_7A00_0000_0002);
        let waves = match kind {
            // Jitter: millimetres and tenths of a degree, frequencies of a hand at rest.
            MotionKind::Static => (0..7)
                .map(|c| {
                    let amp = if c < 3 {
                        0.003
                    } else if c < 6 {
                        0.006
                    } else {
                        0.004
                    };
                    waves(&mut rng, 3, amp, 0.2, 1.2)
                })
                .collect(),
            MotionKind::Handheld => (0..7)
                .map(|c| {
                    let amp = if c < 3 {
                        0.16
                    } else if c < 6 {
                        0.35
                    } else {
                        0.05
                    };
                    waves(&mut rng, 3, amp, 0.04, 0.18)
                })
                .collect(),
            // Deterministic shapes get small random wobble only.
            _ => (0..7)
                .map(|c| {
                    let amp = if c < 3 {
                        0.01
                    } else if c < 6 {
                        0.02
                    } else {
                        0.01
                    };
                    waves(&mut rng, 2, amp, 0.1, 0.5)
                })
                .collect(),
        };
        Self {
            kind,
            rig,
            loop_period: MIN_LOOP_PERIOD,
            follow: None,
            waves,
        }
    }

    /// Camera-to-world pose at time `t` (seconds).
    pub fn pose(&self, t: f64) -> Isometry3<f64> {
        let w = |c: usize| eval(&self.waves[c], t);
        let wobble_eye = Vector3::new(w(0), w(1), w(2));
        let wobble_tgt = Vector3::new(w(3), w(4), w(5));
        let roll_w = w(6);
        let rig = self.rig;
        let (eye, rot) = match self.kind {
            MotionKind::Follow => {
                let (eye, target) = match self.follow {
                    Some(f) => f.eye_target(t),
                    None => (rig.eye, rig.target),
                };
                let eye = eye + wobble_eye;
                (eye, look_at(&eye, &(target + wobble_tgt)))
            }
            MotionKind::Static | MotionKind::Handheld => {
                let eye = rig.eye + wobble_eye;
                let r = look_at(&eye, &(rig.target + wobble_tgt));
                (
                    eye,
                    r * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), roll_w),
                )
            }
            MotionKind::Xyz => {
                let off = Vector3::new(
                    0.3 * (TAU * t / 7.0).sin(),
                    0.25 * (TAU * t / 9.0 + 1.0).sin(),
                    0.2 * (TAU * t / 5.5 + 2.0).sin(),
                );
                let eye = rig.eye + off + wobble_eye;
                (eye, look_at(&rig.eye, &rig.target))
            }
            MotionKind::Rpy => {
                let roll = 15f64.to_radians() * (TAU * t / 6.0).sin();
                let pitch = 15f64.to_radians() * (TAU * t / 7.5 + 0.7).sin();
                let yaw = 20f64.to_radians() * (TAU * t / 9.0 + 1.9).sin();
                let base = look_at(&rig.eye, &rig.target);
                // Camera frame: roll about z (optical axis), pitch about x, yaw about y (down).
                let r = base * UnitQuaternion::from_euler_angles(pitch, yaw, roll);
                (rig.eye + wobble_eye, r)
            }
            MotionKind::Halfsphere => {
                let radius = 0.5;
                let az = 60f64.to_radians() * (TAU * t / 10.0).sin();
                let el = 25f64.to_radians() + 25f64.to_radians() * (TAU * t / 7.0 + 0.5).sin();
                let back = (rig.eye - rig.target).normalize();
                let side = Vector3::z().cross(&back).normalize();
                let up = back.cross(&side);
                let dir =
                    back * (az.cos() * el.cos()) + side * (az.sin() * el.cos()) + up * el.sin();
                // Sphere centre ahead of the base eye so the camera stays clear of the wall behind.
                let eye = rig.eye - back * 0.4 + dir * radius + wobble_eye;
                (eye, look_at(&eye, &(rig.target + wobble_tgt)))
            }
            MotionKind::Loop => {
                // Circle around the room centre, looking across the centre at the opposite
                // side: the view turns at a uniform rate and sweeps all walls once per loop.
                let th = TAU * t / self.loop_period - PI / 2.0;
                let c = Vector3::new(0.2, 0.1, 1.35);
                let eye = Point3::from(
                    c + Vector3::new(0.55 * th.cos(), 0.55 * th.sin(), 0.06 * (2.0 * th).sin()),
                );
                let ta = th + PI;
                let target = Point3::new(c.x + 2.0 * ta.cos(), c.y + 2.0 * ta.sin(), 0.95);
                (
                    eye + wobble_eye * 0.5,
                    look_at(&eye, &(target + wobble_tgt)),
                )
            }
        };
        Isometry3::from_parts(Translation3::from(eye.coords), rot)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn speeds_are_realistic_and_loop_closes() {
        let dt = 1.0 / 30.0;
        for kind in [
            MotionKind::Static,
            MotionKind::Xyz,
            MotionKind::Rpy,
            MotionKind::Halfsphere,
            MotionKind::Handheld,
            MotionKind::Loop,
        ] {
            for seed in 0..3 {
                let m = CameraMotion::new(kind, Rig::default(), seed);
                let mut max_v: f64 = 0.0;
                let mut max_w: f64 = 0.0;
                for i in 0..900 {
                    let a = m.pose(i as f64 * dt);
                    let b = m.pose((i + 1) as f64 * dt);
                    let d = a.inverse() * b;
                    max_v = max_v.max(d.translation.vector.norm() / dt);
                    max_w = max_w.max(d.rotation.angle().to_degrees() / dt);
                    // The camera stays inside the room, away from walls.
                    let p = a.translation.vector;
                    assert!(
                        p.x.abs() < 2.3 && p.y > -1.9 && p.y < 2.2 && p.z > 0.5 && p.z < 2.4,
                        "{kind:?} {p:?}"
                    );
                }
                assert!(max_v <= 0.5, "{kind:?}: {max_v} m/s");
                assert!(max_w <= 40.0, "{kind:?}: {max_w} deg/s");
                if kind == MotionKind::Static {
                    assert!(
                        max_v < 0.05 && max_w < 5.0,
                        "static too fast: {max_v} {max_w}"
                    );
                }
            }
        }
        let m = CameraMotion::new(MotionKind::Loop, Rig::default(), 1);
        let d = m.pose(0.0).inverse() * m.pose(m.loop_period);
        assert!(d.translation.vector.norm() < 0.05 && d.rotation.angle() < 0.05);
    }
}
