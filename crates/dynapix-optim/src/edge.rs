//! Residuals, analytic Jacobians and robust weighting shared by the solvers.
//!
//! The reprojection model is ORB-SLAM2's RGB-D "virtual stereo" one (spec §2.4, §6.3):
//! `π(X) = (fx·X/Z + cx, fy·Y/Z + cy, fx·X/Z + cx − bf/Z)` with residual `r = z − π(X_c)`.
//! Mono edges use the first two rows only; internally they are stored as 3-vectors whose third
//! row is zero, so every edge type shares fixed-size 3×N algebra.
//!
//! Pose perturbations are left-multiplicative, `T ← exp(δ)·T` with `δ = [ω; ρ]`, so
//! `∂X_c/∂δ = [−[X_c]× | I]`, the convention of g2o's `VertexSE3Expmap`.
//!
//! How a DynaPix weight `w` enters (spec §2.4 and design §5):
//! - [`WeightMode::Paper`]: cost `w·ρ(χ²)`, outlier test on the unweighted `χ²`;
//! - [`WeightMode::Reference`]: residual scaled by `w`, cost `ρ(w²·χ²)`, outlier test on `w²·χ²`.

use crate::problem::{Observation, StereoCamera, WeightMode};
use nalgebra::{Matrix3, Matrix3x6, Matrix6, Matrix6x3, Vector3};

/// Depths below this are treated as "at the camera centre": the residual is undefined there.
pub(crate) const MIN_ABS_DEPTH: f64 = 1e-12;

/// Residual `z − π(x_c)` of one observation; the third entry is 0 for mono edges.
/// `None` when the point lies (numerically) in the camera's centre plane.
#[inline]
pub(crate) fn residual(
    cam: &StereoCamera,
    xc: &Vector3<f64>,
    obs: &Observation,
) -> Option<Vector3<f64>> {
    if xc.z.is_nan() || xc.z.abs() <= MIN_ABS_DEPTH {
        return None;
    }
    let iz = 1.0 / xc.z;
    let u = cam.fx * xc.x * iz + cam.cx;
    let v = cam.fy * xc.y * iz + cam.cy;
    let r2 = match obs.u_right {
        Some(ur) => ur - (u - cam.bf * iz),
        None => 0.0,
    };
    Some(Vector3::new(obs.uv[0] - u, obs.uv[1] - v, r2))
}

/// `∂π/∂X_c` (rows u, v, uR); the uR row is zero for mono edges.
#[inline]
pub(crate) fn projection_jacobian(
    cam: &StereoCamera,
    xc: &Vector3<f64>,
    stereo: bool,
) -> Matrix3<f64> {
    let iz = 1.0 / xc.z;
    let iz2 = iz * iz;
    let mut j = Matrix3::zeros();
    j[(0, 0)] = cam.fx * iz;
    j[(0, 2)] = -cam.fx * xc.x * iz2;
    j[(1, 1)] = cam.fy * iz;
    j[(1, 2)] = -cam.fy * xc.y * iz2;
    if stereo {
        j[(2, 0)] = cam.fx * iz;
        j[(2, 2)] = -(cam.fx * xc.x - cam.bf) * iz2;
    }
    j
}

/// `∂r/∂δ` for the left pose perturbation, given `∂π/∂X_c`.
#[inline]
pub(crate) fn pose_jacobian(jpi: &Matrix3<f64>, xc: &Vector3<f64>) -> Matrix3x6<f64> {
    // r = z − π(X_c) and ∂X_c/∂δ = [−[X_c]× | I]  ⇒  ∂r/∂δ = [Jπ·[X_c]× | −Jπ].
    let rot = jpi * dynapix_geometry::se3::hat(xc);
    let mut j = Matrix3x6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&rot);
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-jpi));
    j
}

/// Huber kernel on a squared error `s` with threshold `δ²`: returns `(ρ(s), ρ'(s))`
/// (g2o's convention: `ρ(s) = s` inside, `2δ√s − δ²` outside).
#[inline]
pub(crate) fn huber(s: f64, delta2: f64) -> (f64, f64) {
    if s <= delta2 {
        (s, 1.0)
    } else {
        let sq = s.sqrt();
        let d = delta2.sqrt();
        (2.0 * d * sq - delta2, d / sq)
    }
}

/// Robust cost of an edge, the IRLS weight of its normal equations, and the χ² used for
/// outlier classification, for the given weight mode.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Weighted {
    /// Contribution to `2·F` (the solver minimises `F = ½ Σ cost`).
    pub cost: f64,
    /// Scalar multiplying `JᵀΩJ` and `JᵀΩr`.
    pub irls: f64,
}

/// Applies weight mode and (optional) Huber threshold `δ²` to the plain `χ² = rᵀΩr`.
#[inline]
pub(crate) fn weigh(chi2: f64, w: f64, mode: WeightMode, huber_delta2: Option<f64>) -> Weighted {
    match mode {
        WeightMode::Paper => {
            let (rho, drho) = match huber_delta2 {
                Some(d2) => huber(chi2, d2),
                None => (chi2, 1.0),
            };
            Weighted {
                cost: w * rho,
                irls: w * drho,
            }
        }
        WeightMode::Reference => {
            let w2 = w * w;
            let s = w2 * chi2;
            let (rho, drho) = match huber_delta2 {
                Some(d2) => huber(s, d2),
                None => (s, 1.0),
            };
            Weighted {
                cost: rho,
                irls: w2 * drho,
            }
        }
    }
}

/// The χ² an outlier test compares with its threshold (unweighted in paper mode).
#[inline]
pub(crate) fn classification_chi2(chi2: f64, w: f64, mode: WeightMode) -> f64 {
    match mode {
        WeightMode::Paper => chi2,
        WeightMode::Reference => w * w * chi2,
    }
}

/// Plain `χ² = rᵀΩr` with `Ω = inv_sigma2·I`.
#[inline]
pub(crate) fn chi2(r: &Vector3<f64>, inv_sigma2: f64) -> f64 {
    inv_sigma2 * r.norm_squared()
}

/// `a·bᵀ` for two 6×3 blocks, written out because nalgebra's generic small-matrix product is
/// the bottleneck of the Schur complement.
#[inline(always)]
pub(crate) fn mul_abt_6x3(a: &Matrix6x3<f64>, b: &Matrix6x3<f64>) -> Matrix6<f64> {
    let (a, b) = (&a.data.0, &b.data.0);
    let mut out = Matrix6::zeros();
    for (j, col) in out.data.0.iter_mut().enumerate() {
        for (i, o) in col.iter_mut().enumerate() {
            *o = a[0][i] * b[0][j] + a[1][i] * b[1][j] + a[2][i] * b[2][j];
        }
    }
    out
}

/// `s −= a·bᵀ` for two 6×3 blocks, each entry computed exactly as [`mul_abt_6x3`] does (so
/// the result is bit-identical to subtracting its product), written over the column arrays
/// so the compiler vectorises the six rows of a column.
#[inline(always)]
pub(crate) fn sub_abt_6x3(s: &mut Matrix6<f64>, a: &Matrix6x3<f64>, b: &Matrix6x3<f64>) {
    let a = &a.data.0;
    let b = &b.data.0;
    for (j, col) in s.data.0.iter_mut().enumerate() {
        let (b0, b1, b2) = (b[0][j], b[1][j], b[2][j]);
        for i in 0..6 {
            col[i] -= a[0][i] * b0 + a[1][i] * b1 + a[2][i] * b2;
        }
    }
}

/// `s·aᵀa` for a 3×6 Jacobian (the upper triangle computed, the lower one mirrored: the
/// products commute exactly, so every entry is the one the full product gives).
#[inline(always)]
pub(crate) fn ata_3x6(a: &Matrix3x6<f64>, s: f64) -> Matrix6<f64> {
    let a = &a.data.0;
    let mut out = Matrix6::zeros();
    for j in 0..6 {
        for i in 0..=j {
            let v = s * (a[i][0] * a[j][0] + a[i][1] * a[j][1] + a[i][2] * a[j][2]);
            out.data.0[j][i] = v;
            out.data.0[i][j] = v;
        }
    }
    out
}

/// `s·aᵀb` for a 3×6 and a 3×3 block.
#[inline(always)]
pub(crate) fn atb_3x6_3x3(a: &Matrix3x6<f64>, b: &Matrix3<f64>, s: f64) -> Matrix6x3<f64> {
    let (a, b) = (&a.data.0, &b.data.0);
    let mut out = Matrix6x3::zeros();
    for (j, col) in out.data.0.iter_mut().enumerate() {
        for (i, o) in col.iter_mut().enumerate() {
            *o = s * (a[i][0] * b[j][0] + a[i][1] * b[j][1] + a[i][2] * b[j][2]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynapix_geometry::se3;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector6};

    fn cam() -> StereoCamera {
        StereoCamera {
            fx: 517.3,
            fy: 516.5,
            cx: 318.6,
            cy: 255.3,
            bf: 40.0,
        }
    }

    #[test]
    fn analytic_jacobians_match_numeric_differences() {
        let c = cam();
        let pose = Isometry3::from_parts(
            Translation3::new(0.1, -0.2, 0.3),
            UnitQuaternion::from_euler_angles(0.1, -0.05, 0.2),
        );
        let xw = Vector3::new(0.4, -0.3, 2.5);
        for stereo in [false, true] {
            let obs = Observation {
                uv: [300.0, 240.0],
                u_right: stereo.then_some(290.0),
                inv_sigma2: 1.0,
                weight: 1.0,
            };
            let xc = pose * nalgebra::Point3::from(xw);
            let xc = xc.coords;
            let jpi = projection_jacobian(&c, &xc, stereo);
            let jp = pose_jacobian(&jpi, &xc);
            let jx = -jpi * pose.rotation.to_rotation_matrix().matrix();
            let h = 1e-6;
            for k in 0..6 {
                let mut d = Vector6::zeros();
                d[k] = h;
                let plus = (se3::exp(&d) * pose * nalgebra::Point3::from(xw)).coords;
                let minus = (se3::exp(&-d) * pose * nalgebra::Point3::from(xw)).coords;
                let rp = residual(&c, &plus, &obs).unwrap_or_default();
                let rm = residual(&c, &minus, &obs).unwrap_or_default();
                let num = (rp - rm) / (2.0 * h);
                let err = (num - jp.column(k)).norm();
                assert!(
                    err < 1e-4 * (1.0 + num.norm()),
                    "pose col {k} stereo {stereo}: {err}"
                );
            }
            for k in 0..3 {
                let mut d = Vector3::zeros();
                d[k] = h;
                let plus = (pose * nalgebra::Point3::from(xw + d)).coords;
                let minus = (pose * nalgebra::Point3::from(xw - d)).coords;
                let rp = residual(&c, &plus, &obs).unwrap_or_default();
                let rm = residual(&c, &minus, &obs).unwrap_or_default();
                let num = (rp - rm) / (2.0 * h);
                let err = (num - jx.column(k)).norm();
                assert!(
                    err < 1e-4 * (1.0 + num.norm()),
                    "point col {k} stereo {stereo}: {err}"
                );
            }
        }
    }

    #[test]
    fn small_products_match_nalgebra() {
        let a = Matrix6x3::from_fn(|i, j| (i * 3 + j) as f64 * 0.37 - 2.0);
        let b = Matrix6x3::from_fn(|i, j| (i + 5 * j) as f64 * -0.21 + 1.0);
        assert!((mul_abt_6x3(&a, &b) - a * b.transpose()).norm() < 1e-12);
        let j = Matrix3x6::from_fn(|i, k| (i * 6 + k) as f64 * 0.13 - 1.0);
        let m = Matrix3::from_fn(|i, k| (i + 2 * k) as f64 * 0.3 - 0.5);
        assert!((ata_3x6(&j, 2.0) - 2.0 * j.transpose() * j).norm() < 1e-12);
        assert!((atb_3x6_3x3(&j, &m, 2.0) - 2.0 * j.transpose() * m).norm() < 1e-12);
    }

    /// The written-out products give the bits of the entry-wise formulas they replaced (the
    /// mirrored half of `aᵀa` included), so the BA's results did not change.
    #[test]
    fn small_products_are_bit_identical_to_their_entry_formulas() {
        let a = Matrix6x3::from_fn(|i, j| ((i * 3 + j) as f64 * 0.37 - 2.0).sin() * 1e3);
        let b = Matrix6x3::from_fn(|i, j| ((i + 5 * j) as f64 * -0.21 + 1.0).cos() / 7.0);
        let ab = Matrix6::from_fn(|i, j| {
            a[(i, 0)] * b[(j, 0)] + a[(i, 1)] * b[(j, 1)] + a[(i, 2)] * b[(j, 2)]
        });
        assert_eq!(mul_abt_6x3(&a, &b), ab);
        let j = Matrix3x6::from_fn(|i, k| ((i * 6 + k) as f64 * 0.13 - 1.0).tan());
        let m = Matrix3::from_fn(|i, k| ((i + 2 * k) as f64 * 0.3 - 0.5).exp());
        let s = 0.4137;
        let ata = Matrix6::from_fn(|r, c| {
            s * (j[(0, r)] * j[(0, c)] + j[(1, r)] * j[(1, c)] + j[(2, r)] * j[(2, c)])
        });
        assert_eq!(ata_3x6(&j, s), ata);
        let atb = Matrix6x3::from_fn(|r, c| {
            s * (j[(0, r)] * m[(0, c)] + j[(1, r)] * m[(1, c)] + j[(2, r)] * m[(2, c)])
        });
        assert_eq!(atb_3x6_3x3(&j, &m, s), atb);
    }

    /// The fused kernel of the Schur complement gives the same bits as forming the product
    /// and subtracting it, so the BA's results did not change when it was introduced.
    #[test]
    fn fused_subtraction_is_bit_identical_to_the_product() {
        let a = Matrix6x3::from_fn(|i, j| ((i * 3 + j) as f64 * 0.37 - 2.0).sin() * 1e3);
        let b = Matrix6x3::from_fn(|i, j| ((i + 5 * j) as f64 * -0.21 + 1.0).cos() / 7.0);
        let s0 = Matrix6::from_fn(|i, j| (i as f64 - 2.5 * j as f64) / 3.0);
        let mut fused = s0;
        sub_abt_6x3(&mut fused, &a, &b);
        assert_eq!(fused, s0 - mul_abt_6x3(&a, &b));
        let mut fused_t = s0;
        sub_abt_6x3(&mut fused_t, &b, &a);
        assert_eq!(fused_t, s0 - mul_abt_6x3(&a, &b).transpose());
    }

    #[test]
    fn huber_is_continuous_and_downweights_outside() {
        let d2 = 5.991;
        let (a, da) = huber(d2 - 1e-9, d2);
        let (b, db) = huber(d2 + 1e-9, d2);
        assert!((a - b).abs() < 1e-6 && (da - db).abs() < 1e-6);
        let (c, dc) = huber(100.0, d2);
        assert!(c < 100.0 && dc < 1.0);
    }

    #[test]
    fn weight_modes_differ_as_specified() {
        let p = weigh(10.0, 0.5, WeightMode::Paper, None);
        let r = weigh(10.0, 0.5, WeightMode::Reference, None);
        assert!((p.cost - 5.0).abs() < 1e-12 && (p.irls - 0.5).abs() < 1e-12);
        assert!((r.cost - 2.5).abs() < 1e-12 && (r.irls - 0.25).abs() < 1e-12);
        assert_eq!(classification_chi2(10.0, 0.5, WeightMode::Paper), 10.0);
        assert!((classification_chi2(10.0, 0.5, WeightMode::Reference) - 2.5).abs() < 1e-12);
    }
}
