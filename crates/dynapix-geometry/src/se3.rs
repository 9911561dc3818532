//! SE3: rigid transforms as `nalgebra::Isometry3<f64>` plus the exponential and logarithm
//! maps, the adjoint, the left/right Jacobians, and conversions to and from quaternions and
//! matrices (TUM `tx ty tz qx qy qz qw` lines, KITTI 3×4 rows). Tangent vectors are ordered
//! `[ω (rotation); ρ (translation)]`, as in ORB-SLAM2/g2o.
//!
//! Conventions: `exp(ξ + δ) ≈ exp(J_l(ξ)·δ)·exp(ξ) ≈ exp(ξ)·exp(J_r(ξ)·δ)` and
//! `T·exp(ξ)·T⁻¹ = exp(Ad_T·ξ)`.

use nalgebra::{
    Isometry3, Matrix3, Matrix4, Matrix6, Quaternion, Rotation3, Translation3, UnitQuaternion,
    Vector3, Vector6,
};

/// A rigid transform. `T_ab` maps points from frame b into frame a.
pub type Se3 = Isometry3<f64>;

/// Below this rotation angle (radians) the Jacobians use their Taylor limits, because the
/// closed forms divide small differences by powers of θ.
const SMALL_ANGLE: f64 = 1e-4;

/// Skew-symmetric (cross-product) matrix of `v`.
pub fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Inverse of [`hat`]: the vector of a skew-symmetric matrix (antisymmetric part).
pub fn vee(m: &Matrix3<f64>) -> Vector3<f64> {
    Vector3::new(
        0.5 * (m[(2, 1)] - m[(1, 2)]),
        0.5 * (m[(0, 2)] - m[(2, 0)]),
        0.5 * (m[(1, 0)] - m[(0, 1)]),
    )
}

/// Left Jacobian of SO3 at `omega` (maps ρ to the translation in `exp`).
pub fn so3_left_jacobian(omega: &Vector3<f64>) -> Matrix3<f64> {
    let theta = omega.norm();
    let w = hat(omega);
    if theta < 1e-8 {
        return Matrix3::identity() + 0.5 * w;
    }
    let t2 = theta * theta;
    Matrix3::identity()
        + (1.0 - theta.cos()) / t2 * w
        + (theta - theta.sin()) / (t2 * theta) * (w * w)
}

/// Inverse of [`so3_left_jacobian`].
pub fn so3_left_jacobian_inv(omega: &Vector3<f64>) -> Matrix3<f64> {
    let theta = omega.norm();
    let w = hat(omega);
    if theta < 1e-8 {
        return Matrix3::identity() - 0.5 * w;
    }
    let half = 0.5 * theta;
    let cot = half.cos() / half.sin();
    Matrix3::identity() - 0.5 * w + (1.0 - half * cot) / (theta * theta) * (w * w)
}

/// Right Jacobian of SO3: `J_r(ω) = J_l(−ω)`.
pub fn so3_right_jacobian(omega: &Vector3<f64>) -> Matrix3<f64> {
    so3_left_jacobian(&(-omega))
}

/// Inverse of [`so3_right_jacobian`].
pub fn so3_right_jacobian_inv(omega: &Vector3<f64>) -> Matrix3<f64> {
    so3_left_jacobian_inv(&(-omega))
}

/// Exponential map: tangent `[ω; ρ]` to a rigid transform.
pub fn exp(xi: &Vector6<f64>) -> Se3 {
    let omega = Vector3::new(xi[0], xi[1], xi[2]);
    let rho = Vector3::new(xi[3], xi[4], xi[5]);
    let rot = UnitQuaternion::from_scaled_axis(omega);
    let t = so3_left_jacobian(&omega) * rho;
    Isometry3::from_parts(Translation3::from(t), rot)
}

/// Logarithm map: rigid transform to tangent `[ω; ρ]` (inverse of [`exp`]).
pub fn log(t: &Se3) -> Vector6<f64> {
    let omega = t.rotation.scaled_axis();
    let rho = so3_left_jacobian_inv(&omega) * t.translation.vector;
    Vector6::new(omega.x, omega.y, omega.z, rho.x, rho.y, rho.z)
}

/// Adjoint matrix `Ad_T = [[R, 0], [t^·R, R]]` for the `[ω; ρ]` order, so that
/// `T·exp(ξ)·T⁻¹ = exp(Ad_T·ξ)`.
pub fn adjoint(t: &Se3) -> Matrix6<f64> {
    let r = t.rotation.to_rotation_matrix().into_inner();
    let tr = hat(&t.translation.vector) * r;
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(3, 0).copy_from(&tr);
    ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    ad
}

/// Lie-algebra adjoint `ad_ξ = [[ω^, 0], [ρ^, ω^]]` (the derivative of [`adjoint`]).
pub fn ad(xi: &Vector6<f64>) -> Matrix6<f64> {
    let w = hat(&Vector3::new(xi[0], xi[1], xi[2]));
    let r = hat(&Vector3::new(xi[3], xi[4], xi[5]));
    let mut m = Matrix6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&w);
    m.fixed_view_mut::<3, 3>(3, 0).copy_from(&r);
    m.fixed_view_mut::<3, 3>(3, 3).copy_from(&w);
    m
}

/// The coupling block `Q(ω, ρ)` of the SE3 left Jacobian (Barfoot, "State Estimation for
/// Robotics", eq. 7.86), written for the `[ω; ρ]` order.
fn q_block(omega: &Vector3<f64>, rho: &Vector3<f64>) -> Matrix3<f64> {
    let theta = omega.norm();
    let w = hat(omega);
    let r = hat(rho);
    let wr = w * r;
    let rw = r * w;
    let wrw = wr * w;
    let (c1, c2, c3) = if theta < SMALL_ANGLE {
        // Taylor limits of the three coefficients at θ → 0.
        (1.0 / 6.0, 1.0 / 24.0, 1.0 / 120.0)
    } else {
        let t2 = theta * theta;
        let (s, c) = theta.sin_cos();
        (
            (theta - s) / (t2 * theta),
            (t2 + 2.0 * c - 2.0) / (2.0 * t2 * t2),
            (2.0 * theta - 3.0 * s + theta * c) / (2.0 * t2 * t2 * theta),
        )
    };
    0.5 * r + c1 * (wr + rw + wrw) + c2 * (w * wr + rw * w - 3.0 * wrw) + c3 * (wrw * w + w * wrw)
}

/// Left Jacobian of SE3 at `ξ = [ω; ρ]`: `exp(ξ + δ) ≈ exp(J_l·δ)·exp(ξ)`.
pub fn left_jacobian(xi: &Vector6<f64>) -> Matrix6<f64> {
    let omega = Vector3::new(xi[0], xi[1], xi[2]);
    let rho = Vector3::new(xi[3], xi[4], xi[5]);
    let j = so3_left_jacobian(&omega);
    let mut m = Matrix6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&j);
    m.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&q_block(&omega, &rho));
    m.fixed_view_mut::<3, 3>(3, 3).copy_from(&j);
    m
}

/// Right Jacobian of SE3: `exp(ξ + δ) ≈ exp(ξ)·exp(J_r·δ)`; equals `J_l(−ξ)`.
pub fn right_jacobian(xi: &Vector6<f64>) -> Matrix6<f64> {
    left_jacobian(&(-xi))
}

/// Inverse of [`left_jacobian`] (block form, no general 6×6 inversion).
pub fn left_jacobian_inv(xi: &Vector6<f64>) -> Matrix6<f64> {
    let omega = Vector3::new(xi[0], xi[1], xi[2]);
    let rho = Vector3::new(xi[3], xi[4], xi[5]);
    let ji = so3_left_jacobian_inv(&omega);
    let q = q_block(&omega, &rho);
    let mut m = Matrix6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&ji);
    m.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-ji * q * ji));
    m.fixed_view_mut::<3, 3>(3, 3).copy_from(&ji);
    m
}

/// Inverse of [`right_jacobian`].
pub fn right_jacobian_inv(xi: &Vector6<f64>) -> Matrix6<f64> {
    left_jacobian_inv(&(-xi))
}

/// Builds a pose from a translation and a quaternion given as `[qx, qy, qz, qw]` (TUM order,
/// scalar last). The quaternion is normalised; `None` if its norm is zero or not finite.
pub fn from_translation_quaternion(t: [f64; 3], q_xyzw: [f64; 4]) -> Option<Se3> {
    let q = Quaternion::new(q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]);
    let n = q.norm();
    if !n.is_finite() || n == 0.0 || t.iter().any(|v| !v.is_finite()) {
        return None;
    }
    Some(Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::new_unchecked(q / n),
    ))
}

/// Splits a pose into translation and quaternion `[qx, qy, qz, qw]` (TUM order).
pub fn to_translation_quaternion(t: &Se3) -> ([f64; 3], [f64; 4]) {
    let v = t.translation.vector;
    let q = t.rotation.quaternion();
    ([v.x, v.y, v.z], [q.i, q.j, q.k, q.w])
}

/// 4×4 homogeneous matrix of a pose.
pub fn to_matrix(t: &Se3) -> Matrix4<f64> {
    t.to_homogeneous()
}

/// Pose from a 4×4 homogeneous matrix. The rotation block is projected onto SO3 (nearest
/// rotation, via SVD) so slightly non-orthonormal input from text files is accepted.
/// `None` if the block is singular, a reflection, or not finite.
pub fn from_matrix(m: &Matrix4<f64>) -> Option<Se3> {
    let r = m.fixed_view::<3, 3>(0, 0).into_owned();
    let t = Vector3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    from_rotation_translation(&r, &t)
}

/// Pose from a 3×4 row-major `[R | t]` (KITTI trajectory line), projected onto SE3 as in
/// [`from_matrix`].
pub fn from_rows_3x4(v: &[f64; 12]) -> Option<Se3> {
    let r = Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]);
    let t = Vector3::new(v[3], v[7], v[11]);
    from_rotation_translation(&r, &t)
}

/// The 3×4 row-major `[R | t]` of a pose (KITTI trajectory line).
pub fn to_rows_3x4(t: &Se3) -> [f64; 12] {
    let m = t.to_homogeneous();
    let mut out = [0.0; 12];
    for (row, chunk) in out.chunks_exact_mut(4).enumerate() {
        for (col, o) in chunk.iter_mut().enumerate() {
            *o = m[(row, col)];
        }
    }
    out
}

/// Nearest rotation to `r` (SVD projection); `None` for reflections or degenerate input.
pub fn nearest_rotation(r: &Matrix3<f64>) -> Option<Rotation3<f64>> {
    if r.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let svd = r.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    if svd.singular_values.min() <= 1e-9 * svd.singular_values.max().max(f64::MIN_POSITIVE) {
        return None;
    }
    let p = u * vt;
    if p.determinant() <= 0.0 {
        return None;
    }
    Some(Rotation3::from_matrix_unchecked(p))
}

fn from_rotation_translation(r: &Matrix3<f64>, t: &Vector3<f64>) -> Option<Se3> {
    if t.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let rot = nearest_rotation(r)?;
    Some(Isometry3::from_parts(
        Translation3::from(*t),
        UnitQuaternion::from_rotation_matrix(&rot),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn tangent() -> impl Strategy<Value = Vector6<f64>> {
        (
            prop::array::uniform3(-1.0f64..1.0),
            0.0f64..3.0,
            prop::array::uniform3(-5.0f64..5.0),
        )
            .prop_map(|(axis, angle, rho)| {
                let a = Vector3::from(axis);
                let w = if a.norm() > 1e-6 {
                    a.normalize() * angle
                } else {
                    Vector3::zeros()
                };
                Vector6::new(w.x, w.y, w.z, rho[0], rho[1], rho[2])
            })
    }

    /// Numeric left Jacobian: column k is `log(exp(ξ + h e_k)·exp(ξ)⁻¹)/h` (central).
    fn numeric_left(xi: &Vector6<f64>) -> Matrix6<f64> {
        let h = 1e-6;
        let base_inv = exp(xi).inverse();
        let mut m = Matrix6::zeros();
        for k in 0..6 {
            let mut d = Vector6::zeros();
            d[k] = h;
            let p = log(&(exp(&(xi + d)) * base_inv));
            let n = log(&(exp(&(xi - d)) * base_inv));
            m.set_column(k, &((p - n) / (2.0 * h)));
        }
        m
    }

    fn numeric_right(xi: &Vector6<f64>) -> Matrix6<f64> {
        let h = 1e-6;
        let base_inv = exp(xi).inverse();
        let mut m = Matrix6::zeros();
        for k in 0..6 {
            let mut d = Vector6::zeros();
            d[k] = h;
            let p = log(&(base_inv * exp(&(xi + d))));
            let n = log(&(base_inv * exp(&(xi - d))));
            m.set_column(k, &((p - n) / (2.0 * h)));
        }
        m
    }

    #[test]
    fn exp_log_round_trip() {
        let xi = Vector6::new(0.1, -0.2, 0.3, 1.0, 2.0, -0.5);
        let back = log(&exp(&xi));
        assert!((back - xi).norm() < 1e-12, "{back:?}");
    }

    #[test]
    fn jacobians_at_tiny_angle_match_numeric() {
        let xi = Vector6::new(3e-5, -1e-5, 2e-5, 0.7, -0.3, 1.1);
        assert!((left_jacobian(&xi) - numeric_left(&xi)).amax() < 1e-6);
        assert!((right_jacobian(&xi) - numeric_right(&xi)).amax() < 1e-6);
    }

    #[test]
    fn matrix_and_quaternion_conversions() {
        let t = exp(&Vector6::new(0.3, -0.1, 0.2, 1.0, 2.0, 3.0));
        let back = from_matrix(&to_matrix(&t)).expect("valid matrix");
        assert!((log(&(back.inverse() * t))).norm() < 1e-12);
        let (tr, q) = to_translation_quaternion(&t);
        let back = from_translation_quaternion(tr, q).expect("valid quaternion");
        assert!((log(&(back.inverse() * t))).norm() < 1e-12);
        let back = from_rows_3x4(&to_rows_3x4(&t)).expect("valid rows");
        assert!((log(&(back.inverse() * t))).norm() < 1e-12);
        assert!(from_translation_quaternion([0.0; 3], [0.0; 4]).is_none());
        let mut refl = Matrix4::identity();
        refl[(2, 2)] = -1.0;
        assert!(from_matrix(&refl).is_none());
    }

    proptest! {
        #[test]
        fn prop_exp_log_round_trip(xi in tangent()) {
            let back = log(&exp(&xi));
            prop_assert!((back - xi).norm() < 1e-9, "{:?} vs {:?}", back, xi);
        }

        #[test]
        fn prop_log_exp_round_trip(xi in tangent()) {
            let t = exp(&xi);
            let back = exp(&log(&t));
            prop_assert!((back.to_homogeneous() - t.to_homogeneous()).amax() < 1e-9);
        }

        #[test]
        fn prop_left_jacobian_matches_numeric(xi in tangent()) {
            let d = (left_jacobian(&xi) - numeric_left(&xi)).amax();
            prop_assert!(d < 1e-5, "max diff {}", d);
        }

        #[test]
        fn prop_right_jacobian_matches_numeric(xi in tangent()) {
            let d = (right_jacobian(&xi) - numeric_right(&xi)).amax();
            prop_assert!(d < 1e-5, "max diff {}", d);
        }

        #[test]
        fn prop_jacobian_inverses(xi in tangent()) {
            let i = Matrix6::<f64>::identity();
            prop_assert!((left_jacobian(&xi) * left_jacobian_inv(&xi) - i).amax() < 1e-9);
            prop_assert!((right_jacobian(&xi) * right_jacobian_inv(&xi) - i).amax() < 1e-9);
        }

        #[test]
        fn prop_adjoint_conjugates(a in tangent(), xi in tangent()) {
            let t = exp(&a);
            let lhs = t * exp(&xi) * t.inverse();
            let rhs = exp(&(adjoint(&t) * xi));
            prop_assert!((lhs.to_homogeneous() - rhs.to_homogeneous()).amax() < 1e-9);
        }

        #[test]
        fn prop_ad_is_derivative_of_adjoint(xi in tangent()) {
            let h = 1e-7;
            let num = (adjoint(&exp(&(xi * h))) - adjoint(&exp(&(xi * -h)))) / (2.0 * h);
            prop_assert!((num - ad(&xi)).amax() < 1e-5);
        }
    }
}
