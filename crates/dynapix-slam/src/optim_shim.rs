//! TEMPORARY stand-in for `dynapix_optim::{optimize_pose, bundle_adjust}` until the optim
//! branch lands: Gauss-Newton pose-only optimisation with Huber and outlier rounds; BA is a
//! no-op. Removed once the real solvers are merged.

use dynapix_geometry::se3::{exp, hat};
use dynapix_optim::{
    BaParams, BaProblem, BaResult, PoseOnlyParams, PoseOnlyProblem, PoseOnlyResult,
};
use nalgebra::{Matrix3, Matrix6, SMatrix, Vector3, Vector6};

fn residual_and_jac(
    p: &PoseOnlyProblem,
    pose: &dynapix_geometry::Se3,
    i: usize,
) -> Option<(Vec<f64>, Vec<[f64; 6]>)> {
    let c = &p.camera;
    let o = &p.observations[i];
    let xc = pose
        .transform_point(&nalgebra::Point3::from(p.points[i]))
        .coords;
    if xc.z <= 0.0 {
        return None;
    }
    let iz = 1.0 / xc.z;
    let u = c.fx * xc.x * iz + c.cx;
    let v = c.fy * xc.y * iz + c.cy;
    let mut d = SMatrix::<f64, 3, 6>::zeros();
    let mut dxc = SMatrix::<f64, 3, 6>::zeros();
    let h: Matrix3<f64> = -hat(&xc);
    dxc.fixed_view_mut::<3, 3>(0, 0).copy_from(&h);
    dxc.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&Matrix3::identity());
    let jp = SMatrix::<f64, 3, 3>::new(
        c.fx * iz,
        0.0,
        -c.fx * xc.x * iz * iz,
        0.0,
        c.fy * iz,
        -c.fy * xc.y * iz * iz,
        c.fx * iz,
        0.0,
        -(c.fx * xc.x - c.bf) * iz * iz,
    );
    d.copy_from(&(-jp * dxc));
    let mut r = vec![o.uv[0] - u, o.uv[1] - v];
    let rows = if let Some(ur) = o.u_right {
        r.push(ur - (u - c.bf * iz));
        3
    } else {
        2
    };
    let j = (0..rows)
        .map(|k| {
            let mut a = [0.0; 6];
            for (m, x) in a.iter_mut().enumerate() {
                *x = d[(k, m)];
            }
            a
        })
        .collect();
    Some((r, j))
}

/// Pose-only optimisation (stand-in).
pub fn optimize_pose(p: &PoseOnlyProblem, params: &PoseOnlyParams) -> PoseOnlyResult {
    let n = p.observations.len();
    let mut inlier = vec![true; n];
    let mut pose = p.pose;
    for round in 0..params.rounds {
        pose = p.pose;
        let robust = round < params.robust_rounds;
        for _ in 0..params.iterations {
            let mut hm = Matrix6::<f64>::zeros();
            let mut b = Vector6::<f64>::zeros();
            for i in 0..n {
                if !inlier[i] {
                    continue;
                }
                let Some((r, j)) = residual_and_jac(p, &pose, i) else {
                    continue;
                };
                let o = &p.observations[i];
                let info = o.inv_sigma2 * o.weight;
                let chi2: f64 = r.iter().map(|x| x * x).sum::<f64>() * info;
                let delta = if o.u_right.is_some() {
                    params.chi2_stereo.sqrt()
                } else {
                    params.chi2_mono.sqrt()
                };
                let e = chi2.sqrt();
                let w = if robust && e > delta { delta / e } else { 1.0 } * info;
                for k in 0..r.len() {
                    let jk = Vector6::from_row_slice(&j[k]);
                    hm += w * jk * jk.transpose();
                    b -= w * jk * r[k];
                }
            }
            for k in 0..6 {
                hm[(k, k)] += 1e-6;
            }
            let Some(dx) = hm.cholesky().map(|c| c.solve(&b)) else {
                break;
            };
            pose = exp(&dx) * pose;
            if dx.norm() < 1e-9 {
                break;
            }
        }
        for i in 0..n {
            let o = &p.observations[i];
            let th = if o.u_right.is_some() {
                params.chi2_stereo
            } else {
                params.chi2_mono
            };
            inlier[i] = match residual_and_jac(p, &pose, i) {
                Some((r, _)) => r.iter().map(|x| x * x).sum::<f64>() * o.inv_sigma2 <= th,
                None => false,
            };
        }
        if n < 10 {
            break;
        }
    }
    let _ = Vector3::<f64>::zeros();
    let num_inliers = inlier.iter().filter(|&&x| x).count();
    PoseOnlyResult {
        pose,
        inlier,
        num_inliers,
    }
}

/// Bundle adjustment (stand-in: returns the input, all edges inliers).
pub fn bundle_adjust(p: &BaProblem, _params: &BaParams) -> BaResult {
    BaResult {
        poses: p.poses.clone(),
        points: p.points.clone(),
        inlier: vec![true; p.edges.len()],
    }
}
