//! ORB extraction time per 640×480 fr1_xyz frame (TUM settings), loading the embedded
//! vocabulary, and the BoW transform of one frame's descriptors.
//! Run: `cargo bench -p dynapix-features --bench orb`.

use criterion::{Criterion, criterion_group, criterion_main};
use dynapix_features::orb::{OrbExtractor, rgb_to_gray_orbslam};
use dynapix_features::vocab::Vocabulary;
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

use dynapix_io::usage::cpu_seconds;

fn bench(c: &mut Criterion) {
    let Some(img) = frame() else {
        eprintln!("skipping: ../shared/data fr1_xyz frames not found");
        return;
    };
    let orb = OrbExtractor::default();
    // Load-independent figure: CPU time per extraction over 100 runs.
    if let Some(t0) = cpu_seconds() {
        let wall = std::time::Instant::now();
        let runs = 100;
        for _ in 0..runs {
            black_box(orb.extract(black_box(&img)));
        }
        if let Some(t1) = cpu_seconds() {
            eprintln!(
                "orb_extract CPU time {:.2} ms/frame (all threads), wall {:.2} ms/frame, {} keypoints",
                (t1 - t0) * 1000.0 / runs as f64,
                wall.elapsed().as_secs_f64() * 1000.0 / runs as f64,
                orb.extract(&img).0.len()
            );
        }
    }
    c.bench_function("orb_extract_640x480_fr1_xyz", |b| {
        b.iter(|| black_box(orb.extract(black_box(&img))))
    });
    // A later pass over the same frame: the FAST corners of the first pass are reused.
    let mut corners = None;
    black_box(orb.extract_cached(&img, None, &mut corners));
    c.bench_function("orb_extract_640x480_fr1_xyz_corners_reused", |b| {
        b.iter(|| black_box(orb.extract_cached(black_box(&img), None, &mut corners)))
    });
    c.bench_function("orb_fast_corners_640x480_fr1_xyz", |b| {
        b.iter(|| black_box(orb.detect_corners(black_box(&img))))
    });
    c.bench_function("vocab_load_embedded_default", |b| {
        b.iter(|| black_box(Vocabulary::embedded_default().ok()))
    });
    let Ok(voc) = Vocabulary::embedded_default() else {
        eprintln!("embedded vocabulary does not load");
        return;
    };
    let (_, descs) = orb.extract(&img);
    c.bench_function("vocab_transform_1000_descriptors", |b| {
        b.iter(|| black_box(voc.transform(black_box(&descs))))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
