//! SE3: rigid transforms as `nalgebra::Isometry3<f64>` plus the exponential and logarithm
//! maps. Tangent vectors are ordered `[ω (rotation); ρ (translation)]`, as in ORB-SLAM2/g2o.

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3, Vector6};

/// A rigid transform. `T_ab` maps points from frame b into frame a.
pub type Se3 = Isometry3<f64>;

/// Skew-symmetric (cross-product) matrix of `v`.
pub fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_log_round_trip() {
        let xi = Vector6::new(0.1, -0.2, 0.3, 1.0, 2.0, -0.5);
        let back = log(&exp(&xi));
        assert!((back - xi).norm() < 1e-12, "{back:?}");
    }
}
