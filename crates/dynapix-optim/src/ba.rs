//! Weighted bundle adjustment with a Schur complement: ORB-SLAM2's `LocalBundleAdjustment`
//! schedule (spec §6.7) and the DynaPix weighted edges of local and global BA (spec §2.7).
//!
//! Schedule: `iterations_robust` Levenberg–Marquardt iterations (Huber kernel when `robust`),
//! then, when `iterations_refine > 0`, every edge with χ² over its threshold or a point behind
//! the camera is dropped, the kernel removed, and `iterations_refine` more iterations run.
//! Finally every edge is classified again at the final estimate (the flags ORB-SLAM2 uses to
//! erase observations).
//!
//! Linear algebra: points are 3-DoF blocks eliminated by the Schur complement; the reduced
//! camera system (6 × free poses, dense — local BA has a few tens of keyframes) is solved by
//! Cholesky. Fixed poses contribute edges but no variables. Points are split into a fixed
//! number of chunks (a function of the problem size only) processed in parallel with rayon and
//! summed in chunk order, so results do not depend on the thread count.

use crate::edge;
use crate::pose::{LM_MAX_TRIALS, LM_TAU};
use crate::problem::{BaParams, BaProblem, BaResult, Observation, StereoCamera, WeightMode};
use dynapix_geometry::{Se3, se3};
use dynapix_simd::Avx2;
use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, Matrix6x3, Point3, Vector3, Vector6};
use rayon::prelude::*;
use std::ops::Range;

/// A pose as rotation matrix and translation (cheaper to apply than a quaternion).
type Rt = (Matrix3<f64>, Vector3<f64>);

fn to_rt(poses: &[Se3]) -> Vec<Rt> {
    poses
        .iter()
        .map(|t| {
            (
                *t.rotation.to_rotation_matrix().matrix(),
                t.translation.vector,
            )
        })
        .collect()
}

/// Upper bound on the number of point chunks (parallel work items).
const MAX_CHUNKS: usize = 16;
/// Minimum points per chunk, so small problems are not split needlessly.
const MIN_POINTS_PER_CHUNK: usize = 64;
/// Budget (in f64 entries) for the per-chunk dense Schur accumulators together.
const SCHUR_BUDGET: usize = 1 << 22;

/// A validated edge in point-sorted order.
#[derive(Clone, Copy)]
struct Prep {
    pose: usize,
    /// Index of the pose among the free variables, `None` for fixed poses.
    var: Option<usize>,
    point: usize,
    obs: Observation,
    stereo: bool,
    /// χ² threshold of the edge type, also the Huber δ².
    thr: f64,
    /// Index in [`BaProblem::edges`].
    orig: usize,
}

/// Read-only context shared by the chunks.
struct Ctx<'a> {
    cam: StereoCamera,
    mode: WeightMode,
    edges: &'a [Prep],
    /// CSR: edges of point `p` are `edges[point_start[p]..point_start[p + 1]]`.
    point_start: &'a [usize],
    n_vars: usize,
}

/// Work buffers of one chunk of points (all vectors indexed locally).
struct Chunk {
    points: Range<usize>,
    edge_offset: usize,
    // Per edge.
    s: Vec<f64>,
    w: Vec<Matrix6x3<f64>>,
    // Per point.
    v: Vec<Matrix3<f64>>,
    gp: Vec<Vector3<f64>>,
    vinv: Vec<Matrix3<f64>>,
    dp: Vec<Vector3<f64>>,
    // Per free pose.
    a: Vec<Matrix6<f64>>,
    gc: Vec<Vector6<f64>>,
    // Reduced system contributions.
    /// Upper blocks `(a, b)`, `a ≤ b`, of `−W V⁻¹ Wᵀ` at `a·n_vars + b`.
    schur: Vec<Matrix6<f64>>,
    /// Which blocks of `schur` the last [`Chunk::reduce`] wrote (the others are zero), as
    /// flags at `a·n_vars + b` and as a list; only these are cleared and summed.
    touched: Vec<bool>,
    touched_list: Vec<usize>,
    rhs: DVector<f64>,
    cost: f64,
    new_cost: f64,
    pred: f64,
    /// The active edges on free poses with a non-zero weight, `(pose variable, local edge)`,
    /// of local point `lp` at `free[free_start[lp]..free_start[lp + 1]]` (set by
    /// [`Chunk::linearize`]; the only edges of the reduced system).
    free: Vec<(usize, usize)>,
    free_start: Vec<usize>,
    /// Scratch of [`Chunk::reduce`]: `W V⁻¹` of one point's free edges.
    ys: Vec<Matrix6x3<f64>>,
}

impl Chunk {
    fn new(ctx: &Ctx, points: Range<usize>) -> Self {
        let e0 = ctx.point_start[points.start];
        let e1 = ctx.point_start[points.end];
        let ne = e1 - e0;
        let np = points.len();
        let n6 = 6 * ctx.n_vars;
        Self {
            points,
            edge_offset: e0,
            s: vec![0.0; ne],
            w: vec![Matrix6x3::zeros(); ne],
            v: vec![Matrix3::zeros(); np],
            gp: vec![Vector3::zeros(); np],
            vinv: vec![Matrix3::zeros(); np],
            dp: vec![Vector3::zeros(); np],
            a: vec![Matrix6::zeros(); ctx.n_vars],
            gc: vec![Vector6::zeros(); ctx.n_vars],
            schur: vec![Matrix6::zeros(); ctx.n_vars * ctx.n_vars],
            touched: vec![false; ctx.n_vars * ctx.n_vars],
            touched_list: Vec::new(),
            rhs: DVector::zeros(n6),
            cost: 0.0,
            new_cost: 0.0,
            pred: 0.0,
            free: Vec::with_capacity(ne),
            free_start: Vec::with_capacity(np + 1),
            ys: Vec::new(),
        }
    }

    /// Jacobians, residuals, point blocks `V`, `g_p`, camera blocks `A`, `g_c` and `2F`.
    #[inline(always)]
    fn linearize_body(
        &mut self,
        ctx: &Ctx,
        poses: &[Rt],
        points: &[Vector3<f64>],
        active: &[bool],
        robust: bool,
    ) {
        self.cost = 0.0;
        self.a.iter_mut().for_each(|m| *m = Matrix6::zeros());
        self.gc.iter_mut().for_each(|m| *m = Vector6::zeros());
        self.free.clear();
        self.free_start.clear();
        self.free_start.push(0);
        for (lp, p) in self.points.clone().enumerate() {
            let mut v = Matrix3::zeros();
            let mut gp = Vector3::zeros();
            for e in ctx.point_start[p]..ctx.point_start[p + 1] {
                let le = e - self.edge_offset;
                self.s[le] = 0.0;
                if !active[e] {
                    continue;
                }
                let ed = &ctx.edges[e];
                let (rot, tr) = &poses[ed.pose];
                let xc = rot * points[p] + tr;
                let Some(r) = edge::residual(&ctx.cam, &xc, &ed.obs) else {
                    continue;
                };
                let wt = edge::weigh(
                    edge::chi2(&r, ed.obs.inv_sigma2),
                    ed.obs.weight,
                    ctx.mode,
                    robust.then_some(ed.thr),
                );
                self.cost += wt.cost;
                let s = wt.irls * ed.obs.inv_sigma2;
                let jpi = edge::projection_jacobian(&ctx.cam, &xc, ed.stereo);
                let jp = -jpi * rot;
                v += s * jp.transpose() * jp;
                gp += s * jp.transpose() * r;
                if let Some(k) = ed.var {
                    let jc = edge::pose_jacobian(&jpi, &xc);
                    self.a[k] += edge::ata_3x6(&jc, s);
                    self.gc[k] += s * jc.transpose() * r;
                    self.w[le] = edge::atb_3x6_3x3(&jc, &jp, s);
                    if s != 0.0 {
                        self.free.push((k, le));
                    }
                }
                self.s[le] = s;
            }
            self.free_start.push(self.free.len());
            self.v[lp] = v;
            self.gp[lp] = gp;
        }
    }

    /// Damped point inverses and this chunk's part of `−W V⁻¹ Wᵀ` and `W V⁻¹ g_p`.
    #[inline(always)]
    fn reduce_body(&mut self, ctx: &Ctx, lambda: f64) {
        for &k in &self.touched_list {
            self.schur[k] = Matrix6::zeros();
            self.touched[k] = false;
        }
        self.touched_list.clear();
        let nv = ctx.n_vars;
        self.rhs.fill(0.0);
        let mut ys = std::mem::take(&mut self.ys);
        for lp in 0..self.points.len() {
            let damped = self.v[lp] + Matrix3::identity() * lambda;
            // A point whose block cannot be inverted is left where it is for this step.
            let vinv = damped
                .try_inverse()
                .filter(|m| m.iter().all(|x| x.is_finite()))
                .unwrap_or_else(Matrix3::zeros);
            self.vinv[lp] = vinv;
            // `Y = W V⁻¹` of the point's active edges on free poses.
            let free = &self.free[self.free_start[lp]..self.free_start[lp + 1]];
            ys.clear();
            for &(va, le) in free {
                let y = self.w[le] * vinv;
                let mut rhs = self.rhs.fixed_rows_mut::<6>(6 * va);
                rhs += y * self.gp[lp];
                ys.push(y);
            }
            // Pairs (e, f) with f ≥ e, in edge order; the block of (f, e) is the transpose.
            for (i, (&(va, _), y)) in free.iter().zip(&ys).enumerate() {
                for (j, &(vb, lf)) in free.iter().enumerate().skip(i) {
                    let wf = &self.w[lf];
                    let k = va.min(vb) * nv + va.max(vb);
                    if !self.touched[k] {
                        self.touched[k] = true;
                        self.touched_list.push(k);
                    }
                    // Keep only the upper blocks: `(a, b)` takes `Y_e W_fᵀ` or its transpose.
                    if j == i || va < vb {
                        edge::sub_abt_6x3(&mut self.schur[k], y, wf);
                    } else if va > vb {
                        edge::sub_abt_6x3(&mut self.schur[k], wf, y);
                    } else {
                        let block = edge::mul_abt_6x3(y, wf);
                        self.schur[k] -= block + block.transpose();
                    }
                }
            }
        }
        self.ys = ys;
    }

    /// Point steps `δp = V⁻¹(−g_p − Wᵀδc)` and this chunk's part of the predicted decrease.
    #[inline(always)]
    fn back_substitute_body(&mut self, dc: &DVector<f64>, lambda: f64) {
        self.pred = 0.0;
        for lp in 0..self.points.len() {
            let mut t = -self.gp[lp];
            for &(k, le) in &self.free[self.free_start[lp]..self.free_start[lp + 1]] {
                t -= self.w[le].transpose() * dc.fixed_rows::<6>(6 * k);
            }
            let dp = self.vinv[lp] * t;
            self.dp[lp] = dp;
            self.pred += dp.dot(&(lambda * dp - self.gp[lp]));
        }
    }

    /// `2F` at the candidate poses and `points + δp`.
    #[inline(always)]
    fn candidate_cost_body(
        &mut self,
        ctx: &Ctx,
        poses: &[Rt],
        points: &[Vector3<f64>],
        active: &[bool],
        robust: bool,
    ) {
        let mut cost = 0.0;
        for (lp, p) in self.points.clone().enumerate() {
            let x = points[p] + self.dp[lp];
            for e in ctx.point_start[p]..ctx.point_start[p + 1] {
                if !active[e] {
                    continue;
                }
                let ed = &ctx.edges[e];
                let (rot, tr) = &poses[ed.pose];
                let xc = rot * x + tr;
                if let Some(r) = edge::residual(&ctx.cam, &xc, &ed.obs) {
                    cost += edge::weigh(
                        edge::chi2(&r, ed.obs.inv_sigma2),
                        ed.obs.weight,
                        ctx.mode,
                        robust.then_some(ed.thr),
                    )
                    .cost;
                }
            }
        }
        self.new_cost = cost;
    }
}

/// Defines a `Chunk` method that runs its `_body` compiled for AVX2 when given an [`Avx2`]
/// proof, and the baseline build otherwise. The same IEEE operations in the same order either
/// way (Rust never contracts to FMA), only wider registers: the results are bit-identical.
macro_rules! avx2_method {
    ($(#[$m:meta])* $name:ident, $avx:ident, $body:ident, ($($a:ident: $t:ty),*)) => {
        $(#[$m])*
        fn $name(&mut self, isa: Option<Avx2>, $($a: $t),*) {
            #[cfg(target_arch = "x86_64")]
            if let Some(avx2) = isa {
                // SAFETY: the token proves the CPU has AVX2.
                return unsafe { self.$avx(avx2, $($a),*) };
            }
            let _ = isa;
            self.$body($($a),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        fn $avx(&mut self, _: Avx2, $($a: $t),*) {
            self.$body($($a),*)
        }
    };
}

impl Chunk {
    avx2_method!(
        /// See [`Chunk::linearize_body`].
        linearize, linearize_avx2, linearize_body,
        (ctx: &Ctx, poses: &[Rt], points: &[Vector3<f64>], active: &[bool], robust: bool)
    );
    avx2_method!(
        /// See [`Chunk::reduce_body`].
        reduce, reduce_avx2, reduce_body, (ctx: &Ctx, lambda: f64)
    );
    avx2_method!(
        /// See [`Chunk::back_substitute_body`].
        back_substitute, back_substitute_avx2, back_substitute_body,
        (dc: &DVector<f64>, lambda: f64)
    );
    avx2_method!(
        /// See [`Chunk::candidate_cost_body`].
        candidate_cost, candidate_cost_avx2, candidate_cost_body,
        (ctx: &Ctx, poses: &[Rt], points: &[Vector3<f64>], active: &[bool], robust: bool)
    );
}

/// Bundle adjustment of `problem` (see the module documentation).
///
/// Edges with an out-of-range pose or point index, a non-finite point, or a non-positive
/// `inv_sigma2` take no part and are reported as outliers. Missing `pose_fixed` entries mean
/// "free". The returned `inlier[i]` refers to `problem.edges[i]`.
pub fn bundle_adjust(problem: &BaProblem, params: &BaParams) -> BaResult {
    bundle_adjust_on(problem, params, Avx2::detect())
}

/// [`bundle_adjust`] with the chunk kernels of `isa` (AVX2 or the baseline build).
fn bundle_adjust_on(problem: &BaProblem, params: &BaParams, isa: Option<Avx2>) -> BaResult {
    let n_poses = problem.poses.len();
    let n_points = problem.points.len();
    let mut var_of = vec![None; n_poses];
    let mut var_pose = Vec::new();
    for (i, v) in var_of.iter_mut().enumerate() {
        if !problem.pose_fixed.get(i).copied().unwrap_or(false) {
            *v = Some(var_pose.len());
            var_pose.push(i);
        }
    }

    let mut edges: Vec<Prep> = problem
        .edges
        .iter()
        .enumerate()
        .filter(|(_, e)| {
            e.pose < n_poses
                && e.point < n_points
                && problem.points[e.point].iter().all(|v| v.is_finite())
                && e.obs.inv_sigma2.is_finite()
                && e.obs.inv_sigma2 > 0.0
                && e.obs.weight.is_finite()
        })
        .map(|(orig, e)| {
            let mut obs = e.obs;
            if let Some((lo, hi)) = params.weight_clamp {
                obs.weight = obs.weight.max(lo).min(hi);
            }
            let stereo = obs.u_right.is_some();
            Prep {
                pose: e.pose,
                var: var_of[e.pose],
                point: e.point,
                obs,
                stereo,
                thr: if stereo {
                    params.chi2_stereo
                } else {
                    params.chi2_mono
                },
                orig,
            }
        })
        .collect();
    // Stable: edges of one point stay in input order, so sums are reproducible.
    edges.sort_by_key(|e| e.point);
    let mut point_start = vec![0usize; n_points + 1];
    for e in &edges {
        point_start[e.point + 1] += 1;
    }
    for p in 0..n_points {
        point_start[p + 1] += point_start[p];
    }

    let ctx = Ctx {
        cam: problem.camera,
        mode: params.weight_mode,
        edges: &edges,
        point_start: &point_start,
        n_vars: var_pose.len(),
    };
    let n6 = 6 * ctx.n_vars;
    let by_size = n_points.div_ceil(MIN_POINTS_PER_CHUNK);
    let by_memory = (SCHUR_BUDGET / (n6 * n6).max(1)).max(1);
    let n_chunks = by_size.min(MAX_CHUNKS).min(by_memory).max(1);
    let per_chunk = n_points.div_ceil(n_chunks).max(1);
    let mut chunks: Vec<Chunk> = (0..n_points)
        .step_by(per_chunk)
        .map(|s| Chunk::new(&ctx, s..(s + per_chunk).min(n_points)))
        .collect();

    let mut poses = problem.poses.clone();
    let mut points = problem.points.clone();
    let mut active = vec![true; edges.len()];

    let mut solver = Lm {
        ctx: &ctx,
        chunks: &mut chunks,
        var_pose: &var_pose,
        min_relative_decrease: params.min_relative_decrease,
        isa,
    };
    let mut iterations = solver.run(
        &mut poses,
        &mut points,
        &active,
        params.robust,
        params.iterations_robust,
    );
    if params.iterations_refine > 0 {
        for (k, e) in edges.iter().enumerate() {
            active[k] = classify(&ctx, e, &poses, &points);
        }
        iterations += solver.run(
            &mut poses,
            &mut points,
            &active,
            false,
            params.iterations_refine,
        );
    }

    let mut inlier = vec![false; problem.edges.len()];
    for e in &edges {
        inlier[e.orig] = classify(&ctx, e, &poses, &points);
    }
    BaResult {
        poses,
        points,
        inlier,
        iterations,
    }
}

/// Inlier test of ORB-SLAM2's local BA: χ² (weighted per mode) within the threshold and the
/// point in front of the camera.
fn classify(ctx: &Ctx, e: &Prep, poses: &[Se3], points: &[Vector3<f64>]) -> bool {
    let xc = (poses[e.pose] * Point3::from(points[e.point])).coords;
    if xc.z <= 0.0 {
        return false;
    }
    match edge::residual(&ctx.cam, &xc, &e.obs) {
        Some(r) => {
            edge::classification_chi2(edge::chi2(&r, e.obs.inv_sigma2), e.obs.weight, ctx.mode)
                <= e.thr
        }
        None => false,
    }
}

/// The Levenberg–Marquardt driver over the chunks.
struct Lm<'a, 'b> {
    ctx: &'a Ctx<'a>,
    chunks: &'b mut [Chunk],
    var_pose: &'a [usize],
    /// See [`BaParams::min_relative_decrease`].
    min_relative_decrease: f64,
    /// The chunk kernels' instruction set.
    isa: Option<Avx2>,
}

impl Lm<'_, '_> {
    /// Up to `iterations` LM iterations (g2o style, see `pose::lm`) on the active edges;
    /// returns how many ran (an iteration counts once its linearisation is done).
    fn run(
        &mut self,
        poses: &mut Vec<Se3>,
        points: &mut [Vector3<f64>],
        active: &[bool],
        robust: bool,
        iterations: usize,
    ) -> usize {
        let ctx = self.ctx;
        let isa = self.isa;
        let nv = ctx.n_vars;
        let n6 = 6 * nv;
        let mut lambda = 0.0;
        let mut nu = 2.0;
        let mut a_tot = vec![Matrix6::<f64>::zeros(); nv];
        let mut gc_tot = DVector::<f64>::zeros(n6);
        let mut s = DMatrix::<f64>::zeros(n6, n6);
        let mut rhs = DVector::<f64>::zeros(n6);
        let mut done = 0;
        for it in 0..iterations {
            done += 1;
            // From the second iteration on, the damping of the first trial is known before
            // the linearisation, and a chunk's reduction reads only what its own
            // linearisation wrote: both run in one parallel loop (the same operations on the
            // same data, one hand-over between the threads fewer).
            let reduced_with = (it > 0).then_some(lambda);
            {
                let rt = to_rt(poses);
                let (p, pts) = (&rt, &*points);
                self.chunks.par_iter_mut().for_each(|c| {
                    c.linearize(isa, ctx, p, pts, active, robust);
                    if let Some(l) = reduced_with {
                        c.reduce(isa, ctx, l);
                    }
                });
            }
            let mut cost = 0.0;
            a_tot.iter_mut().for_each(|m| *m = Matrix6::zeros());
            gc_tot.fill(0.0);
            let mut max_diag: f64 = 0.0;
            let mut grad_zero = true;
            for c in self.chunks.iter() {
                cost += c.cost;
                for k in 0..nv {
                    a_tot[k] += c.a[k];
                    let mut g = gc_tot.fixed_rows_mut::<6>(6 * k);
                    g += c.gc[k];
                }
                for (v, g) in c.v.iter().zip(&c.gp) {
                    max_diag = max_diag.max(v[(0, 0)]).max(v[(1, 1)]).max(v[(2, 2)]);
                    grad_zero &= g.iter().all(|x| *x == 0.0);
                }
            }
            for a in &a_tot {
                for k in 0..6 {
                    max_diag = max_diag.max(a[(k, k)]);
                }
            }
            grad_zero &= gc_tot.iter().all(|x| *x == 0.0);
            if it == 0 {
                lambda = LM_TAU * max_diag;
            }
            if grad_zero || lambda.is_nan() || lambda <= 0.0 {
                break;
            }

            let mut accepted = false;
            let mut converged = false;
            for trial in 0..LM_MAX_TRIALS {
                if trial > 0 || reduced_with != Some(lambda) {
                    self.chunks
                        .par_iter_mut()
                        .for_each(|c| c.reduce(isa, ctx, lambda));
                }
                rhs.copy_from(&gc_tot);
                rhs.neg_mut();
                for c in self.chunks.iter() {
                    rhs += &c.rhs;
                }
                for a in 0..nv {
                    for b in a..nv {
                        let mut block = Matrix6::zeros();
                        // Blocks a chunk did not write are zero: skipping them only leaves
                        // out additions of +0.
                        for c in self.chunks.iter().filter(|c| c.touched[a * nv + b]) {
                            block += c.schur[a * nv + b];
                        }
                        if a == b {
                            block += a_tot[a] + Matrix6::identity() * lambda;
                            // Exact symmetry for the factorisation.
                            block = (block + block.transpose()) * 0.5;
                        }
                        s.fixed_view_mut::<6, 6>(6 * a, 6 * b).copy_from(&block);
                        s.fixed_view_mut::<6, 6>(6 * b, 6 * a)
                            .copy_from(&block.transpose());
                    }
                }
                let dc = if n6 == 0 {
                    Some(DVector::zeros(0))
                } else {
                    s.clone().cholesky().map(|ch| ch.solve(&rhs))
                };
                let Some(dc) = dc.filter(|d| d.iter().all(|x| x.is_finite())) else {
                    lambda *= nu;
                    nu *= 2.0;
                    continue;
                };
                let mut cand = poses.clone();
                for (k, &pi) in self.var_pose.iter().enumerate() {
                    let d: Vector6<f64> = dc.fixed_rows::<6>(6 * k).into_owned();
                    cand[pi] = se3::exp(&d) * poses[pi];
                }
                {
                    // A chunk's candidate cost needs only its own point steps: one loop.
                    let rt = to_rt(&cand);
                    let (cp, pts, dc) = (&rt, &*points, &dc);
                    self.chunks.par_iter_mut().for_each(|c| {
                        c.back_substitute(isa, dc, lambda);
                        c.candidate_cost(isa, ctx, cp, pts, active, robust);
                    });
                }
                let mut predicted = dc.dot(&(lambda * &dc - &gc_tot));
                let mut finite = true;
                for c in self.chunks.iter() {
                    predicted += c.pred;
                    finite &= c.dp.iter().all(|d| d.iter().all(|x| x.is_finite()));
                }
                let new_cost: f64 = self.chunks.iter().map(|c| c.new_cost).sum();
                let gain = (cost - new_cost) / predicted;
                if finite && new_cost.is_finite() && predicted > 0.0 && gain > 0.0 {
                    *poses = cand;
                    for c in self.chunks.iter() {
                        for (lp, p) in c.points.clone().enumerate() {
                            points[p] += c.dp[lp];
                        }
                    }
                    let t = 2.0 * gain - 1.0;
                    lambda *= (1.0 - t * t * t).max(1.0 / 3.0);
                    nu = 2.0;
                    accepted = true;
                    converged = cost - new_cost < self.min_relative_decrease * cost;
                    break;
                }
                lambda *= nu;
                nu *= 2.0;
            }
            if !accepted || converged {
                break;
            }
        }
        done
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::BaEdge;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn cam() -> StereoCamera {
        StereoCamera {
            fx: 535.4,
            fy: 539.2,
            cx: 320.1,
            cy: 247.6,
            bf: 40.0,
        }
    }

    fn gauss(rng: &mut ChaCha8Rng) -> f64 {
        let u1: f64 = rng.random_range(1e-12..1.0);
        let u2: f64 = rng.random_range(0.0..1.0);
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Ground truth and a perturbed problem: `n_poses` cameras on a short arc, `n_points`
    /// points, every visible point observed (mono every `mono_every`-th edge), pixel noise σ.
    fn scene(
        seed: u64,
        n_poses: usize,
        n_points: usize,
        noise: f64,
        mono_every: usize,
    ) -> (BaProblem, Vec<Se3>, Vec<Vector3<f64>>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let c = cam();
        let truth_poses: Vec<Se3> = (0..n_poses)
            .map(|i| {
                let f = i as f64;
                let twc = Isometry3::from_parts(
                    Translation3::new(0.08 * f, 0.02 * (f * 0.7).sin(), 0.03 * f),
                    UnitQuaternion::from_euler_angles(0.01 * f, -0.02 * f, 0.005 * f),
                );
                twc.inverse()
            })
            .collect();
        let truth_points: Vec<Vector3<f64>> = (0..n_points)
            .map(|_| {
                Vector3::new(
                    rng.random_range(-2.0..2.5),
                    rng.random_range(-1.5..1.5),
                    rng.random_range(2.5..6.0),
                )
            })
            .collect();
        let mut edges = Vec::new();
        for (j, x) in truth_points.iter().enumerate() {
            for (i, t) in truth_poses.iter().enumerate() {
                let xc = (t * Point3::from(*x)).coords;
                let u = c.fx * xc.x / xc.z + c.cx;
                let v = c.fy * xc.y / xc.z + c.cy;
                if xc.z <= 0.1 || !(0.0..640.0).contains(&u) || !(0.0..480.0).contains(&v) {
                    continue;
                }
                let k = edges.len();
                edges.push(BaEdge {
                    pose: i,
                    point: j,
                    obs: Observation {
                        uv: [u + noise * gauss(&mut rng), v + noise * gauss(&mut rng)],
                        u_right: (mono_every == 0 || k % mono_every != 0)
                            .then(|| u - c.bf / xc.z + noise * gauss(&mut rng)),
                        inv_sigma2: 1.0,
                        weight: 1.0,
                    },
                });
            }
        }
        let mut poses = truth_poses.clone();
        for t in poses.iter_mut().skip(1) {
            let d = Vector6::new(
                0.01 * gauss(&mut rng),
                0.01 * gauss(&mut rng),
                0.01 * gauss(&mut rng),
                0.03 * gauss(&mut rng),
                0.03 * gauss(&mut rng),
                0.03 * gauss(&mut rng),
            );
            *t = se3::exp(&d) * *t;
        }
        let points = truth_points
            .iter()
            .map(|x| x + Vector3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng)) * 0.05)
            .collect();
        let mut pose_fixed = vec![false; n_poses];
        pose_fixed[0] = true;
        (
            BaProblem {
                camera: c,
                poses,
                pose_fixed,
                points,
                edges,
            },
            truth_poses,
            truth_points,
        )
    }

    fn max_pose_err(a: &[Se3], b: &[Se3]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(x, y)| {
                let d = x * y.inverse();
                d.translation.vector.norm() + d.rotation.angle()
            })
            .fold(0.0, f64::max)
    }

    /// Largest error over the points that have at least one observation.
    /// 95th percentile over the edges of `p` of the distance between their points in `a`
    /// and `b` (the bulk of the points, not the worst one).
    fn p95_point_diff(p: &BaProblem, a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
        let mut d: Vec<f64> = p
            .edges
            .iter()
            .map(|e| (a[e.point] - b[e.point]).norm())
            .collect();
        d.sort_by(f64::total_cmp);
        d[d.len() * 95 / 100]
    }

    fn max_point_err(p: &BaProblem, a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
        p.edges
            .iter()
            .map(|e| (a[e.point] - b[e.point]).norm())
            .fold(0.0, f64::max)
    }

    #[test]
    fn recovers_structure_and_motion_noise_free() {
        for mono_every in [0, 3] {
            let (p, tp, tx) = scene(1, 5, 300, 0.0, mono_every);
            let before = max_pose_err(&p.poses, &tp);
            let res = bundle_adjust(&p, &BaParams::default());
            let pe = max_pose_err(&res.poses, &tp);
            let xe = max_point_err(&p, &res.points, &tx);
            assert!(before > 1e-2);
            assert!(pe < 1e-6 && xe < 1e-5, "mono_every {mono_every}: {pe} {xe}");
            assert!(res.inlier.iter().all(|b| *b));
            assert_eq!(res.poses[0], p.poses[0], "fixed pose moved");
        }
    }

    #[test]
    fn noisy_problem_improves_and_fixed_poses_stay() {
        let (mut p, tp, tx) = scene(2, 6, 400, 1.0, 4);
        p.pose_fixed[3] = true;
        p.poses[3] = tp[3];
        let res = bundle_adjust(&p, &BaParams::default());
        assert_eq!(res.poses[0], p.poses[0]);
        assert_eq!(res.poses[3], p.poses[3]);
        let pe = max_pose_err(&res.poses, &tp);
        // With 1 px noise the estimate is not the truth, but it must be the same minimum
        // as the one reached when starting from the truth.
        let from_truth = bundle_adjust(
            &BaProblem {
                poses: tp.clone(),
                points: tx.clone(),
                ..p.clone()
            },
            &BaParams::default(),
        );
        let to_ml = max_pose_err(&res.poses, &from_truth.poses);
        // The robust stage may end with a slightly different outlier set (one edge here), so
        // compare the bulk of the points, not the worst one.
        let p95 = p95_point_diff(&p, &res.points, &from_truth.points);
        assert!(pe < 0.02, "pose error {pe}");
        assert!(
            to_ml < 1e-3 && p95 < 2e-3,
            "not at the optimum: {to_ml} {p95}"
        );
        let outliers = res.inlier.iter().filter(|b| !**b).count();
        assert!(
            outliers * 50 < res.inlier.len(),
            "{outliers} of {} rejected",
            res.inlier.len()
        );
    }

    #[test]
    fn outliers_are_flagged() {
        let (mut p, tp, _) = scene(3, 5, 300, 0.5, 0);
        let mut bad = vec![false; p.edges.len()];
        for (k, e) in p.edges.iter_mut().enumerate() {
            if k % 10 == 3 {
                e.obs.uv[0] += 30.0;
                e.obs.uv[1] -= 25.0;
                bad[k] = true;
            }
        }
        let res = bundle_adjust(&p, &BaParams::default());
        for k in 0..bad.len() {
            if bad[k] {
                assert!(!res.inlier[k], "corrupted edge {k} kept");
            }
        }
        let kept = (0..bad.len()).filter(|&k| !bad[k] && res.inlier[k]).count();
        let clean = bad.iter().filter(|b| !**b).count();
        assert!(kept as f64 > 0.95 * clean as f64, "{kept} of {clean}");
        assert!(max_pose_err(&res.poses, &tp) < 5e-3);
    }

    #[test]
    fn negative_depth_is_an_outlier() {
        let (mut p, _, _) = scene(4, 3, 100, 0.0, 0);
        // A point far behind every camera, observed once: it cannot be moved in front with
        // a small step and must be flagged.
        p.points.push(Vector3::new(0.0, 0.0, -50.0));
        let j = p.points.len() - 1;
        p.edges.push(BaEdge {
            pose: 0,
            point: j,
            obs: Observation {
                uv: [320.0, 240.0],
                u_right: Some(300.0),
                inv_sigma2: 1.0,
                weight: 1.0,
            },
        });
        let params = BaParams {
            iterations_robust: 0,
            iterations_refine: 0,
            ..BaParams::default()
        };
        let res = bundle_adjust(&p, &params);
        assert!(!res.inlier[p.edges.len() - 1]);
    }

    /// Observations of one point group in camera 1 agree with a camera shifted by 4 cm:
    /// down-weighting them moves camera 1 back towards the truth.
    #[test]
    fn weights_pull_the_estimate_towards_trusted_edges() {
        let (mut p, tp, _) = scene(5, 2, 300, 0.0, 0);
        let shifted = Isometry3::from_parts(
            Translation3::new(0.04, 0.0, 0.0),
            UnitQuaternion::identity(),
        ) * tp[1];
        let c = cam();
        let tx = scene(5, 2, 300, 0.0, 0).2;
        let mut group_b = vec![false; p.edges.len()];
        for (k, e) in p.edges.iter_mut().enumerate() {
            if e.pose == 1 && e.point % 2 == 1 {
                let xc = (shifted * Point3::from(tx[e.point])).coords;
                let u = c.fx * xc.x / xc.z + c.cx;
                e.obs.uv = [u, c.fy * xc.y / xc.z + c.cy];
                e.obs.u_right = Some(u - c.bf / xc.z);
                group_b[k] = true;
            }
        }
        let err = |res: &BaResult| {
            let d = res.poses[1] * tp[1].inverse();
            d.translation.vector.norm()
        };
        let plain = BaParams {
            robust: false,
            iterations_robust: 20,
            iterations_refine: 0,
            ..BaParams::default()
        };
        let base = err(&bundle_adjust(&p, &plain));
        assert!(base > 5e-3, "{base}");
        for mode in [WeightMode::Paper, WeightMode::Reference] {
            let mut q = p.clone();
            for (k, e) in q.edges.iter_mut().enumerate() {
                if group_b[k] {
                    e.obs.weight = 0.1;
                }
            }
            let params = BaParams {
                weight_mode: mode,
                ..plain.clone()
            };
            let weighted = err(&bundle_adjust(&q, &params));
            assert!(weighted < 0.5 * base, "{mode:?}: {weighted} vs {base}");
            // A clamp to [0.9, 1] undoes most of the down-weighting.
            let clamped = err(&bundle_adjust(
                &q,
                &BaParams {
                    weight_clamp: Some((0.9, 1.0)),
                    ..params.clone()
                },
            ));
            assert!(
                clamped > 2.0 * weighted,
                "{mode:?}: clamped {clamped} vs {weighted}"
            );
        }
    }

    /// One bad, low-weight observation: paper mode (unweighted χ²) rejects it, the reference
    /// (w²·χ²) keeps it, unless the weight is clamped to [0.9, 1].
    #[test]
    fn paper_and_reference_classify_differently() {
        let (mut p, tp, tx) = scene(6, 5, 200, 0.0, 0);
        p.poses = tp;
        p.points = tx;
        let k = p.edges.iter().position(|e| e.pose == 2).unwrap_or(0);
        let j = p.edges[k].point;
        let n_obs = p.edges.iter().filter(|e| e.point == j).count();
        assert!(n_obs >= 4, "test point seen {n_obs} times");
        p.edges[k].obs.uv[0] += 5.0;
        p.edges[k].obs.u_right = p.edges[k].obs.u_right.map(|u| u + 5.0);
        p.edges[k].obs.weight = 0.3;
        let run = |mode, clamp| {
            bundle_adjust(
                &p,
                &BaParams {
                    weight_mode: mode,
                    weight_clamp: clamp,
                    ..BaParams::default()
                },
            )
        };
        assert!(!run(WeightMode::Paper, None).inlier[k]);
        assert!(run(WeightMode::Reference, None).inlier[k]);
        assert!(!run(WeightMode::Reference, Some((0.9, 1.0))).inlier[k]);
        let n_out = run(WeightMode::Reference, None)
            .inlier
            .iter()
            .filter(|b| !**b)
            .count();
        assert_eq!(n_out, 0);
    }

    #[test]
    fn invalid_edges_are_ignored_and_flagged() {
        let (mut p, _, _) = scene(7, 3, 100, 0.0, 0);
        let n = p.edges.len();
        let mut e = p.edges[0];
        e.pose = 99;
        p.edges.push(e);
        let mut e = p.edges[1];
        e.obs.inv_sigma2 = f64::NAN;
        p.edges.push(e);
        let res = bundle_adjust(&p, &BaParams::default());
        assert!(!res.inlier[n] && !res.inlier[n + 1]);
        assert!(res.inlier[..n].iter().all(|b| *b));
    }

    #[test]
    fn avx2_and_baseline_kernels_agree_bit_for_bit() {
        let Some(isa) = Avx2::detect() else {
            eprintln!("skipping: no AVX2 on this CPU");
            return;
        };
        let (mut p, _, _) = scene(8, 6, 600, 1.0, 3);
        p.pose_fixed[2] = true;
        for e in p.edges.iter_mut().step_by(7) {
            e.obs.weight = 0.4;
        }
        let params = BaParams::default();
        let a = bundle_adjust_on(&p, &params, None);
        let b = bundle_adjust_on(&p, &params, Some(isa));
        assert_eq!(a.poses, b.poses);
        assert_eq!(a.points, b.points);
        assert_eq!(a.inlier, b.inlier);
        assert_eq!(a.iterations, b.iterations);
    }

    #[test]
    fn converged_stages_stop_early_at_the_same_minimum() {
        let (p, _, _) = scene(2, 6, 400, 1.0, 4);
        let full = bundle_adjust(&p, &BaParams::default());
        assert_eq!(full.iterations, 15, "every iteration runs by default");
        let params = BaParams {
            min_relative_decrease: 1e-5,
            ..BaParams::default()
        };
        let early = bundle_adjust(&p, &params);
        assert!(
            early.iterations < full.iterations,
            "{} iterations",
            early.iterations
        );
        let pe = max_pose_err(&early.poses, &full.poses);
        let p95 = p95_point_diff(&p, &early.points, &full.points);
        assert!(pe < 1e-4 && p95 < 1e-3, "{pe} {p95}");
    }

    #[test]
    fn result_does_not_depend_on_thread_count() {
        let (p, _, _) = scene(8, 6, 600, 1.0, 3);
        let run = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .map_err(|e| e.to_string());
            match pool {
                Ok(pool) => pool.install(|| bundle_adjust(&p, &BaParams::default())),
                Err(e) => panic!("thread pool: {e}"),
            }
        };
        let a = run(1);
        let b = run(3);
        assert_eq!(a.poses, b.poses);
        assert_eq!(a.points, b.points);
        assert_eq!(a.inlier, b.inlier);
    }
}
