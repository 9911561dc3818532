//! Synthetic problems shared by the criterion benchmark and the CPU-time example.

use dynapix_geometry::{Se3, se3};
use dynapix_optim::{BaEdge, BaProblem, Observation, PoseOnlyProblem, StereoCamera};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3, Vector6};
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

fn observe(rng: &mut ChaCha8Rng, t: &Se3, x: &Vector3<f64>, k: usize) -> Observation {
    let c = cam();
    let xc = (t * Point3::from(*x)).coords;
    let u = c.fx * xc.x / xc.z + c.cx;
    let v = c.fy * xc.y / xc.z + c.cy;
    let gross = if k % 20 == 7 { 25.0 } else { 0.0 };
    Observation {
        uv: [u + gauss(rng) + gross, v + gauss(rng)],
        u_right: (!k.is_multiple_of(4)).then(|| u - c.bf / xc.z + gauss(rng)),
        inv_sigma2: 1.0,
        weight: 1.0 - 0.05 * (k % 3) as f64,
    }
}

pub fn pose_problem() -> PoseOnlyProblem {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let c = cam();
    let t = Isometry3::from_parts(
        Translation3::new(0.2, -0.1, 0.3),
        UnitQuaternion::from_euler_angles(0.05, -0.1, 0.08),
    );
    let mut points = Vec::new();
    let mut observations = Vec::new();
    for k in 0..300 {
        let u = rng.random_range(20.0..620.0);
        let v = rng.random_range(20.0..460.0);
        let z = rng.random_range(1.0..5.0);
        let xc = Vector3::new((u - c.cx) / c.fx * z, (v - c.cy) / c.fy * z, z);
        let xw = (t.inverse() * Point3::from(xc)).coords;
        observations.push(observe(&mut rng, &t, &xw, k));
        points.push(xw);
    }
    PoseOnlyProblem {
        camera: c,
        pose: se3::exp(&Vector6::new(0.01, -0.02, 0.01, 0.03, 0.02, -0.03)) * t,
        points,
        observations,
    }
}

pub fn ba_problem() -> BaProblem {
    ba_problem_sized(10, 2000, 5)
}

/// A local-BA problem of `n_poses` keyframes (the first two fixed) and `n_points` points,
/// each seen by `per_point` consecutive keyframes.
pub fn ba_problem_sized(n_poses: usize, n_points: usize, per_point: usize) -> BaProblem {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let truth: Vec<Se3> = (0..n_poses)
        .map(|i| {
            let f = i as f64;
            Isometry3::from_parts(
                Translation3::new(0.05 * f, 0.01 * f, 0.02 * f),
                UnitQuaternion::from_euler_angles(0.005 * f, -0.01 * f, 0.003 * f),
            )
            .inverse()
        })
        .collect();
    let mut points = Vec::new();
    let mut edges = Vec::new();
    for j in 0..n_points {
        let x = Vector3::new(
            rng.random_range(-1.5..2.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(2.5..6.0),
        );
        let first = j % (n_poses + 1 - per_point);
        for (i, t) in truth.iter().enumerate().skip(first).take(per_point) {
            let k = edges.len();
            edges.push(BaEdge {
                pose: i,
                point: j,
                obs: observe(&mut rng, t, &x, k),
            });
        }
        points.push(x + Vector3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng)) * 0.02);
    }
    let poses = truth
        .iter()
        .enumerate()
        .map(|(i, t)| {
            if i < 2 {
                *t
            } else {
                let d = Vector6::new(
                    0.003 * gauss(&mut rng),
                    0.003 * gauss(&mut rng),
                    0.003 * gauss(&mut rng),
                    0.01 * gauss(&mut rng),
                    0.01 * gauss(&mut rng),
                    0.01 * gauss(&mut rng),
                );
                se3::exp(&d) * *t
            }
        })
        .collect();
    let mut pose_fixed = vec![false; n_poses];
    pose_fixed[0] = true;
    pose_fixed[1] = true;
    BaProblem {
        camera: cam(),
        poses,
        pose_fixed,
        points,
        edges,
    }
}

/// A drifted loop of 200 keyframes with odometry edges, a loop edge and covisibility edges to
/// the keyframe two steps back (about 400 edges), as essential-graph optimisation sees it.
pub fn pose_graph_problem() -> (Vec<Se3>, Vec<bool>, Vec<dynapix_optim::PoseGraphEdge>) {
    let n = 200;
    let truth: Vec<Se3> = (0..n)
        .map(|k| {
            let a = k as f64 / n as f64 * std::f64::consts::TAU;
            Isometry3::from_parts(
                Translation3::new(3.0 * a.cos(), 0.1 * (3.0 * a).sin(), 3.0 * a.sin()),
                UnitQuaternion::from_euler_angles(0.0, -a, 0.05 * a.sin()),
            )
            .inverse()
        })
        .collect();
    let mut edges = Vec::new();
    for k in 0..n {
        for step in [1, 2] {
            let j = (k + step) % n;
            if step == 2 && j < k {
                continue;
            }
            edges.push(dynapix_optim::PoseGraphEdge {
                i: k,
                j,
                t_ij: truth[k] * truth[j].inverse(),
                information: nalgebra::Matrix6::identity(),
            });
        }
    }
    let bias = se3::exp(&Vector6::new(0.001, -0.001, 0.0005, 0.004, 0.0, -0.002));
    let mut drifted = vec![truth[0]];
    for k in 1..n {
        let rel = truth[k] * truth[k - 1].inverse();
        let prev = drifted[k - 1];
        drifted.push(bias * rel * prev);
    }
    let mut fixed = vec![false; n];
    fixed[0] = true;
    (drifted, fixed, edges)
}

/// 150 correspondences, 30 % of them random pixels, for EPnP RANSAC.
pub fn pnp_problem() -> (Vec<Vector3<f64>>, Vec<nalgebra::Vector2<f64>>, Vec<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let c = cam();
    let t = Isometry3::from_parts(
        Translation3::new(0.3, -0.2, 0.5),
        UnitQuaternion::from_euler_angles(0.2, -0.3, 0.1),
    );
    let mut pw = Vec::new();
    let mut px = Vec::new();
    for k in 0..150 {
        let u: f64 = rng.random_range(10.0..630.0);
        let v: f64 = rng.random_range(10.0..470.0);
        let z: f64 = rng.random_range(0.8..6.0);
        let xc = Vector3::new((u - c.cx) / c.fx * z, (v - c.cy) / c.fy * z, z);
        pw.push((t.inverse() * Point3::from(xc)).coords);
        px.push(if k % 10 < 3 {
            nalgebra::Vector2::new(rng.random_range(0.0..640.0), rng.random_range(0.0..480.0))
        } else {
            nalgebra::Vector2::new(u + 0.5 * gauss(&mut rng), v + 0.5 * gauss(&mut rng))
        });
    }
    (pw, px, vec![1.0; 150])
}
