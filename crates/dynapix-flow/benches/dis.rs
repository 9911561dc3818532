//! DIS on a real 640×480 pair (two consecutive TUM fr1_xyz frames; a synthetic textured pair
//! when the data is missing), every preset, and the rigidity cue's flow (medium at 160 px).
//!
//! `cargo bench -p dynapix-flow --bench dis`

use criterion::{Criterion, criterion_group, criterion_main};
use dynapix_flow::{DisFlow, FlowProvider, Preset, pairs};
use std::hint::black_box;

fn load_pair() -> (image::GrayImage, image::GrayImage) {
    let dir = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/tum/rgbd_dataset_freiburg1_xyz/rgb"
    );
    let frames = std::fs::read_dir(dir).ok().map(|rd| {
        let mut v: Vec<_> = rd
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "png"))
            .collect();
        v.sort();
        v
    });
    if let Some(f) = frames.filter(|f| f.len() >= 2)
        && let (Ok(a), Ok(b)) = (image::open(&f[0]), image::open(&f[1]))
    {
        return (a.to_luma8(), b.to_luma8());
    }
    eprintln!("TUM frames not found at {dir}: benchmarking a synthetic pair");
    let b = pairs::texture(640, 480);
    let a = pairs::make_a(&b, &pairs::smooth_nonrigid(640, 480, 4.0)).unwrap_or_else(|_| b.clone());
    (a, b)
}

fn bench(c: &mut Criterion) {
    let (a, b) = load_pair();
    let mut g = c.benchmark_group("dis_640x480");
    g.sample_size(30);
    for (name, preset) in [
        ("medium", Preset::Medium),
        ("fast", Preset::Fast),
        ("ultrafast", Preset::Ultrafast),
    ] {
        let dis = DisFlow::with_preset(preset);
        g.bench_function(name, |bench| {
            bench.iter(|| dis.flow(black_box(&a), black_box(&b)))
        });
    }
    // The rigidity cue's flow: medium stopped at the 160-pixel-wide level (its working width
    // on 640×480), on the default pool and on one thread (its CPU cost per call).
    let mut p = dynapix_flow::DisParams::preset(Preset::Medium);
    p.finest_scale = 2;
    let dis = DisFlow::new(p);
    g.bench_function("medium_160", |bench| {
        bench.iter(|| dis.flow(black_box(&a), black_box(&b)))
    });
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a one-thread pool");
    g.bench_function("medium_160_one_thread", |bench| {
        bench.iter(|| one.install(|| dis.flow(black_box(&a), black_box(&b))))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
