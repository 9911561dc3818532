//! Criterion benchmarks of the solvers on synthetic problems of tracking / local-BA size:
//! pose-only optimisation with 300 edges, local BA with 10 keyframes, 2000 points and 10000
//! edges (1 px noise, 5 % gross outliers, a quarter of the edges mono).

mod common;

use common::{ba_problem, pose_problem};
use criterion::{Criterion, criterion_group, criterion_main};
use dynapix_optim::{BaParams, PoseOnlyParams, bundle_adjust, optimize_pose};
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
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
