//! Refinement of the relative transform `T₁₂` of a loop (ORB-SLAM2 `Optimizer::OptimizeSim3`
//! with the scale fixed to 1, spec §6.6): the map points stay fixed in their own camera and
//! only `T₁₂` moves, minimising for every matched pair the reprojection error of point 2 in
//! image 1 (through `T₁₂`) and of point 1 in image 2 (through `T₁₂⁻¹`), each weighted by the
//! keypoint's 1/σ² and robustified with a Huber kernel of width √χ².
//!
//! A small Levenberg–Marquardt on the 6-dof left perturbation `T₁₂ ← exp(ξ)·T₁₂` with
//! analytic Jacobians replaces g2o. Schedule as in ORB-SLAM2: a first round, then pairs with
//! either error above χ² are dropped, then a second round (longer when pairs were dropped)
//! and a final χ² classification.

use dynapix_geometry::{PinholeCamera, Se3, se3};

use crate::camera::RgbdCamera;
use nalgebra::{Matrix3, Matrix6, Point3, SMatrix, Vector2, Vector3, Vector6};

use super::solver::project;

/// One matched pair with its two observations.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct RefinePair {
    /// Point of keyframe 1 in camera-1 coordinates.
    pub p1: Vector3<f64>,
    /// Point of keyframe 2 in camera-2 coordinates.
    pub p2: Vector3<f64>,
    /// Undistorted keypoint of keyframe 1 observing `p1`.
    pub kp1: Vector2<f64>,
    /// Undistorted keypoint of keyframe 2 observing `p2`.
    pub kp2: Vector2<f64>,
    /// Virtual right coordinate of the keypoint in keyframe 1 (None without depth).
    pub ur1: Option<f64>,
    /// Virtual right coordinate of the keypoint in keyframe 2.
    pub ur2: Option<f64>,
    /// 1/σ² of the keypoint level in keyframe 1.
    pub inv_sigma2_1: f64,
    /// 1/σ² of the keypoint level in keyframe 2.
    pub inv_sigma2_2: f64,
}

/// Iteration schedule and thresholds (ORB-SLAM2: χ² 10, 5 iterations, then 10 after
/// removing outliers or 5 when none were removed, at least 10 pairs left).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct RefineSettings {
    /// χ² threshold per direction for a keypoint without depth (2 dof; also the squared
    /// Huber width).
    pub chi2: f64,
    /// χ² threshold per direction for a keypoint with depth (3 dof: u, v, uR).
    pub chi2_depth: f64,
    /// Iterations of the first round.
    pub first_iterations: usize,
    /// Iterations of the second round when pairs were dropped.
    pub second_iterations_after_drop: usize,
    /// Iterations of the second round otherwise.
    pub second_iterations: usize,
    /// Fewer pairs than this after the first round: the refinement fails.
    pub min_pairs: usize,
}

impl RefineSettings {
    fn threshold(&self, depth: bool) -> f64 {
        if depth { self.chi2_depth } else { self.chi2 }
    }
}

type Jac = SMatrix<f64, 3, 6>;
/// A residual (u, v, uR; the uR row is zero without depth) with its Jacobian.
type Linearised = (Vector3<f64>, Jac);

/// Jacobian of (u, v, uR) w.r.t. the camera-frame point; the uR row is zeroed without depth.
fn proj_jacobian(cam: &PinholeCamera, bf: f64, x: &Vector3<f64>, stereo: bool) -> Matrix3<f64> {
    let iz = 1.0 / x.z;
    let iz2 = iz * iz;
    let s = if stereo { 1.0 } else { 0.0 };
    Matrix3::new(
        cam.fx * iz,
        0.0,
        -cam.fx * x.x * iz2,
        0.0,
        cam.fy * iz,
        -cam.fy * x.y * iz2,
        s * cam.fx * iz,
        0.0,
        s * (-cam.fx * x.x * iz2 + bf * iz2),
    )
}

/// Residual (observation − projection) of keypoint `kp` (with right coordinate `ur`) and
/// camera-frame point `x`; None behind the camera.
fn residual(
    cam: &PinholeCamera,
    bf: f64,
    kp: &Vector2<f64>,
    ur: Option<f64>,
    x: &Vector3<f64>,
) -> Option<Vector3<f64>> {
    let u = project(cam, x)?;
    let er = ur.map_or(0.0, |r| r - (u.x - bf / x.z));
    Some(Vector3::new(kp.x - u.x, kp.y - u.y, er))
}

/// Residuals (observation − projection) and their Jacobians w.r.t. ξ = [ω; ρ] for one pair;
/// None when a point falls behind a camera.
fn linearise(
    cam: &PinholeCamera,
    bf: f64,
    t12: &Se3,
    p: &RefinePair,
) -> Option<(Linearised, Linearised)> {
    let r = t12.rotation.to_rotation_matrix().into_inner();
    // Direction 1: x = T₁₂·p2; perturbed exp(ξ)·x ≈ x + ω×x + ρ.
    let x = t12.transform_point(&Point3::from(p.p2)).coords;
    let e1 = residual(cam, bf, &p.kp1, p.ur1, &x)?;
    let mut dx = SMatrix::<f64, 3, 6>::zeros();
    dx.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-se3::hat(&x)));
    dx.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&Matrix3::identity());
    let j1 = -(proj_jacobian(cam, bf, &x, p.ur1.is_some()) * dx);
    // Direction 2: y = T₁₂⁻¹·p1 with T₁₂⁻¹ ← T₁₂⁻¹·exp(−ξ):
    // y ≈ y + Rᵀ·(p1×ω − ρ).
    let y = t12.inverse_transform_point(&Point3::from(p.p1)).coords;
    let e2 = residual(cam, bf, &p.kp2, p.ur2, &y)?;
    let rt = r.transpose();
    let mut dy = SMatrix::<f64, 3, 6>::zeros();
    dy.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(rt * se3::hat(&p.p1)));
    dy.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-rt));
    let j2 = -(proj_jacobian(cam, bf, &y, p.ur2.is_some()) * dy);
    Some(((e1, j1), (e2, j2)))
}

/// χ² of both directions of one pair (∞ behind a camera).
fn chi2s(cam: &PinholeCamera, bf: f64, t12: &Se3, p: &RefinePair) -> (f64, f64) {
    let x = t12.transform_point(&Point3::from(p.p2)).coords;
    let y = t12.inverse_transform_point(&Point3::from(p.p1)).coords;
    let e1 = residual(cam, bf, &p.kp1, p.ur1, &x)
        .map_or(f64::INFINITY, |e| e.norm_squared() * p.inv_sigma2_1);
    let e2 = residual(cam, bf, &p.kp2, p.ur2, &y)
        .map_or(f64::INFINITY, |e| e.norm_squared() * p.inv_sigma2_2);
    (e1, e2)
}

/// Huber cost ρ(s) for squared error `s` and its weight ρ'(s).
fn huber(s: f64, delta2: f64) -> (f64, f64) {
    if s <= delta2 {
        (s, 1.0)
    } else {
        let d = delta2.sqrt();
        let e = s.sqrt();
        (2.0 * d * e - delta2, d / e)
    }
}

fn cost(
    cam: &RgbdCamera,
    t12: &Se3,
    pairs: &[RefinePair],
    active: &[bool],
    st: &RefineSettings,
) -> f64 {
    pairs
        .iter()
        .zip(active)
        .filter(|(_, a)| **a)
        .map(|(p, _)| {
            let (a, b) = chi2s(&cam.pinhole, cam.bf, t12, p);
            huber(a, st.threshold(p.ur1.is_some())).0 + huber(b, st.threshold(p.ur2.is_some())).0
        })
        .sum()
}

/// Levenberg–Marquardt on the active pairs; returns the refined transform.
fn lm(
    cam: &RgbdCamera,
    t12: Se3,
    pairs: &[RefinePair],
    active: &[bool],
    iterations: usize,
    st: &RefineSettings,
) -> Se3 {
    let mut t = t12;
    let mut lambda = 1e-4;
    let mut current = cost(cam, &t, pairs, active, st);
    for _ in 0..iterations {
        let mut h = Matrix6::<f64>::zeros();
        let mut g = Vector6::<f64>::zeros();
        for (p, _) in pairs.iter().zip(active).filter(|(_, a)| **a) {
            let Some(((e1, j1), (e2, j2))) = linearise(&cam.pinhole, cam.bf, &t, p) else {
                continue;
            };
            for (e, j, info, d2) in [
                (e1, j1, p.inv_sigma2_1, st.threshold(p.ur1.is_some())),
                (e2, j2, p.inv_sigma2_2, st.threshold(p.ur2.is_some())),
            ] {
                let s = e.norm_squared() * info;
                let w = huber(s, d2).1 * info;
                h += j.transpose() * j * w;
                g += j.transpose() * e * w;
            }
        }
        // Residual r = obs − π(·); the step solves (H + λ·diag H)·ξ = −Jᵀr.
        let mut improved = false;
        for _ in 0..10 {
            let mut hd = h;
            for k in 0..6 {
                hd[(k, k)] += lambda * h[(k, k)].max(1e-9);
            }
            let Some(step) = hd.cholesky().map(|c| c.solve(&(-g))) else {
                lambda *= 10.0;
                continue;
            };
            if !step.iter().all(|v| v.is_finite()) {
                lambda *= 10.0;
                continue;
            }
            let cand = se3::exp(&step) * t;
            let c = cost(cam, &cand, pairs, active, st);
            if c < current {
                t = crate::pose::normalized(&cand);
                current = c;
                lambda = (lambda * 0.1).max(1e-9);
                improved = true;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    t
}

/// Refines `t12` over `pairs`; returns the refined transform and per pair whether it is an
/// inlier (both χ² ≤ threshold), or None when fewer than `min_pairs` survive the first round.
pub(crate) fn refine_relative(
    cam: &RgbdCamera,
    t12: &Se3,
    pairs: &[RefinePair],
    s: &RefineSettings,
) -> Option<(Se3, Vec<bool>)> {
    let mut active = vec![true; pairs.len()];
    let t = lm(cam, *t12, pairs, &active, s.first_iterations, s);
    let mut bad = 0;
    for (p, a) in pairs.iter().zip(active.iter_mut()) {
        let (e1, e2) = chi2s(&cam.pinhole, cam.bf, &t, p);
        if e1 > s.threshold(p.ur1.is_some()) || e2 > s.threshold(p.ur2.is_some()) {
            *a = false;
            bad += 1;
        }
    }
    if pairs.len() - bad < s.min_pairs {
        return None;
    }
    let more = if bad > 0 {
        s.second_iterations_after_drop
    } else {
        s.second_iterations
    };
    let t = lm(cam, t, pairs, &active, more, s);
    for (p, a) in pairs.iter().zip(active.iter_mut()) {
        if *a {
            let (e1, e2) = chi2s(&cam.pinhole, cam.bf, &t, p);
            *a = e1 <= s.threshold(p.ur1.is_some()) && e2 <= s.threshold(p.ur2.is_some());
        }
    }
    Some((t, active))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn settings() -> RefineSettings {
        RefineSettings {
            chi2: 10.0,
            chi2_depth: 12.8,
            first_iterations: 5,
            second_iterations_after_drop: 10,
            second_iterations: 5,
            min_pairs: 10,
        }
    }

    #[test]
    fn refinement_converges_from_a_perturbed_start_and_drops_outliers() {
        let cam = RgbdCamera::new(
            PinholeCamera::new(320, 240, 260.0, 260.0, 160.0, 120.0),
            40.0,
            40.0,
            30.0,
        );
        let t12 = Se3::from_parts(
            Translation3::new(0.2, 0.05, -0.1),
            UnitQuaternion::from_euler_angles(-0.05, 0.3, 0.02),
        );
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut pairs = Vec::new();
        for i in 0..60 {
            let p2 = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-0.7..0.7),
                rng.random_range(1.5..3.5),
            );
            let mut p1 = t12.transform_point(&Point3::from(p2)).coords;
            if i < 8 {
                p1 += Vector3::new(0.3, -0.2, 0.1);
            }
            let kp1 = project(&cam.pinhole, &p1).unwrap();
            let kp2 = project(&cam.pinhole, &p2).unwrap();
            pairs.push(RefinePair {
                p1,
                p2,
                kp1: kp1 + Vector2::new(rng.random_range(-0.5..0.5), 0.0),
                kp2: kp2 + Vector2::new(0.0, rng.random_range(-0.5..0.5)),
                ur1: None,
                ur2: None,
                inv_sigma2_1: 1.0,
                inv_sigma2_2: 1.0,
            });
        }
        let start = se3::exp(&Vector6::new(0.02, -0.03, 0.01, 0.03, 0.02, -0.04)) * t12;
        let (est, inl) = refine_relative(&cam, &start, &pairs, &settings()).unwrap();
        let d = est.inverse() * t12;
        assert!(d.translation.vector.norm() < 0.005, "{d:?}");
        assert!(d.rotation.angle() < 0.002, "{d:?}");
        assert!(inl[..8].iter().all(|b| !b), "outliers kept: {inl:?}");
        assert_eq!(inl[8..].iter().filter(|&&b| b).count(), 52);
    }
}
