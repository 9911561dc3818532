//! SE3 pose-graph optimisation for loop closing: ORB-SLAM2's `OptimizeEssentialGraph`
//! (spec §6.6) with the scale fixed to 1 as for RGB-D, i.e. relative-pose edges between
//! keyframes, some poses fixed (the loop keyframe), Levenberg–Marquardt (20 iterations).
//!
//! Edge `(i, j, T_ij)` measures `T_iw · T_jw⁻¹` (how camera j sits in camera i); its residual is
//! `r = log(T_ij⁻¹ · T_iw · T_jw⁻¹)` ∈ se(3) (`[ω; ρ]`), cost `rᵀΩr`. As in ORB-SLAM2 (whose
//! `EdgeSim3` has no analytic Jacobian) the Jacobians are numeric central differences of the
//! left perturbations `T ← exp(δ)·T`.
//!
//! The damped normal equations are block-sparse; keyframe ids in temporal order keep most
//! edges near the diagonal, so they are solved by an envelope ("skyline") Cholesky
//! factorisation whose fill stays within each row's first non-zero column.

use crate::pose::{LM_MAX_TRIALS, LM_TAU};
use dynapix_geometry::{Se3, se3};
use nalgebra::{Matrix6, Vector6};

/// One relative-pose constraint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseGraphEdge {
    /// First pose index.
    pub i: usize,
    /// Second pose index.
    pub j: usize,
    /// Measured `T_iw · T_jw⁻¹`.
    pub t_ij: Se3,
    /// Information matrix (order `[ω; ρ]`); ORB-SLAM2 uses the identity.
    pub information: Matrix6<f64>,
}

/// Parameters of pose-graph optimisation (missing serialised fields take the defaults).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct PoseGraphParams {
    /// Levenberg–Marquardt iterations (20 in ORB-SLAM2's essential-graph optimisation).
    pub iterations: usize,
}

impl Default for PoseGraphParams {
    fn default() -> Self {
        Self { iterations: 20 }
    }
}

/// Result of pose-graph optimisation.
#[derive(Clone, Debug)]
pub struct PoseGraphResult {
    /// Optimised poses `T_cw` (fixed ones unchanged).
    pub poses: Vec<Se3>,
    /// Σ rᵀΩr before optimisation.
    pub initial_cost: f64,
    /// Σ rᵀΩr after optimisation.
    pub final_cost: f64,
}

/// Step of the central differences of the numeric Jacobians.
const NUMERIC_STEP: f64 = 1e-6;

/// Residual of an edge.
fn residual(e: &PoseGraphEdge, ti: &Se3, tj: &Se3) -> Vector6<f64> {
    se3::log(&(e.t_ij.inverse() * ti * tj.inverse()))
}

/// Optimises `poses` (`T_cw`) under `edges`; `fixed[k]` (missing = free) holds pose k.
/// Edges with out-of-range indices, `i == j`, or non-finite values are ignored.
pub fn optimize_pose_graph(
    poses: &[Se3],
    fixed: &[bool],
    edges: &[PoseGraphEdge],
    params: &PoseGraphParams,
) -> PoseGraphResult {
    let n = poses.len();
    let edges: Vec<PoseGraphEdge> = edges
        .iter()
        .filter(|e| {
            e.i < n
                && e.j < n
                && e.i != e.j
                && e.information.iter().all(|v| v.is_finite())
                && e.t_ij.translation.vector.iter().all(|v| v.is_finite())
                && e.t_ij.rotation.coords.iter().all(|v| v.is_finite())
        })
        .copied()
        .collect();
    let mut var = vec![None; n];
    let mut nv = 0;
    for (k, v) in var.iter_mut().enumerate() {
        if !fixed.get(k).copied().unwrap_or(false) {
            *v = Some(nv);
            nv += 1;
        }
    }
    let cost_of = |p: &[Se3]| -> f64 {
        edges
            .iter()
            .map(|e| {
                let r = residual(e, &p[e.i], &p[e.j]);
                r.dot(&(e.information * r))
            })
            .sum()
    };
    let mut poses = poses.to_vec();
    let initial_cost = cost_of(&poses);
    let mut cost = initial_cost;

    // Envelope: first variable each variable's row block touches.
    let mut first = (0..nv).collect::<Vec<usize>>();
    for e in &edges {
        if let (Some(a), Some(b)) = (var[e.i], var[e.j]) {
            let (lo, hi) = (a.min(b), a.max(b));
            first[hi] = first[hi].min(lo);
        }
    }
    let mut lambda = 0.0;
    let mut nu = 2.0;
    for it in 0..params.iterations {
        if nv == 0 {
            break;
        }
        // Block normal equations: diagonal blocks, off-diagonal (hi, lo) blocks, gradient.
        let mut diag = vec![Matrix6::<f64>::zeros(); nv];
        let mut off: Vec<(usize, usize, Matrix6<f64>)> = Vec::new();
        let mut g = vec![Vector6::<f64>::zeros(); nv];
        for e in &edges {
            let (vi, vj) = (var[e.i], var[e.j]);
            if vi.is_none() && vj.is_none() {
                continue;
            }
            let (ti, tj) = (poses[e.i], poses[e.j]);
            let r = residual(e, &ti, &tj);
            let mut ji = Matrix6::zeros();
            let mut jj = Matrix6::zeros();
            for k in 0..6 {
                let mut d = Vector6::zeros();
                d[k] = NUMERIC_STEP;
                let (p, m) = (se3::exp(&d), se3::exp(&-d));
                if vi.is_some() {
                    let col = (residual(e, &(p * ti), &tj) - residual(e, &(m * ti), &tj))
                        / (2.0 * NUMERIC_STEP);
                    ji.set_column(k, &col);
                }
                if vj.is_some() {
                    let col = (residual(e, &ti, &(p * tj)) - residual(e, &ti, &(m * tj)))
                        / (2.0 * NUMERIC_STEP);
                    jj.set_column(k, &col);
                }
            }
            let om = e.information;
            if let Some(a) = vi {
                diag[a] += ji.transpose() * om * ji;
                g[a] += ji.transpose() * om * r;
            }
            if let Some(b) = vj {
                diag[b] += jj.transpose() * om * jj;
                g[b] += jj.transpose() * om * r;
            }
            if let (Some(a), Some(b)) = (vi, vj) {
                // Block (a, b) = J_iᵀΩJ_j; store the lower one (row > column).
                if a > b {
                    off.push((a, b, ji.transpose() * om * jj));
                } else {
                    off.push((b, a, jj.transpose() * om * ji));
                }
            }
        }
        if it == 0 {
            let max_diag = diag
                .iter()
                .flat_map(|d| (0..6).map(move |k| d[(k, k)]))
                .fold(0.0, f64::max);
            lambda = LM_TAU * max_diag;
        }
        if lambda.is_nan() || lambda <= 0.0 || g.iter().all(|v| v.iter().all(|x| *x == 0.0)) {
            break;
        }
        let rhs: Vec<f64> = g.iter().flat_map(|v| v.iter().map(|x| -x)).collect();

        let mut accepted = false;
        for _ in 0..LM_MAX_TRIALS {
            let mut m = Skyline::new(&first);
            for (a, d) in diag.iter().enumerate() {
                let dd = d + Matrix6::identity() * lambda;
                for r in 0..6 {
                    for c in 0..=r {
                        m.add(6 * a + r, 6 * a + c, dd[(r, c)]);
                    }
                }
            }
            for (a, b, blk) in &off {
                for r in 0..6 {
                    for c in 0..6 {
                        m.add(6 * a + r, 6 * b + c, blk[(r, c)]);
                    }
                }
            }
            let step = m.factor().then(|| m.solve(&rhs));
            if let Some(dx) = step.filter(|d| d.iter().all(|x| x.is_finite())) {
                let mut cand = poses.clone();
                let mut predicted = 0.0;
                for (k, v) in var.iter().enumerate() {
                    if let Some(a) = v {
                        let d = Vector6::from_column_slice(&dx[6 * a..6 * a + 6]);
                        cand[k] = se3::exp(&d) * poses[k];
                        predicted += d.dot(&(lambda * d - g[*a]));
                    }
                }
                let new_cost = cost_of(&cand);
                // Costs are Σ rᵀΩr = 2F; the predicted decrease of F is ½δᵀ(λδ − g).
                let gain = (cost - new_cost) / predicted;
                if new_cost.is_finite() && predicted > 0.0 && gain > 0.0 {
                    poses = cand;
                    cost = new_cost;
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
    PoseGraphResult {
        poses,
        initial_cost,
        final_cost: cost,
    }
}

/// Symmetric matrix stored by rows of its lower triangle from each row's first non-zero
/// column (the envelope); Cholesky `A = LLᵀ` in place keeps the same envelope.
struct Skyline {
    /// First stored column of each scalar row.
    start: Vec<usize>,
    /// Row `i` holds columns `start[i]..=i`.
    rows: Vec<Vec<f64>>,
}

impl Skyline {
    /// Envelope from the first variable (6-blocks) each block row touches.
    fn new(first_block: &[usize]) -> Self {
        let mut start = Vec::with_capacity(6 * first_block.len());
        let mut rows = Vec::with_capacity(6 * first_block.len());
        for (a, &f) in first_block.iter().enumerate() {
            for r in 0..6 {
                let i = 6 * a + r;
                start.push(6 * f);
                rows.push(vec![0.0; i + 1 - 6 * f]);
            }
        }
        Self { start, rows }
    }

    /// Adds `v` at `(i, j)`, `j ≤ i` inside the envelope (entries outside are ignored, which
    /// cannot happen for blocks declared in the envelope).
    fn add(&mut self, i: usize, j: usize, v: f64) {
        if let Some(x) = self
            .rows
            .get_mut(i)
            .and_then(|row| row.get_mut(j.wrapping_sub(self.start[i])))
        {
            *x += v;
        }
    }

    /// In-place Cholesky; false when the matrix is not positive definite.
    fn factor(&mut self) -> bool {
        let n = self.rows.len();
        for i in 0..n {
            let si = self.start[i];
            for j in si..=i {
                let sj = self.start[j];
                let k0 = si.max(sj);
                let mut sum = self.rows[i][j - si];
                for k in k0..j {
                    sum -= self.rows[i][k - si] * self.rows[j][k - sj];
                }
                if j == i {
                    if sum.is_nan() || sum <= 0.0 {
                        return false;
                    }
                    self.rows[i][i - si] = sum.sqrt();
                } else {
                    self.rows[i][j - si] = sum / self.rows[j][j - sj];
                }
            }
        }
        true
    }

    /// Solves `LLᵀx = b` after [`Skyline::factor`].
    fn solve(&self, b: &[f64]) -> Vec<f64> {
        let n = self.rows.len();
        let mut y = b.to_vec();
        for i in 0..n {
            let si = self.start[i];
            let mut s = y[i];
            for k in si..i {
                s -= self.rows[i][k - si] * y[k];
            }
            y[i] = s / self.rows[i][i - si];
        }
        for i in (0..n).rev() {
            let si = self.start[i];
            y[i] /= self.rows[i][i - si];
            let xi = y[i];
            for k in si..i {
                y[k] -= self.rows[i][k - si] * xi;
            }
        }
        y
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector, Isometry3, Translation3, UnitQuaternion};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn skyline_cholesky_matches_dense() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        // 4 blocks; block 3 touches block 0 (a "loop"), others their predecessor.
        let first = [0usize, 0, 1, 0];
        let n = 24;
        let mut a = DMatrix::<f64>::zeros(n, n);
        for bi in 0..4 {
            for bj in first[bi]..=bi {
                if bj + 1 < bi && !(bi == 3 && bj == 0) {
                    continue;
                }
                for r in 0..6 {
                    for c in 0..6 {
                        let (i, j) = (6 * bi + r, 6 * bj + c);
                        if j <= i {
                            let v = rng.random_range(-1.0..1.0);
                            a[(i, j)] = v;
                            a[(j, i)] = v;
                        }
                    }
                }
            }
        }
        for i in 0..n {
            a[(i, i)] += 30.0;
        }
        let mut m = Skyline::new(&first);
        for i in 0..n {
            for j in 0..=i {
                if a[(i, j)] != 0.0 {
                    m.add(i, j, a[(i, j)]);
                }
            }
        }
        let b: Vec<f64> = (0..n).map(|i| (i as f64 * 0.7).sin()).collect();
        assert!(m.factor());
        let x = m.solve(&b);
        let dense = a
            .clone()
            .cholesky()
            .map(|c| c.solve(&DVector::from_vec(b.clone())));
        let Some(dense) = dense else {
            panic!("dense Cholesky failed");
        };
        let err = (DVector::from_vec(x) - dense).norm();
        assert!(err < 1e-10, "{err}");
    }

    /// A loop of `n` poses on a circle with consistent odometry and one loop edge.
    fn ring(n: usize) -> (Vec<Se3>, Vec<PoseGraphEdge>) {
        let truth: Vec<Se3> = (0..n)
            .map(|k| {
                let a = k as f64 / n as f64 * std::f64::consts::TAU;
                let twc = Isometry3::from_parts(
                    Translation3::new(2.0 * a.cos(), 0.1 * (3.0 * a).sin(), 2.0 * a.sin()),
                    UnitQuaternion::from_euler_angles(0.0, -a, 0.05 * a.sin()),
                );
                twc.inverse()
            })
            .collect();
        let mut edges = Vec::new();
        for k in 0..n {
            let j = (k + 1) % n;
            edges.push(PoseGraphEdge {
                i: k,
                j,
                t_ij: truth[k] * truth[j].inverse(),
                information: Matrix6::identity(),
            });
        }
        (truth, edges)
    }

    fn max_err(a: &[Se3], b: &[Se3]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(x, y)| {
                let d = x * y.inverse();
                d.translation.vector.norm() + d.rotation.angle()
            })
            .fold(0.0, f64::max)
    }

    #[test]
    fn closes_a_drifted_loop() {
        let n = 40;
        let (truth, edges) = ring(n);
        // Drifted estimate: odometry composed with a small bias, as tracking would give.
        let bias = se3::exp(&Vector6::new(0.002, -0.003, 0.001, 0.01, 0.0, -0.005));
        let mut drifted = vec![truth[0]];
        for k in 1..n {
            let rel = truth[k] * truth[k - 1].inverse();
            let prev = drifted[k - 1];
            drifted.push(bias * rel * prev);
        }
        assert!(max_err(&drifted, &truth) > 0.1);
        let mut fixed = vec![false; n];
        fixed[0] = true;
        let res = optimize_pose_graph(&drifted, &fixed, &edges, &PoseGraphParams::default());
        assert_eq!(res.poses[0], drifted[0]);
        let e = max_err(&res.poses, &truth);
        assert!(e < 1e-6, "{e}");
        assert!(res.final_cost < 1e-10 && res.initial_cost > 1e-3);
    }

    #[test]
    fn information_weights_decide_conflicts() {
        // Two poses, pose 0 fixed, two contradicting measurements of pose 1.
        let t0 = Se3::identity();
        let t1 = Se3::from_parts(Translation3::new(1.0, 0.0, 0.0), UnitQuaternion::identity());
        let t1b = Se3::from_parts(Translation3::new(1.2, 0.0, 0.0), UnitQuaternion::identity());
        let e = |t: Se3, w: f64| PoseGraphEdge {
            i: 1,
            j: 0,
            t_ij: t * t0.inverse(),
            information: Matrix6::identity() * w,
        };
        let run = |wa: f64, wb: f64| {
            let r = optimize_pose_graph(
                &[t0, t1],
                &[true, false],
                &[e(t1, wa), e(t1b, wb)],
                &PoseGraphParams::default(),
            );
            r.poses[1].translation.vector.x
        };
        let equal = run(1.0, 1.0);
        let trust_a = run(9.0, 1.0);
        assert!((equal - 1.1).abs() < 1e-6, "{equal}");
        assert!((trust_a - 1.02).abs() < 1e-6, "{trust_a}");
    }

    #[test]
    fn noisy_edges_and_bad_input_are_tolerated() {
        let n = 20;
        let (truth, mut edges) = ring(n);
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        for e in edges.iter_mut() {
            let d = Vector6::from_fn(|_, _| rng.random_range(-0.002..0.002));
            e.t_ij = se3::exp(&d) * e.t_ij;
        }
        let mut bad = edges[0];
        bad.i = 99;
        edges.push(bad);
        let mut fixed = vec![false; n];
        fixed[0] = true;
        let res = optimize_pose_graph(&truth, &fixed, &edges, &PoseGraphParams::default());
        assert!(res.final_cost <= res.initial_cost);
        assert!(max_err(&res.poses, &truth) < 0.05);
    }
}
