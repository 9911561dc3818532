//! Criterion benchmarks of the solvers on synthetic problems of tracking / local-BA size:
//! pose-only optimisation with 300 edges, local BA with 10 keyframes, 2000 points and 10000
//! edges (1 px noise, 5 % gross outliers, a quarter of the edges mono).

mod common;

use common::{ba_problem, ba_problem_sized, pnp_problem, pose_graph_problem, pose_problem};
use criterion::{Criterion, criterion_group, criterion_main};
use dynapix_geometry::PinholeCamera;
use dynapix_geometry::pnp::{PnpRansac, PnpRansacParams};
use dynapix_optim::{
    BaParams, PoseGraphParams, PoseOnlyParams, bundle_adjust, optimize_pose, optimize_pose_graph,
};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let p = pose_problem();
    let params = PoseOnlyParams::default();
    c.bench_function("pose_only_300_edges", |b| {
        b.iter(|| optimize_pose(black_box(&p), black_box(&params)))
    });
    let ba = ba_problem();
    let params = BaParams::default();
    let mut group = c.benchmark_group("local_ba");
    group.sample_size(20);
    group.bench_function("10_poses_2000_points_10000_edges", |b| {
        b.iter(|| bundle_adjust(black_box(&ba), black_box(&params)))
    });
    // The size of ORB-SLAM2 mode's local BAs on synthetic walking_xyz 640×480 (≈ 20 free
    // keyframes, ≈ 32 000 edges).
    let big = ba_problem_sized(22, 4000, 8);
    group.bench_function("22_poses_4000_points_32000_edges", |b| {
        b.iter(|| bundle_adjust(black_box(&big), black_box(&params)))
    });
    group.finish();

    let (poses, fixed, edges) = pose_graph_problem();
    let pg = PoseGraphParams::default();
    let mut group = c.benchmark_group("pose_graph");
    group.sample_size(10);
    group.bench_function("200_poses_399_edges", |b| {
        b.iter(|| optimize_pose_graph(black_box(&poses), &fixed, black_box(&edges), &pg))
    });
    group.finish();

    let (pw, px, s2) = pnp_problem();
    let cam = PinholeCamera::new(640, 480, 535.4, 539.2, 320.1, 247.6);
    let rp = PnpRansacParams::default();
    c.bench_function("epnp_ransac_150_points_30pct_outliers", |b| {
        b.iter(|| {
            PnpRansac::new(black_box(&pw), black_box(&px), &s2, &cam, &rp)
                .ok()
                .and_then(|mut r| r.solve())
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
