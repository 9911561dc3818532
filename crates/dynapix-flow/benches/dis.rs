//! DIS on a real 640×480 pair (two consecutive TUM fr1_xyz frames; a synthetic textured pair
//! when the data is missing), every preset.
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
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
