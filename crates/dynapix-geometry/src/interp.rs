//! Pose interpolation: rotation by quaternion SLERP (shortest arc), translation linearly.
//! Used to read ground truth at frame timestamps (the motion-capture rate differs from the
//! camera rate) and by the evaluation code.

use crate::se3::Se3;
use nalgebra::{Isometry3, Translation3};

/// Interpolates between `a` (at `alpha = 0`) and `b` (at `alpha = 1`): SLERP of the rotation
/// along the shortest arc, linear interpolation of the translation. `alpha` outside [0, 1]
/// extrapolates the translation and clamps nothing (callers choose).
pub fn interpolate(a: &Se3, b: &Se3, alpha: f64) -> Se3 {
    let rot = a.rotation.slerp(&b.rotation, alpha);
    let t = a.translation.vector.lerp(&b.translation.vector, alpha);
    Isometry3::from_parts(Translation3::from(t), rot)
}

/// Pose at time `t` in a trajectory sorted by timestamp, interpolated between the two
/// bracketing samples. `None` when `t` is outside `[first, last]` or the trajectory is empty.
/// An exact timestamp match returns that sample.
pub fn interpolate_at(traj: &[(f64, Se3)], t: f64) -> Option<Se3> {
    let (first, last) = (traj.first()?, traj.last()?);
    if !(t >= first.0 && t <= last.0) {
        return None;
    }
    // Index of the first sample with timestamp > t.
    let hi = traj.partition_point(|(s, _)| *s <= t);
    if hi == 0 {
        return None;
    }
    let (t0, p0) = traj.get(hi - 1)?;
    if *t0 == t {
        return Some(*p0);
    }
    let (t1, p1) = traj.get(hi)?;
    let span = t1 - t0;
    if span <= 0.0 {
        return Some(*p0);
    }
    Some(interpolate(p0, p1, (t - t0) / span))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::se3::{exp, log};
    use nalgebra::Vector6;

    #[test]
    fn midpoint_of_pure_rotation_is_half_angle() {
        let a = Se3::identity();
        let b = exp(&Vector6::new(0.0, 0.0, 1.2, 2.0, 0.0, -4.0));
        let m = interpolate(&a, &b, 0.5);
        assert!((m.rotation.angle() - 0.6).abs() < 1e-12);
        assert!((m.translation.vector - b.translation.vector * 0.5).norm() < 1e-12);
        assert!(log(&(interpolate(&a, &b, 1.0).inverse() * b)).norm() < 1e-12);
        assert!(log(&interpolate(&a, &b, 0.0)).norm() < 1e-12);
    }

    #[test]
    fn shortest_arc_is_taken() {
        // Same rotation with opposite quaternion signs must not spin by 2π.
        let a = Se3::identity();
        let mut b = exp(&Vector6::new(0.0, 0.0, 0.2, 0.0, 0.0, 0.0));
        b.rotation = nalgebra::UnitQuaternion::new_unchecked(-b.rotation.into_inner());
        let m = interpolate(&a, &b, 0.5);
        assert!((m.rotation.angle() - 0.1).abs() < 1e-12);
    }

    #[test]
    fn interpolate_at_brackets_and_bounds() {
        let p0 = Se3::identity();
        let p1 = exp(&Vector6::new(0.1, 0.0, 0.0, 1.0, 0.0, 0.0));
        let traj = vec![(1.0, p0), (2.0, p1)];
        assert!(interpolate_at(&traj, 0.999).is_none());
        assert!(interpolate_at(&traj, 2.001).is_none());
        assert!(interpolate_at(&[], 1.0).is_none());
        let m = interpolate_at(&traj, 1.25).expect("inside");
        assert!((m.translation.x - 0.25).abs() < 1e-12);
        let e = interpolate_at(&traj, 2.0).expect("end");
        assert!(log(&(e.inverse() * p1)).norm() < 1e-12);
    }
}
