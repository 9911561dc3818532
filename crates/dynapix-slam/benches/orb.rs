//! ORB extraction time per 640×480 fr1_xyz frame (TUM settings), and vocabulary transform time.
//! Run: `cargo bench -p dynapix-slam --bench orb`.

use criterion::{Criterion, criterion_group, criterion_main};
use dynapix_slam::orb::{OrbExtractor, rgb_to_gray_orbslam};
use std::hint::black_box;
use std::path::PathBuf;

fn frame() -> Option<image::GrayImage> {
    let dir = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/tum/rgbd_dataset_freiburg1_xyz/rgb"
    ));
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    files.sort();
    let img = image::open(files.first()?).ok()?;
    Some(rgb_to_gray_orbslam(&img.to_rgb8()))
}

fn bench(c: &mut Criterion) {
    let Some(img) = frame() else {
        eprintln!("skipping: ../shared/data fr1_xyz frames not found");
        return;
    };
    let orb = OrbExtractor::default();
    c.bench_function("orb_extract_640x480_fr1_xyz", |b| {
        b.iter(|| black_box(orb.extract(black_box(&img))))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
