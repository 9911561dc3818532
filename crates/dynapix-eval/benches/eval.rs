//! Evaluation speed on a 100 000-pose trajectory (about 55 min at 30 Hz): association,
//! Horn alignment and ATE statistics, plus the tracking rate against 100 000 reference
//! stamps. Ground truth at 100 Hz (300 000 poses), estimate at 30 Hz with noise and a few
//! lost stretches. Run: `cargo bench -p dynapix-eval --bench eval`.

use criterion::{Criterion, criterion_group, criterion_main};
use dynapix_eval::{AteParams, TrackingParams, ate, tracking_rate};
use dynapix_geometry::{Se3, se3};
use nalgebra::Vector6;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

fn pose_at(t: f64) -> Se3 {
    se3::exp(&Vector6::new(
        0.3 * (0.1 * t).sin(),
        0.2 * (0.07 * t).cos(),
        0.05 * t,
        2.0 * (0.05 * t).sin(),
        1.5 * (0.03 * t).cos(),
        0.3 * (0.2 * t).sin(),
    ))
}

type Stamped = Vec<(f64, Se3)>;

/// Ground truth, estimate and reference stamps.
fn data() -> (Stamped, Stamped, Vec<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let t0 = 1.3e9;
    let gt: Vec<_> = (0..300_000)
        .map(|k| {
            let t = k as f64 * 0.01;
            (t0 + t, pose_at(t))
        })
        .collect();
    let reference: Vec<f64> = (0..100_000).map(|k| t0 + k as f64 / 30.0 + 0.002).collect();
    let world = se3::exp(&Vector6::new(0.1, -0.2, 0.3, 1.0, 2.0, 3.0));
    let est: Vec<_> = reference
        .iter()
        .enumerate()
        .filter(|(k, _)| k % 5000 >= 30)
        .map(|(_, &t)| {
            let mut p = world * pose_at(t - t0);
            p.translation.vector += nalgebra::Vector3::new(
                rng.random_range(-0.01..0.01),
                rng.random_range(-0.01..0.01),
                rng.random_range(-0.01..0.01),
            );
            (t, p)
        })
        .collect();
    (gt, est, reference)
}

fn bench(c: &mut Criterion) {
    let (gt, est, reference) = data();
    let mut g = c.benchmark_group("eval_100k");
    g.sample_size(10);
    g.bench_function("ate_assoc_align_stats", |b| {
        b.iter(|| {
            let r = ate(black_box(&gt), black_box(&est), &AteParams::default());
            black_box(r.map(|r| r.stats.rmse).unwrap_or(f64::NAN))
        })
    });
    let est_t: Vec<f64> = est.iter().map(|p| p.0).collect();
    let gt_t: Vec<f64> = gt.iter().map(|p| p.0).collect();
    g.bench_function("associate_only", |b| {
        b.iter(|| {
            black_box(
                dynapix_eval::associate(
                    black_box(&gt_t),
                    black_box(&est_t),
                    &dynapix_eval::AssocParams::default(),
                )
                .len(),
            )
        })
    });
    g.bench_function("tracking_rate", |b| {
        b.iter(|| {
            let r = tracking_rate(
                black_box(&reference),
                black_box(&est_t),
                &TrackingParams::default(),
            );
            black_box(r.map(|r| r.tracking_rate).unwrap_or(f64::NAN))
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
