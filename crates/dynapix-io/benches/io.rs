//! Throughput of the dynapix-io readers and writers: trajectory text, association, frame
//! loading and probability-map writing. Run: `cargo bench -p dynapix-io --bench io`.

use std::hint::black_box;
use std::path::{Path, PathBuf};

use criterion::{Criterion, criterion_group, criterion_main};
use dynapix_geometry::Se3;
use dynapix_io::images::ProbMap;
use dynapix_io::weights;
use dynapix_io::{Sequence, StampedPose, Trajectory, associate};
use image::Luma;
use nalgebra::Vector3;

fn trajectory(n: usize) -> Trajectory {
    Trajectory::new(
        (0..n)
            .map(|i| {
                let t = 1_305_031_102.0 + i as f64 / 30.0;
                let x = i as f64 * 1e-3;
                StampedPose::new(
                    t,
                    Se3::new(Vector3::new(x, -x, 0.5 * x), Vector3::new(0.1, x, 0.2)),
                )
            })
            .collect(),
    )
}

fn bench_trajectory(c: &mut Criterion) {
    let traj = trajectory(100_000);
    let text = traj.to_tum_string();
    c.bench_function("tum_parse_100k_poses", |b| {
        b.iter(|| Trajectory::parse_tum(black_box(&text), Path::new("bench")).unwrap())
    });
    c.bench_function("tum_format_100k_poses", |b| {
        b.iter(|| black_box(&traj).to_tum_string())
    });
    c.bench_function("slerp_interpolate_100k_queries", |b| {
        b.iter(|| {
            let mut n = 0usize;
            for i in 0..100_000 {
                let t = 1_305_031_102.0 + (i as f64 + 0.5) / 30.0;
                n += traj.interpolate(black_box(t), 0.05).is_some() as usize;
            }
            n
        })
    });
}

fn bench_associate(c: &mut Criterion) {
    // Two jittered 30 Hz streams of 100 000 stamps each.
    let a: Vec<f64> = (0..100_000).map(|i| i as f64 / 30.0).collect();
    let b: Vec<f64> = (0..100_000)
        .map(|i| i as f64 / 30.0 + 0.004 * ((i % 7) as f64 - 3.0))
        .collect();
    c.bench_function("associate_100k_x_100k", |bch| {
        bch.iter(|| associate(black_box(&a), black_box(&b), 0.0, 0.02))
    });
}

fn bench_frames(c: &mut Criterion) {
    let dir = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/tum/rgbd_dataset_freiburg1_xyz"
    ));
    if dir.is_dir() {
        let seq = Sequence::open(&dir).unwrap();
        c.bench_function("sequence_open_fr1_xyz_300", |b| {
            b.iter(|| Sequence::open(&dir).unwrap())
        });
        c.bench_function("load_frame_640x480_rgb_depth", |b| {
            b.iter(|| seq.load_frame(black_box(10)).unwrap())
        });
    } else {
        eprintln!("skipped frame benches: {} not found", dir.display());
    }
    let tmp = tempfile::tempdir().unwrap();
    let prob = ProbMap::from_fn(640, 480, |x, y| {
        Luma([((x * 7 + y * 3) % 1000) as f32 / 1000.0])
    });
    let png = tmp.path().join("p.png");
    let pfm = tmp.path().join("p.pfm");
    c.bench_function("write_prob_png_640x480", |b| {
        b.iter(|| weights::write_prob_png(&png, &prob).unwrap())
    });
    c.bench_function("write_prob_pfm_640x480", |b| {
        b.iter(|| weights::write_prob_pfm(&pfm, &prob).unwrap())
    });
    c.bench_function("read_prob_png_640x480", |b| {
        b.iter(|| weights::read_prob_png(&png).unwrap())
    });
    c.bench_function("read_prob_pfm_640x480", |b| {
        b.iter(|| weights::read_prob_pfm(&pfm).unwrap())
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench_trajectory, bench_associate, bench_frames
}
criterion_main!(benches);
