//! Closed-form alignment of two corresponding point sets: Horn's method for a rigid transform
//! (rotation + translation, no scale) and Umeyama's method with scale, both through the SVD of
//! the cross-covariance with the reflection fix. This is what the TUM `evaluate_ate.py`
//! (`align`, spec §4.2) and `evo_ape -a` / `-as` compute before the ATE.

use crate::se3::Se3;
use crate::sim3::Sim3;
use nalgebra::{Matrix3, Point3, Rotation3, Similarity3, Translation3, UnitQuaternion, Vector3};

/// Why an alignment could not be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AlignError {
    /// The two point lists have different lengths.
    #[error("alignment needs corresponding points: {source_len} source vs {target_len} target")]
    LengthMismatch {
        /// Number of source points.
        source_len: usize,
        /// Number of target points.
        target_len: usize,
    },
    /// Fewer points than the method needs.
    #[error("alignment needs at least {needed} point pairs, got {got}")]
    TooFewPoints {
        /// Points needed.
        needed: usize,
        /// Points given.
        got: usize,
    },
    /// The points contain NaN or infinity.
    #[error("alignment input contains non-finite coordinates")]
    NonFinite,
    /// SVD failed or the source points are all identical (no scale can be estimated).
    #[error("alignment is degenerate: {0}")]
    Degenerate(&'static str),
}

/// A computed alignment `target ≈ s·R·source + t`.
#[derive(Debug, Clone, PartialEq)]
pub struct Alignment {
    /// The transform mapping source points onto target points (scale 1 for SE3 alignment).
    pub transform: Sim3,
    /// Number of point pairs used.
    pub points_used: usize,
}

impl Alignment {
    /// The rigid part (exact for an SE3 alignment, scale dropped for Sim3).
    pub fn se3(&self) -> Se3 {
        self.transform.isometry
    }

    /// The estimated scale (1 for SE3 alignment).
    pub fn scale(&self) -> f64 {
        self.transform.scaling()
    }

    /// Applies the alignment to a source point.
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        self.transform.transform_point(p)
    }
}

/// Rigid alignment (Horn; rotation and translation, scale fixed to 1) of `source` onto
/// `target`, minimising Σ‖R·sᵢ + t − tᵢ‖². Needs at least 3 pairs.
pub fn align_se3(source: &[Point3<f64>], target: &[Point3<f64>]) -> Result<Alignment, AlignError> {
    umeyama(source, target, false)
}

/// Similarity alignment (Umeyama; rotation, translation and scale) of `source` onto `target`,
/// minimising Σ‖s·R·sᵢ + t − tᵢ‖². Needs at least 3 pairs and a source set with spread.
pub fn align_sim3(source: &[Point3<f64>], target: &[Point3<f64>]) -> Result<Alignment, AlignError> {
    umeyama(source, target, true)
}

fn umeyama(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    with_scale: bool,
) -> Result<Alignment, AlignError> {
    if source.len() != target.len() {
        return Err(AlignError::LengthMismatch {
            source_len: source.len(),
            target_len: target.len(),
        });
    }
    let n = source.len();
    // Two pairs fix all but the rotation about their common line; TUM's tool accepts 2, but
    // the result is then arbitrary, so 3 is required.
    if n < 3 {
        return Err(AlignError::TooFewPoints { needed: 3, got: n });
    }
    if source
        .iter()
        .chain(target.iter())
        .any(|p| !p.coords.iter().all(|v| v.is_finite()))
    {
        return Err(AlignError::NonFinite);
    }
    let inv_n = 1.0 / n as f64;
    let mu_s = source.iter().fold(Vector3::zeros(), |a, p| a + p.coords) * inv_n;
    let mu_t = target.iter().fold(Vector3::zeros(), |a, p| a + p.coords) * inv_n;
    // Centred sums: the means are subtracted first so large absolute coordinates do not
    // cancel catastrophically.
    let mut cov = Matrix3::zeros();
    let mut var_s = 0.0;
    for (s, t) in source.iter().zip(target) {
        let ds = s.coords - mu_s;
        let dt = t.coords - mu_t;
        cov += dt * ds.transpose();
        var_s += ds.norm_squared();
    }
    cov *= inv_n;
    var_s *= inv_n;
    let svd = cov.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return Err(AlignError::Degenerate("SVD did not converge"));
    };
    // Reflection fix: flip the axis of the smallest singular value if det(U·Vᵀ) < 0.
    let mut signs = Vector3::new(1.0, 1.0, 1.0);
    if u.determinant() * vt.determinant() < 0.0 {
        signs.z = -1.0;
    }
    // nalgebra does not sort singular values; find the smallest one for the sign flip.
    let sv = svd.singular_values;
    let smallest = sv.imin();
    if signs.z < 0.0 && smallest != 2 {
        signs = Vector3::new(1.0, 1.0, 1.0);
        signs[smallest] = -1.0;
    }
    let r = u * Matrix3::from_diagonal(&signs) * vt;
    let scale = if with_scale {
        if var_s <= 0.0 {
            return Err(AlignError::Degenerate("source points have no spread"));
        }
        sv.dot(&signs) / var_s
    } else {
        1.0
    };
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let t = mu_t - rot * mu_s * scale;
    Ok(Alignment {
        transform: Similarity3::from_parts(Translation3::from(t), rot, scale),
        points_used: n,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim3;
    use proptest::prelude::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn cloud(seed: u64, n: usize) -> Vec<Point3<f64>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                Point3::new(
                    rng.random_range(-3.0..3.0),
                    rng.random_range(-3.0..3.0),
                    rng.random_range(-1.0..1.0),
                )
            })
            .collect()
    }

    fn transform_strategy() -> impl Strategy<Value = Sim3> {
        (
            prop::array::uniform3(-1.0f64..1.0),
            0.0f64..3.1,
            prop::array::uniform3(-10.0f64..10.0),
            -1.0f64..1.0,
        )
            .prop_map(|(axis, angle, t, sigma)| {
                let a = Vector3::from(axis);
                let w = if a.norm() > 1e-6 {
                    a.normalize() * angle
                } else {
                    Vector3::zeros()
                };
                Similarity3::from_parts(
                    Translation3::from(Vector3::from(t)),
                    UnitQuaternion::from_scaled_axis(w),
                    sigma.exp(),
                )
            })
    }

    #[test]
    fn rejects_bad_input() {
        let p = cloud(1, 5);
        assert!(matches!(
            align_se3(&p, &p[..4]),
            Err(AlignError::LengthMismatch { .. })
        ));
        assert!(matches!(
            align_se3(&p[..2], &p[..2]),
            Err(AlignError::TooFewPoints { got: 2, .. })
        ));
        let mut q = p.clone();
        q[0].x = f64::NAN;
        assert_eq!(align_se3(&q, &p), Err(AlignError::NonFinite));
        let same = vec![Point3::new(1.0, 2.0, 3.0); 4];
        assert!(matches!(
            align_sim3(&same, &same),
            Err(AlignError::Degenerate(_))
        ));
    }

    #[test]
    fn planar_points_need_the_reflection_fix() {
        // Coplanar points: the cross-covariance has a zero singular value, and a reflection
        // fits as well as the rotation; the fix must still return the proper rotation.
        let src: Vec<_> = cloud(7, 20)
            .into_iter()
            .map(|p| Point3::new(p.x, p.y, 0.0))
            .collect();
        let truth = Similarity3::from_parts(
            Translation3::new(1.0, -2.0, 0.5),
            UnitQuaternion::from_euler_angles(0.3, -0.2, 1.0),
            1.0,
        );
        let dst: Vec<_> = src.iter().map(|p| truth.transform_point(p)).collect();
        let a = align_se3(&src, &dst).expect("aligns");
        assert!(
            a.transform
                .isometry
                .rotation
                .to_rotation_matrix()
                .matrix()
                .determinant()
                > 0.0
        );
        for (s, d) in src.iter().zip(&dst) {
            assert!((a.apply(s) - d).norm() < 1e-9);
        }
    }

    proptest! {
        #[test]
        fn prop_se3_alignment_recovers_rigid_transform(t in transform_strategy(), seed in 0u64..1000) {
            let rigid = Similarity3::from_isometry(t.isometry, 1.0);
            let src = cloud(seed, 30);
            let dst: Vec<_> = src.iter().map(|p| rigid.transform_point(p)).collect();
            let a = align_se3(&src, &dst);
            prop_assert!(a.is_ok());
            if let Ok(a) = a {
                prop_assert_eq!(a.points_used, 30);
                let d = sim3::log(&(a.transform.inverse() * rigid)).map(|v| v.norm());
                prop_assert!(d.is_some_and(|d| d < 1e-9), "{:?}", d);
            }
        }

        #[test]
        fn prop_sim3_alignment_recovers_similarity(t in transform_strategy(), seed in 0u64..1000) {
            let src = cloud(seed, 30);
            let dst: Vec<_> = src.iter().map(|p| t.transform_point(p)).collect();
            let a = align_sim3(&src, &dst);
            prop_assert!(a.is_ok());
            if let Ok(a) = a {
                prop_assert!((a.scale() - t.scaling()).abs() < 1e-9);
                let d = sim3::log(&(a.transform.inverse() * t)).map(|v| v.norm());
                prop_assert!(d.is_some_and(|d| d < 1e-9), "{:?}", d);
            }
        }
    }
}
