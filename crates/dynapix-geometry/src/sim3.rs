//! Sim3: similarity transforms (rotation, translation, positive scale) as
//! `nalgebra::Similarity3<f64>`, with the exponential and logarithm maps, the adjoint and the
//! left/right Jacobians. Tangent vectors are ordered `[ω (rotation); ρ (translation); σ (log
//! scale)]`, extending the `[ω; ρ]` order of [`crate::se3`]. A point maps as `x ↦ s·R·x + t`.
//!
//! Used for monocular-style scale drift (loop closing) and for Umeyama alignment with scale.

use crate::se3::{self, Se3, hat};
use nalgebra::{
    Matrix3, SMatrix, SVector, Similarity3, Translation3, UnitQuaternion, Vector3, Vector6,
};

/// A similarity transform `x ↦ s·R·x + t`.
pub type Sim3 = Similarity3<f64>;
/// A Sim3 tangent vector `[ω; ρ; σ]`.
pub type Vector7 = SVector<f64, 7>;
/// A 7×7 matrix (Sim3 adjoint and Jacobians).
pub type Matrix7 = SMatrix<f64, 7, 7>;

/// Thresholds below which the closed-form coefficients switch to Taylor limits.
const SMALL_ANGLE: f64 = 1e-5;
const SMALL_SCALE: f64 = 1e-5;

/// Coefficients `(A, B, C)` of `W = A·ω^ + B·ω^² + C·I`, the matrix that maps ρ to the
/// translation in `exp`: `W = ∫₀¹ e^{στ} exp(τ ω^) dτ`.
fn w_coefficients(theta: f64, sigma: f64) -> (f64, f64, f64) {
    let es = sigma.exp();
    let c = if sigma.abs() < SMALL_SCALE {
        1.0 + sigma / 2.0 + sigma * sigma / 6.0
    } else {
        (es - 1.0) / sigma
    };
    if theta < SMALL_ANGLE {
        // ω^ terms vanish to first order: A = ∫τ e^{στ}, B = ½∫τ² e^{στ}.
        if sigma.abs() < SMALL_SCALE {
            (0.5 + sigma / 3.0, 1.0 / 6.0 + sigma / 8.0, c)
        } else {
            let s2 = sigma * sigma;
            let a = (es * (sigma - 1.0) + 1.0) / s2;
            let b = 0.5 * (es * (s2 - 2.0 * sigma + 2.0) - 2.0) / (s2 * sigma);
            (a, b, c)
        }
    } else {
        let (s, co) = theta.sin_cos();
        let d = sigma * sigma + theta * theta;
        // ∫₀¹ e^{στ} sin(θτ) dτ and ∫₀¹ e^{στ} cos(θτ) dτ.
        let int_sin = (es * (sigma * s - theta * co) + theta) / d;
        let int_cos = (es * (sigma * co + theta * s) - sigma) / d;
        (int_sin / theta, (c - int_cos) / (theta * theta), c)
    }
}

fn w_matrix(omega: &Vector3<f64>, sigma: f64) -> Matrix3<f64> {
    let (a, b, c) = w_coefficients(omega.norm(), sigma);
    let w = hat(omega);
    Matrix3::identity() * c + w * a + w * w * b
}

/// Exponential map: tangent `[ω; ρ; σ]` to a similarity with scale `e^σ`.
pub fn exp(xi: &Vector7) -> Sim3 {
    let omega = Vector3::new(xi[0], xi[1], xi[2]);
    let rho = Vector3::new(xi[3], xi[4], xi[5]);
    let sigma = xi[6];
    let t = w_matrix(&omega, sigma) * rho;
    Similarity3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_scaled_axis(omega),
        sigma.exp(),
    )
}

/// Logarithm map: similarity to tangent `[ω; ρ; σ]` (inverse of [`exp`]).
/// Returns `None` for a non-positive scale (not a proper similarity).
pub fn log(s: &Sim3) -> Option<Vector7> {
    let scale = s.scaling();
    if scale <= 0.0 || !scale.is_finite() {
        return None;
    }
    let sigma = scale.ln();
    let omega = s.isometry.rotation.scaled_axis();
    let rho = w_matrix(&omega, sigma)
        .lu()
        .solve(&s.isometry.translation.vector)?;
    Some(Vector7::from_column_slice(&[
        omega.x, omega.y, omega.z, rho.x, rho.y, rho.z, sigma,
    ]))
}

/// Similarity with scale 1 from a rigid transform.
pub fn from_se3(t: &Se3) -> Sim3 {
    Similarity3::from_isometry(*t, 1.0)
}

/// The rigid part of a similarity (rotation and translation; the scale is dropped).
pub fn to_se3(s: &Sim3) -> Se3 {
    s.isometry
}

/// Adjoint `Ad_S = [[R, 0, 0], [t^·R, s·R, −t], [0, 0, 1]]` for the `[ω; ρ; σ]` order, so
/// that `S·exp(ξ)·S⁻¹ = exp(Ad_S·ξ)`.
pub fn adjoint(s: &Sim3) -> Matrix7 {
    let r = s.isometry.rotation.to_rotation_matrix().into_inner();
    let t = s.isometry.translation.vector;
    let mut m = Matrix7::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    m.fixed_view_mut::<3, 3>(3, 0).copy_from(&(hat(&t) * r));
    m.fixed_view_mut::<3, 3>(3, 3).copy_from(&(r * s.scaling()));
    m.fixed_view_mut::<3, 1>(3, 6).copy_from(&(-t));
    m[(6, 6)] = 1.0;
    m
}

/// Lie-algebra adjoint `ad_ξ = [[ω^, 0, 0], [ρ^, ω^ + σI, −ρ], [0, 0, 0]]`.
pub fn ad(xi: &Vector7) -> Matrix7 {
    let w = hat(&Vector3::new(xi[0], xi[1], xi[2]));
    let rho = Vector3::new(xi[3], xi[4], xi[5]);
    let mut m = Matrix7::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&w);
    m.fixed_view_mut::<3, 3>(3, 0).copy_from(&hat(&rho));
    m.fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&(w + Matrix3::identity() * xi[6]));
    m.fixed_view_mut::<3, 1>(3, 6).copy_from(&(-rho));
    m
}

/// Series `Σₙ Mⁿ/(n+1)!`, summed until the terms stop mattering. Sim3 has no compact closed
/// form for its Jacobians; the series converges for every tangent (factorial decay) and, for
/// the tangents SLAM produces (|ξ| of order 1), within a few dozen terms.
fn phi_series(m: &Matrix7) -> Matrix7 {
    let mut sum = Matrix7::identity();
    let mut term = Matrix7::identity();
    for n in 1..200 {
        term = term * m / (n as f64 + 1.0);
        sum += term;
        if term.amax() < 1e-17 * sum.amax() {
            break;
        }
    }
    sum
}

/// Left Jacobian of Sim3: `exp(ξ + δ) ≈ exp(J_l·δ)·exp(ξ)`.
pub fn left_jacobian(xi: &Vector7) -> Matrix7 {
    phi_series(&ad(xi))
}

/// Right Jacobian of Sim3: `exp(ξ + δ) ≈ exp(ξ)·exp(J_r·δ)`; equals `J_l(−ξ)`.
pub fn right_jacobian(xi: &Vector7) -> Matrix7 {
    phi_series(&(-ad(xi)))
}

/// The `[ω; ρ]` part of a Sim3 tangent (drops σ).
pub fn rigid_part(xi: &Vector7) -> Vector6<f64> {
    Vector6::new(xi[0], xi[1], xi[2], xi[3], xi[4], xi[5])
}

/// Convenience: the Sim3 tangent of a rigid transform (σ = 0).
pub fn tangent_of_se3(t: &Se3) -> Vector7 {
    let v = se3::log(t);
    Vector7::from_column_slice(&[v[0], v[1], v[2], v[3], v[4], v[5], 0.0])
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn tangent() -> impl Strategy<Value = Vector7> {
        (
            prop::array::uniform3(-1.0f64..1.0),
            0.0f64..3.0,
            prop::array::uniform3(-5.0f64..5.0),
            -1.5f64..1.5,
        )
            .prop_map(|(axis, angle, rho, sigma)| {
                let a = Vector3::from(axis);
                let w = if a.norm() > 1e-6 {
                    a.normalize() * angle
                } else {
                    Vector3::zeros()
                };
                Vector7::from_column_slice(&[w.x, w.y, w.z, rho[0], rho[1], rho[2], sigma])
            })
    }

    fn close(a: &Sim3, b: &Sim3, tol: f64) -> bool {
        (a.to_homogeneous() - b.to_homogeneous()).amax() < tol
    }

    fn log_ok(s: &Sim3) -> Vector7 {
        log(s).unwrap_or_else(|| Vector7::repeat(f64::NAN))
    }

    #[test]
    fn exp_matches_se3_when_sigma_is_zero() {
        let xi = Vector7::from_column_slice(&[0.2, -0.1, 0.4, 1.0, -2.0, 0.5, 0.0]);
        let s = exp(&xi);
        let t = se3::exp(&rigid_part(&xi));
        assert!(close(&s, &from_se3(&t), 1e-12));
        assert!((log_ok(&from_se3(&t)) - tangent_of_se3(&t)).norm() < 1e-12);
    }

    #[test]
    fn small_angle_and_scale_branches_are_continuous() {
        for (w, sg) in [
            (0.0, 0.0),
            (2e-6, 0.0),
            (0.0, 3e-6),
            (2e-6, 3e-6),
            (2e-6, 0.3),
        ] {
            let xi = Vector7::from_column_slice(&[w, -w, 0.5 * w, 0.3, 0.2, -0.1, sg]);
            let xi2 =
                Vector7::from_column_slice(&[w + 2e-5, -w, 0.5 * w, 0.3, 0.2, -0.1, sg + 2e-5]);
            let d = (exp(&xi).to_homogeneous() - exp(&xi2).to_homogeneous()).amax();
            assert!(d < 1e-4, "jump {d} at w={w} sigma={sg}");
            assert!((log_ok(&exp(&xi)) - xi).norm() < 1e-9);
        }
    }

    proptest! {
        #[test]
        fn prop_exp_log_round_trip(xi in tangent()) {
            let back = log_ok(&exp(&xi));
            prop_assert!((back - xi).norm() < 1e-9, "{:?} vs {:?}", back, xi);
        }

        #[test]
        fn prop_log_exp_round_trip(xi in tangent()) {
            let s = exp(&xi);
            prop_assert!(close(&exp(&log_ok(&s)), &s, 1e-9));
        }

        #[test]
        fn prop_adjoint_conjugates(a in tangent(), xi in tangent()) {
            let s = exp(&a);
            let lhs = s * exp(&xi) * s.inverse();
            let rhs = exp(&(adjoint(&s) * xi));
            prop_assert!((lhs.to_homogeneous() - rhs.to_homogeneous()).amax()
                < 1e-8 * (1.0 + lhs.to_homogeneous().amax()));
        }

        #[test]
        fn prop_jacobians_match_numeric(xi in tangent()) {
            let h = 1e-6;
            let base = exp(&xi);
            let base_inv = base.inverse();
            let mut nl = Matrix7::zeros();
            let mut nr = Matrix7::zeros();
            for k in 0..7 {
                let mut d = Vector7::zeros();
                d[k] = h;
                let (p, n) = (exp(&(xi + d)), exp(&(xi - d)));
                nl.set_column(k, &((log_ok(&(p * base_inv)) - log_ok(&(n * base_inv))) / (2.0 * h)));
                nr.set_column(k, &((log_ok(&(base_inv * p)) - log_ok(&(base_inv * n))) / (2.0 * h)));
            }
            let dl = (left_jacobian(&xi) - nl).amax();
            let dr = (right_jacobian(&xi) - nr).amax();
            prop_assert!(dl < 1e-5 && dr < 1e-5, "left {} right {}", dl, dr);
        }
    }
}
