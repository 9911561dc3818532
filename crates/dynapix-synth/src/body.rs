//! The human body shared by every person mover: dimensions, joint angles, the walking gait,
//! and the ten posed parts (torso, head, two-segment arms and legs) of a person.

use crate::shape::{Primitive, Shape};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use std::f32::consts::FRAC_PI_2;

/// Materials of a person: shirt, trousers, skin/head.
#[derive(Clone, Copy, Debug, Default)]
pub struct PersonLook {
    /// Material of torso and upper arms.
    pub shirt: usize,
    /// Material of the legs.
    pub trousers: usize,
    /// Material of forearms.
    pub skin: usize,
    /// Material of the head (hair and face; one texture tile around the head).
    pub head: usize,
}

/// Body dimensions (metres) shared by all people.
pub(crate) mod dims {
    pub(crate) const HIP_Z: f32 = 0.9;
    pub(crate) const HIP_X: f32 = 0.1;
    pub(crate) const THIGH: f32 = 0.44;
    pub(crate) const SHIN: f32 = 0.42;
    pub(crate) const THIGH_R: f32 = 0.075;
    pub(crate) const SHIN_R: f32 = 0.06;
    pub(crate) const TORSO_HALF: [f32; 3] = [0.17, 0.1, 0.29];
    pub(crate) const TORSO_Z: f32 = 0.29; // torso centre above the hips
    pub(crate) const SHOULDER_X: f32 = 0.23;
    pub(crate) const SHOULDER_Z: f32 = 0.5; // above the hips
    pub(crate) const UPPER_ARM: f32 = 0.28;
    pub(crate) const FOREARM: f32 = 0.27;
    pub(crate) const ARM_R: f32 = 0.05;
    pub(crate) const FOREARM_R: f32 = 0.043;
    pub(crate) const HEAD_R: f32 = 0.115;
    pub(crate) const HEAD_Z: f32 = 0.71; // above the hips
    pub(crate) const STRIDE: f32 = 1.3; // metres per gait cycle
    pub(crate) const SEAT_Z: f32 = 0.47;
}

/// Joint angles of a person (radians). Positive hip/shoulder angles swing the limb forward;
/// positive knee angles bend the shin backwards, positive elbow angles bend the forearm forward.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Pose {
    pub(crate) hip: [f32; 2],
    pub(crate) knee: [f32; 2],
    pub(crate) shoulder: [f32; 2],
    pub(crate) shoulder_out: [f32; 2],
    pub(crate) elbow: [f32; 2],
}

pub(crate) fn rot_x(a: f32) -> UnitQuaternion<f32> {
    UnitQuaternion::from_axis_angle(&Vector3::x_axis(), a)
}

pub(crate) fn rot_y(a: f32) -> UnitQuaternion<f32> {
    UnitQuaternion::from_axis_angle(&Vector3::y_axis(), a)
}

pub(crate) fn iso(t: Vector3<f32>, r: UnitQuaternion<f32>) -> Isometry3<f32> {
    Isometry3::from_parts(Translation3::from(t), r)
}

/// Two-segment limb hanging from `pivot` (body frame): returns the two capsule poses.
pub(crate) fn limb(
    pivot: Vector3<f32>,
    r1: UnitQuaternion<f32>,
    bend: UnitQuaternion<f32>,
    l1: f32,
    l2: f32,
) -> (Isometry3<f32>, Isometry3<f32>) {
    let down = Vector3::new(0.0, 0.0, -1.0);
    let c1 = pivot + r1 * (down * (l1 * 0.5));
    let joint = pivot + r1 * (down * l1);
    let r2 = r1 * bend;
    let c2 = joint + r2 * (down * (l2 * 0.5));
    (iso(c1, r1), iso(c2, r2))
}

/// The ten parts of a person with body frame `body` (origin on the floor below the hips,
/// +y forward, +z up) and hip height `hip_z`, legs either standing or seated.
pub(crate) fn person_parts(
    body_to_world: &Isometry3<f32>,
    hip_z: f32,
    p: &Pose,
    look: &PersonLook,
    out: &mut Vec<Primitive>,
) {
    use dims::*;
    let mut push = |shape: Shape, local: Isometry3<f32>, m: usize| {
        out.push(Primitive::new(shape, body_to_world * local, m));
    };
    let hips = Vector3::new(0.0, 0.0, hip_z);
    push(
        Shape::Box {
            half: Vector3::from(TORSO_HALF),
        },
        iso(
            hips + Vector3::new(0.0, 0.0, TORSO_Z),
            UnitQuaternion::identity(),
        ),
        look.shirt,
    );
    push(
        Shape::Sphere { r: HEAD_R },
        // Texture u = 0.5 (φ = ±π, local -x) must face forward (+y in the body frame).
        iso(
            hips + Vector3::new(0.0, 0.0, HEAD_Z),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -FRAC_PI_2),
        ),
        look.head,
    );
    for side in 0..2 {
        let sx = if side == 0 { -1.0 } else { 1.0 };
        let (a, b) = limb(
            hips + Vector3::new(sx * HIP_X, 0.0, 0.0),
            rot_x(p.hip[side]),
            rot_x(-p.knee[side]),
            THIGH,
            SHIN,
        );
        push(
            Shape::Capsule {
                r: THIGH_R,
                half_h: THIGH * 0.5,
            },
            a,
            look.trousers,
        );
        push(
            Shape::Capsule {
                r: SHIN_R,
                half_h: SHIN * 0.5,
            },
            b,
            look.trousers,
        );
        let (a, b) = limb(
            hips + Vector3::new(sx * SHOULDER_X, 0.0, SHOULDER_Z),
            rot_y(-sx * p.shoulder_out[side]) * rot_x(p.shoulder[side]),
            rot_x(p.elbow[side]),
            UPPER_ARM,
            FOREARM,
        );
        push(
            Shape::Capsule {
                r: ARM_R,
                half_h: UPPER_ARM * 0.5,
            },
            a,
            look.shirt,
        );
        push(
            Shape::Capsule {
                r: FOREARM_R,
                half_h: FOREARM * 0.5,
            },
            b,
            look.skin,
        );
    }
}

/// Walking gait at phase `phi` (radians; one cycle per stride), amplitude scaled by `amp`.
pub(crate) fn gait(phi: f32, amp: f32) -> Pose {
    let hip_a = 0.42 * amp;
    let s = phi.sin();
    let c = phi.cos();
    Pose {
        hip: [hip_a * s, -hip_a * s],
        // The knee bends while the leg swings forward.
        knee: [
            0.08 + 0.6 * amp * c.max(0.0),
            0.08 + 0.6 * amp * (-c).max(0.0),
        ],
        shoulder: [-0.35 * amp * s, 0.35 * amp * s],
        shoulder_out: [0.06, 0.06],
        elbow: [
            0.2 + 0.15 * amp * (-s).max(0.0),
            0.2 + 0.15 * amp * s.max(0.0),
        ],
    }
}

pub(crate) fn body_frame(pos: [f32; 2], heading: f32) -> Isometry3<f32> {
    // Body +y must point along `heading`, so rotate by heading - 90°.
    iso(
        Vector3::new(pos[0], pos[1], 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), heading - FRAC_PI_2),
    )
}
