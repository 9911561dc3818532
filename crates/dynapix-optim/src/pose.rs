//! Weighted pose-only optimisation: ORB-SLAM2's `Optimizer::PoseOptimization` (spec §6.3) and
//! DynaPix's `PoseWeightOptimization` (spec §2.3), selected by [`PoseOnlyParams`].
//!
//! `rounds` rounds of `iterations` Levenberg–Marquardt iterations on the 6-DoF pose. Every
//! round restarts from the initial guess (as ORB-SLAM2 does, which re-sets the vertex estimate
//! from `Frame::mTcw` each round) and uses only the edges classified as inliers by the previous
//! round; the Huber kernel (δ = √χ²-threshold of the edge type) is on for the first
//! `robust_rounds` rounds. After each round every edge is classified again at the new pose;
//! problems with fewer than `min_edges_for_rounds` edges stop after the first round.

use crate::edge::{self, Weighted};
use crate::problem::{PoseOnlyParams, PoseOnlyProblem, PoseOnlyResult, StereoCamera, WeightMode};
use dynapix_geometry::{Se3, se3};
use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};

/// Minimum number of edges for the optimisation to run (ORB-SLAM2: `nInitialCorrespondences < 3`).
const MIN_EDGES: usize = 3;
/// g2o's initial damping factor: λ₀ = τ · max diag(H).
pub(crate) const LM_TAU: f64 = 1e-5;
/// g2o's number of damping increases tried inside one LM iteration before giving up.
pub(crate) const LM_MAX_TRIALS: usize = 10;

/// One edge as the solver sees it.
#[derive(Clone, Copy)]
struct PoseEdge {
    /// Index into the problem's observations.
    idx: usize,
    stereo: bool,
    /// χ² threshold of the edge type, also the Huber δ².
    thr: f64,
}

/// Optimises the pose `T_cw` of `problem` (see the module documentation).
///
/// Returns the initial pose and no inliers when fewer than 3 observations take part.
/// `inlier[i]` is the classification of observation `i` after the last round; observations
/// that take no part (mono observations with `use_mono = false`) keep `inlier = true`, as in
/// the reference where such matches are never tested (spec §2.3), but are not counted in
/// `num_inliers`.
pub fn optimize_pose(problem: &PoseOnlyProblem, params: &PoseOnlyParams) -> PoseOnlyResult {
    let n = problem.observations.len().min(problem.points.len());
    let mut inlier = vec![false; problem.observations.len()];
    let mut edges = Vec::with_capacity(n);
    for (i, obs) in problem.observations.iter().enumerate().take(n) {
        let stereo = obs.u_right.is_some();
        if !stereo && !params.use_mono {
            inlier[i] = true;
            continue;
        }
        let valid = obs.weight.is_finite()
            && obs.inv_sigma2.is_finite()
            && obs.inv_sigma2 > 0.0
            && problem.points[i].iter().all(|v| v.is_finite());
        if !valid {
            continue;
        }
        edges.push(PoseEdge {
            idx: i,
            stereo,
            thr: if stereo {
                params.chi2_stereo
            } else {
                params.chi2_mono
            },
        });
    }
    if edges.len() < MIN_EDGES {
        return PoseOnlyResult {
            pose: problem.pose,
            inlier: vec![false; problem.observations.len()],
            num_inliers: 0,
        };
    }

    let mut active = vec![true; edges.len()];
    let mut pose = problem.pose;
    for round in 0..params.rounds {
        let robust = round < params.robust_rounds;
        pose = lm(
            problem,
            params.weight_mode,
            &edges,
            &active,
            robust,
            params.iterations,
            problem.pose,
        );
        let rt = to_rt(&pose);
        for (k, e) in edges.iter().enumerate() {
            active[k] = classify(problem, params.weight_mode, e, &rt);
        }
        if edges.len() < params.min_edges_for_rounds {
            break;
        }
    }
    let mut num_inliers = 0;
    for (k, e) in edges.iter().enumerate() {
        inlier[e.idx] = active[k];
        num_inliers += usize::from(active[k]);
    }
    PoseOnlyResult {
        pose,
        inlier,
        num_inliers,
    }
}

/// A pose as rotation matrix and translation (cheaper to apply than a quaternion).
type Rt = (Matrix3<f64>, Vector3<f64>);

fn to_rt(t: &Se3) -> Rt {
    (
        *t.rotation.to_rotation_matrix().matrix(),
        t.translation.vector,
    )
}

/// Camera-frame point and residual of edge `e` at `pose`.
#[inline]
fn eval(
    problem: &PoseOnlyProblem,
    e: &PoseEdge,
    pose: &Rt,
) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let xc = pose.0 * problem.points[e.idx] + pose.1;
    let r = edge::residual(&problem.camera, &xc, &problem.observations[e.idx])?;
    Some((xc, r))
}

/// Inlier test: in front of the camera and χ² (weighted per mode) within the threshold.
fn classify(problem: &PoseOnlyProblem, mode: WeightMode, e: &PoseEdge, pose: &Rt) -> bool {
    let obs = &problem.observations[e.idx];
    match eval(problem, e, pose) {
        Some((xc, r)) if xc.z > 0.0 => {
            let c = edge::classification_chi2(edge::chi2(&r, obs.inv_sigma2), obs.weight, mode);
            c <= e.thr
        }
        _ => false,
    }
}

/// Robust cost of one edge at `pose` (`None` when undefined).
#[inline]
fn edge_cost(
    problem: &PoseOnlyProblem,
    mode: WeightMode,
    e: &PoseEdge,
    robust: bool,
    pose: &Rt,
) -> Option<(Vector3<f64>, Vector3<f64>, Weighted)> {
    let obs = &problem.observations[e.idx];
    let (xc, r) = eval(problem, e, pose)?;
    let w = edge::weigh(
        edge::chi2(&r, obs.inv_sigma2),
        obs.weight,
        mode,
        robust.then_some(e.thr),
    );
    Some((xc, r, w))
}

/// `2F = Σ cost` over active edges.
fn total_cost(
    problem: &PoseOnlyProblem,
    mode: WeightMode,
    edges: &[PoseEdge],
    active: &[bool],
    robust: bool,
    pose: &Rt,
) -> f64 {
    edges
        .iter()
        .zip(active)
        .filter(|(_, a)| **a)
        .filter_map(|(e, _)| edge_cost(problem, mode, e, robust, pose))
        .map(|(_, _, w)| w.cost)
        .sum()
}

/// Normal equations `H = Σ ω JᵀΩJ`, `g = Σ ω JᵀΩr` and `2F` at `pose`.
fn linearize(
    cam: &StereoCamera,
    problem: &PoseOnlyProblem,
    mode: WeightMode,
    edges: &[PoseEdge],
    active: &[bool],
    robust: bool,
    pose: &Rt,
) -> (Matrix6<f64>, Vector6<f64>, f64) {
    let mut h = Matrix6::zeros();
    let mut g = Vector6::zeros();
    let mut cost = 0.0;
    for (e, _) in edges.iter().zip(active).filter(|(_, a)| **a) {
        let Some((xc, r, w)) = edge_cost(problem, mode, e, robust, pose) else {
            continue;
        };
        cost += w.cost;
        let jpi = edge::projection_jacobian(cam, &xc, e.stereo);
        let j = edge::pose_jacobian(&jpi, &xc);
        let s = w.irls * problem.observations[e.idx].inv_sigma2;
        h += edge::ata_3x6(&j, s);
        g += s * (j.transpose() * r);
    }
    (h, g, cost)
}

/// Levenberg–Marquardt on the pose from `start`, g2o style (λ₀ = τ·max diag H, Nielsen update,
/// up to [`LM_MAX_TRIALS`] damping increases per iteration, stop when none reduces the cost).
fn lm(
    problem: &PoseOnlyProblem,
    mode: WeightMode,
    edges: &[PoseEdge],
    active: &[bool],
    robust: bool,
    iterations: usize,
    start: Se3,
) -> Se3 {
    let cam = problem.camera;
    let mut pose = start;
    let mut lambda = 0.0;
    let mut nu = 2.0;
    for it in 0..iterations {
        let (h, g, cost) = linearize(&cam, problem, mode, edges, active, robust, &to_rt(&pose));
        if it == 0 {
            let max_diag = (0..6).map(|k| h[(k, k)]).fold(0.0, f64::max);
            lambda = LM_TAU * max_diag;
        }
        if lambda.is_nan() || lambda <= 0.0 || g.iter().all(|v| *v == 0.0) {
            break;
        }
        let mut accepted = false;
        for _ in 0..LM_MAX_TRIALS {
            let mut damped = h;
            for k in 0..6 {
                damped[(k, k)] += lambda;
            }
            let step = damped.cholesky().map(|c| c.solve(&(-g)));
            if let Some(delta) = step.filter(|d| d.iter().all(|v| v.is_finite())) {
                let candidate = se3::exp(&delta) * pose;
                let new_cost = total_cost(problem, mode, edges, active, robust, &to_rt(&candidate));
                // Both costs are 2F; the predicted decrease of F is ½δᵀ(λδ − g).
                let predicted = delta.dot(&(lambda * delta - g));
                let gain = (cost - new_cost) / predicted;
                if new_cost.is_finite() && predicted > 0.0 && gain > 0.0 {
                    pose = candidate;
                    let t = 2.0 * gain - 1.0;
                    lambda *= (1.0 - t * t * t).max(1.0 / 3.0);
                    nu = 2.0;
                    accepted = true;
                    break;
                }
            }
            lambda *= nu;
            nu *= 2.0;
        }
        if !accepted {
            break;
        }
    }
    pose
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::Observation;
    use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    pub(crate) fn cam() -> StereoCamera {
        StereoCamera {
            fx: 535.4,
            fy: 539.2,
            cx: 320.1,
            cy: 247.6,
            bf: 40.0,
        }
    }

    fn gauss(rng: &mut ChaCha8Rng) -> f64 {
        // Box–Muller; enough for test noise.
        let u1: f64 = rng.random_range(1e-12..1.0);
        let u2: f64 = rng.random_range(0.0..1.0);
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    fn true_pose() -> Se3 {
        Isometry3::from_parts(
            Translation3::new(0.2, -0.1, 0.3),
            UnitQuaternion::from_euler_angles(0.05, -0.1, 0.08),
        )
    }

    /// Points in front of the true camera with observations (noise σ px), every `mono_every`-th
    /// observation mono.
    fn scene(seed: u64, n: usize, noise: f64, mono_every: usize) -> PoseOnlyProblem {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let c = cam();
        let t = true_pose();
        let mut points = Vec::new();
        let mut observations = Vec::new();
        for i in 0..n {
            let u = rng.random_range(20.0..620.0);
            let v = rng.random_range(20.0..460.0);
            let z = rng.random_range(1.0..5.0);
            let xc = Vector3::new((u - c.cx) / c.fx * z, (v - c.cy) / c.fy * z, z);
            let xw = (t.inverse() * Point3::from(xc)).coords;
            let un = u + noise * gauss(&mut rng);
            let vn = v + noise * gauss(&mut rng);
            let urn = u - c.bf / z + noise * gauss(&mut rng);
            points.push(xw);
            observations.push(Observation {
                uv: [un, vn],
                u_right: (mono_every == 0 || i % mono_every != 0).then_some(urn),
                inv_sigma2: 1.0,
                weight: 1.0,
            });
        }
        let guess = se3::exp(&Vector6::new(0.02, -0.03, 0.01, 0.05, 0.04, -0.06)) * t;
        PoseOnlyProblem {
            camera: c,
            pose: guess,
            points,
            observations,
        }
    }

    fn pose_error(a: &Se3, b: &Se3) -> (f64, f64) {
        let d = a * b.inverse();
        (d.rotation.angle(), d.translation.vector.norm())
    }

    #[test]
    fn recovers_perturbed_pose_noise_free() {
        for mono_every in [0, 3] {
            let p = scene(1, 100, 0.0, mono_every);
            let res = optimize_pose(&p, &PoseOnlyParams::default());
            let (ang, tr) = pose_error(&res.pose, &true_pose());
            assert!(
                ang < 1e-7 && tr < 1e-7,
                "mono_every {mono_every}: {ang} {tr}"
            );
            assert_eq!(res.num_inliers, 100);
            assert!(res.inlier.iter().all(|b| *b));
        }
    }

    #[test]
    fn recovers_pose_with_noise_and_flags_outliers() {
        let mut p = scene(2, 300, 1.0, 4);
        let mut rng = ChaCha8Rng::seed_from_u64(99);
        let mut corrupted = vec![false; 300];
        for (i, c) in corrupted.iter_mut().enumerate() {
            if i % 5 == 1 {
                *c = true;
                let o = &mut p.observations[i];
                o.uv[0] +=
                    rng.random_range(20.0..60.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                o.uv[1] += rng.random_range(20.0..60.0);
            }
        }
        let res = optimize_pose(&p, &PoseOnlyParams::default());
        let (ang, tr) = pose_error(&res.pose, &true_pose());
        assert!(ang < 2e-3 && tr < 5e-3, "{ang} {tr}");
        for i in 0..300 {
            if corrupted[i] {
                assert!(!res.inlier[i], "outlier {i} accepted");
            }
        }
        let good = (0..300).filter(|&i| !corrupted[i] && res.inlier[i]).count();
        assert!(good >= 220, "only {good} of 240 clean edges kept");
        assert_eq!(res.num_inliers, res.inlier.iter().filter(|b| **b).count());
    }

    #[test]
    fn too_few_edges_returns_initial_pose() {
        let mut p = scene(3, 2, 0.0, 0);
        p.observations.truncate(2);
        let res = optimize_pose(&p, &PoseOnlyParams::default());
        assert_eq!(res.pose, p.pose);
        assert_eq!(res.num_inliers, 0);
        // Mono edges skipped by `use_mono = false` do not count towards the minimum.
        let mut p = scene(4, 6, 0.0, 2);
        p.observations.truncate(6);
        let params = PoseOnlyParams {
            use_mono: false,
            ..PoseOnlyParams::default()
        };
        let res = optimize_pose(&p, &params);
        assert_ne!(res.pose, p.pose, "3 stereo edges must be optimised");
        assert_eq!(res.num_inliers, 3);
    }

    #[test]
    fn small_problems_stop_after_one_round() {
        let mut p = scene(9, 8, 1.0, 0);
        p.observations[3].uv[0] += 6.0;
        let one_round = PoseOnlyParams {
            rounds: 1,
            min_edges_for_rounds: 0,
            ..PoseOnlyParams::default()
        };
        let all_rounds = PoseOnlyParams {
            min_edges_for_rounds: 0,
            ..PoseOnlyParams::default()
        };
        let a = optimize_pose(&p, &PoseOnlyParams::default());
        let b = optimize_pose(&p, &one_round);
        let c = optimize_pose(&p, &all_rounds);
        assert_eq!(a.pose, b.pose);
        assert_eq!(a.inlier, b.inlier);
        assert_ne!(a.pose, c.pose, "four rounds must differ from one here");
    }

    #[test]
    fn edges_behind_the_camera_are_outliers() {
        let mut p = scene(5, 50, 0.0, 0);
        let t = true_pose();
        // Move one point behind the true camera; its observation stays the same.
        let xc = (t * Point3::from(p.points[7])).coords;
        p.points[7] = (t.inverse() * Point3::from(-xc)).coords;
        let res = optimize_pose(&p, &PoseOnlyParams::default());
        assert!(!res.inlier[7]);
        assert_eq!(res.num_inliers, 49);
    }

    /// Two groups of points that disagree by a 4 cm shift: down-weighting one moves the
    /// estimate towards the pose the other group supports.
    #[test]
    fn weights_pull_the_estimate_towards_trusted_edges() {
        let p0 = scene(6, 200, 0.0, 0);
        let shift = Vector3::new(0.04, 0.0, 0.0);
        let mut p = p0.clone();
        for i in (0..200).filter(|i| i % 2 == 1) {
            p.points[i] += shift;
        }
        let no_kernel = PoseOnlyParams {
            robust_rounds: 0,
            chi2_mono: 1e9,
            chi2_stereo: 1e9,
            ..PoseOnlyParams::default()
        };
        let dist = |res: &PoseOnlyResult| pose_error(&res.pose, &true_pose()).1;
        let base = dist(&optimize_pose(&p, &no_kernel));
        for mode in [WeightMode::Paper, WeightMode::Reference] {
            let mut q = p.clone();
            for i in (0..200).filter(|i| i % 2 == 1) {
                q.observations[i].weight = 0.2;
            }
            let params = PoseOnlyParams {
                weight_mode: mode,
                ..no_kernel.clone()
            };
            let weighted = dist(&optimize_pose(&q, &params));
            assert!(weighted < 0.5 * base, "{mode:?}: {weighted} vs {base}");
            // Zero weight: the shifted group has no say at all.
            for i in (0..200).filter(|i| i % 2 == 1) {
                q.observations[i].weight = 0.0;
            }
            let zero = dist(&optimize_pose(&q, &params));
            assert!(zero < 1e-7, "{mode:?}: {zero}");
        }
    }

    /// Paper mode tests outliers on the unweighted χ², the reference on w²·χ²: a badly
    /// fitting, low-weight observation is an outlier only in paper mode.
    #[test]
    fn paper_and_reference_classify_differently() {
        let mut p = scene(7, 60, 0.0, 0);
        p.pose = true_pose();
        p.observations[10].uv[0] += 5.0; // χ² = 25 + (5)² on u and uR (> 7.815)
        p.observations[10].u_right = p.observations[10].u_right.map(|u| u + 5.0);
        p.observations[10].weight = 0.3; // w²χ² = 0.09·50 = 4.5 < 7.815
        let paper = optimize_pose(&p, &PoseOnlyParams::default());
        let reference = optimize_pose(
            &p,
            &PoseOnlyParams {
                weight_mode: WeightMode::Reference,
                ..PoseOnlyParams::default()
            },
        );
        assert!(!paper.inlier[10]);
        assert!(reference.inlier[10]);
        assert_eq!(paper.num_inliers, 59);
        assert_eq!(reference.num_inliers, 60);
    }

    #[test]
    fn deterministic() {
        let p = scene(8, 150, 0.7, 3);
        let a = optimize_pose(&p, &PoseOnlyParams::default());
        let b = optimize_pose(&p, &PoseOnlyParams::default());
        assert_eq!(a.pose, b.pose);
        assert_eq!(a.inlier, b.inlier);
    }
}
