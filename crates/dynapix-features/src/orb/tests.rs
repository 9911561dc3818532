//! Tests of the ORB extractor on real TUM frames and generated images.

use super::*;
use crate::keypoint::hamming;
use image::{GrayImage, Luma};
use std::path::PathBuf;

fn data_dir() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data"))
}

/// The `i`-th (sorted) RGB frame of fr1_xyz as gray, or None (with a skip message) when the
/// shared data is not present.
pub(crate) fn fr1_xyz_frame(i: usize) -> Option<GrayImage> {
    let dir = data_dir().join("tum/rgbd_dataset_freiburg1_xyz/rgb");
    let mut files: Vec<PathBuf> = match std::fs::read_dir(&dir) {
        Ok(rd) => rd.filter_map(|e| e.ok().map(|e| e.path())).collect(),
        Err(_) => {
            eprintln!("skipping: {} not found", dir.display());
            return None;
        }
    };
    files.sort();
    let path = files.get(i)?;
    match image::open(path) {
        Ok(img) => Some(rgb_to_gray_orbslam(&img.to_rgb8())),
        Err(e) => {
            eprintln!("skipping: cannot read {}: {e}", path.display());
            None
        }
    }
}

/// A deterministic textured test image (blobs and edges) of the given size.
fn synthetic(w: u32, h: u32, seed: u64) -> GrayImage {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut img = GrayImage::from_pixel(w, h, Luma([100]));
    for _ in 0..400 {
        let (cx, cy) = (rng.random_range(0..w), rng.random_range(0..h));
        let (rw, rh) = (rng.random_range(3..25u32), rng.random_range(3..25u32));
        let v: u8 = rng.random();
        for y in cy..(cy + rh).min(h) {
            for x in cx..(cx + rw).min(w) {
                img.put_pixel(x, y, Luma([v]));
            }
        }
    }
    img
}

#[test]
fn level_budget_follows_geometric_formula() {
    let n = features_per_level(1000, 1.2, 8);
    assert_eq!(n.iter().sum::<usize>(), 1000);
    let s = 1.2f64;
    let n0 = 1000.0 * (1.0 - 1.0 / s) / (1.0 - (1.0 / s).powi(8));
    assert_eq!(n[0], n0.round() as usize);
    #[allow(clippy::needless_range_loop)]
    for l in 1..7 {
        let expect = n0 / s.powi(l as i32);
        assert!(
            (n[l] as f64 - expect).abs() <= 0.5 + 1e-3,
            "level {l}: {}",
            n[l]
        );
    }
    let e = OrbExtractor::default();
    assert_eq!(e.features_per_level(), &n[..]);
    assert!((e.level_sigma2()[3] - 1.2f32.powi(6)).abs() < 1e-4);
    assert!((e.inv_level_sigma2()[2] * e.level_sigma2()[2] - 1.0).abs() < 1e-6);
    assert!((e.scale_factors()[7] - 1.2f32.powi(7)).abs() < 1e-4);
}

#[test]
fn rejects_bad_params() {
    let bad = OrbParams {
        scale_factor: 1.0,
        ..OrbParams::default()
    };
    assert!(OrbExtractor::new(bad).is_err());
    let bad = OrbParams {
        nlevels: 0,
        ..OrbParams::default()
    };
    assert!(OrbExtractor::new(bad).is_err());
}

#[test]
fn umax_matches_symmetric_disk() {
    // Row half-widths of the radius-15 patch after ORB's 90°-symmetrisation.
    let u = circular_umax();
    assert_eq!(u[0], 15);
    assert_eq!(u[15], 3);
    assert!(u.windows(2).all(|w| w[0] >= w[1]));
    // Symmetry: the number of rows with half-width ≥ k equals the half-width of row k.
    for k in 0..=15usize {
        let rows = u.iter().filter(|&&w| w >= k as i32).count() as i32 - 1;
        assert_eq!(rows, u[k], "k={k}");
    }
}

#[test]
fn no_features_on_degenerate_images() {
    let e = OrbExtractor::default();
    for img in [
        GrayImage::new(640, 480),
        GrayImage::from_pixel(640, 480, Luma([128])),
        GrayImage::new(0, 0),
        GrayImage::new(1, 1),
        synthetic(40, 30, 1),
        synthetic(3, 500, 2),
    ] {
        let (k, d) = e.extract(&img);
        assert!(k.is_empty(), "{}x{}", img.width(), img.height());
        assert!(d.is_empty());
    }
    // A small but valid image gives features on level 0 only.
    let (k, d) = e.extract(&synthetic(80, 70, 3));
    assert_eq!(k.len(), d.len());
    assert!(k.iter().all(|kp| kp.octave == 0 || kp.x < 80.0));
}

#[test]
fn extraction_is_deterministic() {
    let img = fr1_xyz_frame(3).unwrap_or_else(|| synthetic(320, 240, 7));
    let e = OrbExtractor::default();
    let a = e.extract(&img);
    let b = e.extract(&img);
    assert!(!a.0.is_empty());
    assert_eq!(a, b);
    // Same result on a single-thread and a three-thread pool.
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap_or_else(|err| panic!("{err}"));
        assert_eq!(pool.install(|| e.extract(&img)), a, "{threads} threads");
    }
}

#[test]
fn real_frame_count_spread_and_levels() {
    let Some(img) = fr1_xyz_frame(0) else { return };
    let e = OrbExtractor::default();
    let (kps, descs) = e.extract(&img);
    assert_eq!(kps.len(), descs.len());
    let n = kps.len();
    let levels: Vec<usize> = (0..8)
        .map(|l| kps.iter().filter(|k| k.octave as usize == l).count())
        .collect();
    eprintln!("fr1_xyz frame 0: {n} keypoints, per level {levels:?}");
    assert!((900..=1150).contains(&n), "got {n} keypoints");

    // Per level: close to the budget (the octree may overshoot by up to 3 per level).
    for (l, &budget) in e.features_per_level().iter().enumerate() {
        let got = kps.iter().filter(|k| k.octave as usize == l).count();
        assert!(
            got as f64 >= 0.85 * budget as f64 && got <= budget + 3,
            "level {l}: {got} vs budget {budget}"
        );
    }
    for k in &kps {
        let s = e.scale_factors()[k.octave as usize];
        assert!(k.x >= 19.0 * s - 1e-3 && k.x < 640.0 && k.y >= 19.0 * s - 1e-3 && k.y < 480.0);
        assert!((0.0..360.0).contains(&k.angle));
        assert_eq!(k.size, (31.0 * s).trunc());
    }

    // Spread: on a 4×3 grid every cell holds keypoints, and the fullest cell holds far fewer
    // than the strongest-response selection would put there.
    let cell = |k: &KeyPoint| ((k.x / 160.0) as usize).min(3) + 4 * ((k.y / 160.0) as usize).min(2);
    let mut hist = [0usize; 12];
    kps.iter().for_each(|k| hist[cell(k)] += 1);
    eprintln!("4x3 grid histogram {hist:?}");
    assert!(hist.iter().all(|&c| c > 0), "{hist:?}");
    assert!(*hist.iter().max().unwrap_or(&0) < n / 4, "{hist:?}");
}

/// Rotating the image by 90° clockwise maps (x, y) → (H−1−y, x) and adds 90° to every angle;
/// descriptors of level-0 keypoints found at corresponding positions stay close.
#[test]
fn rotation_by_90_degrees() {
    let Some(img) = fr1_xyz_frame(10) else { return };
    let rot = image::imageops::rotate90(&img);
    let h = img.height() as f32;
    let e = OrbExtractor::default();
    let (ka, da) = e.extract(&img);
    let (kb, db) = e.extract(&rot);
    let mut dists = Vec::new();
    let mut angle_err = Vec::new();
    for (a, dsa) in ka.iter().zip(&da).filter(|(k, _)| k.octave == 0) {
        let (x, y) = (h - 1.0 - a.y, a.x);
        if let Some((b, dsb)) = kb
            .iter()
            .zip(&db)
            .find(|(b, _)| b.octave == 0 && b.x == x && b.y == y)
        {
            let d = (b.angle - a.angle - 90.0).rem_euclid(360.0);
            angle_err.push(d.min(360.0 - d));
            dists.push(hamming(dsa, dsb));
        }
    }
    assert!(
        dists.len() >= 50,
        "only {} common level-0 keypoints",
        dists.len()
    );
    dists.sort_unstable();
    angle_err.sort_by(|a, b| a.total_cmp(b));
    let median = dists[dists.len() / 2];
    eprintln!(
        "rotation: {} common level-0 keypoints, Hamming median {median}, max {:?}",
        dists.len(),
        dists.last()
    );
    let p90 = dists[dists.len() * 9 / 10];
    assert!(median <= 4 && p90 <= 16, "median {median}, p90 {p90}");
    assert!(angle_err[angle_err.len() / 2] < 0.1, "{angle_err:?}");
    // Unrelated descriptors differ in about half of their 256 bits.
    let unrelated = hamming(&da[0], &db[db.len() / 2]);
    assert!(unrelated > 60, "{unrelated}");
}

#[test]
fn gray_conversions() {
    let mut img = RgbImage::new(2, 1);
    img.put_pixel(0, 0, image::Rgb([255, 0, 0]));
    img.put_pixel(1, 0, image::Rgb([10, 200, 30]));
    let g = rgb_to_gray_orbslam(&img);
    assert_eq!(g.get_pixel(0, 0).0[0], 76); // 0.299 · 255
    assert_eq!(g.get_pixel(1, 0).0[0], 124); // 2.99 + 117.4 + 3.42 = 123.8
    let s = rgb_to_gray(&img, GrayConversion::OrbSlam2Swapped);
    assert_eq!(s.get_pixel(0, 0).0[0], 29); // 0.114 · 255
    assert_eq!(s.get_pixel(1, 0).0[0], 128); // 1.14 + 117.4 + 8.97 = 127.5
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]

    /// Any image size and content: no panic, consistent outputs inside the image.
    #[test]
    fn extract_never_panics(w in 0u32..200, h in 0u32..200, seed in 0u64..1000) {
        let img = if w > 0 && h > 0 { synthetic(w, h, seed) } else { GrayImage::new(w, h) };
        let (k, d) = OrbExtractor::default().extract(&img);
        proptest::prop_assert_eq!(k.len(), d.len());
        for kp in &k {
            proptest::prop_assert!(kp.x >= 0.0 && kp.x < w as f32 && kp.y >= 0.0 && kp.y < h as f32);
        }
    }
}

#[test]
fn grade_setting_3000_features() {
    let Some(img) = fr1_xyz_frame(0) else { return };
    let e = OrbExtractor::new(OrbParams {
        nfeatures: 3000,
        ..OrbParams::default()
    })
    .unwrap_or_else(|err| panic!("{err}"));
    let (k, d) = e.extract(&img);
    let levels: Vec<usize> = (0..8)
        .map(|l| k.iter().filter(|kp| kp.octave as usize == l).count())
        .collect();
    eprintln!(
        "3000-feature setting: {} keypoints, per level {levels:?}",
        k.len()
    );
    assert_eq!(k.len(), d.len());
    assert!(k.len() > 2400 && k.len() <= 3030, "{}", k.len());
}

#[test]
fn cached_fast_corners_give_the_same_features_under_any_mask() {
    let (w, h) = (320u32, 240u32);
    let img = synthetic(w, h, 21);
    let ex = OrbExtractor::default();
    // Movers on the right: only the left 60 % and the top rows are allowed.
    let allowed: Vec<bool> = (0..w * h)
        .map(|k| k % w < w * 3 / 5 || k / w < 40)
        .collect();
    let mask = KeepMask::new(w, h, allowed).unwrap();
    // First pass, unmasked: detects and stores the corners.
    let mut corners = None;
    let first = ex.extract_cached(&img, None, &mut corners);
    assert_eq!(first, ex.extract_where(&img, None));
    let stored = corners.clone().unwrap();
    assert!(stored.len() > first.0.len(), "{} corners", stored.len());
    // A later, masked pass reuses them and gets what detecting afresh gives.
    let masked = ex.extract_cached(&img, Some(&mask), &mut corners);
    let fresh = ex.extract_where(&img, Some(&mask));
    assert_eq!(masked, fresh);
    assert!(!masked.0.is_empty() && masked.0.len() < first.0.len() + 1);
    assert!(std::sync::Arc::ptr_eq(&stored, corners.as_ref().unwrap()));
    // An extractor with other parameters does not take them.
    let other = OrbExtractor::new(OrbParams {
        ini_th_fast: 30,
        ..OrbParams::default()
    })
    .unwrap();
    let mut c2 = corners.clone();
    assert_eq!(
        other.extract_cached(&img, Some(&mask), &mut c2),
        other.extract_where(&img, Some(&mask))
    );
    assert!(!std::sync::Arc::ptr_eq(&stored, c2.as_ref().unwrap()));
}
