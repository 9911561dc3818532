//! Golden tests on real data (`../shared/data`, see its README): the ATE RMSE and pair counts
//! that the TUM benchmark tool reported for published trajectories must be reproduced to
//! 1e-6 m, and removing frames from a real trajectory must give the exact missing time.

use dynapix_eval::files::{read_reference_stamps, read_trajectory};
use dynapix_eval::{AteParams, TrackingParams, ate, tracking_rate};
use std::path::PathBuf;

fn data_dir() -> Option<PathBuf> {
    let d = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data"));
    if d.is_dir() {
        Some(d)
    } else {
        eprintln!(
            "skipped: {} not found (real data is not available)",
            d.display()
        );
        None
    }
}

/// Reads `compared_pose_pairs N` and `absolute_translational_error.rmse X` of a TUM report.
fn reported(path: &std::path::Path) -> (usize, f64) {
    let text = std::fs::read_to_string(path).expect("report readable");
    let mut pairs = None;
    let mut rmse = None;
    for line in text.lines() {
        let f: Vec<&str> = line.split_whitespace().collect();
        match f.as_slice() {
            ["compared_pose_pairs", n, ..] => pairs = n.parse().ok(),
            ["absolute_translational_error.rmse", x, ..] => rmse = x.parse().ok(),
            _ => {}
        }
    }
    (
        pairs.expect("pairs in report"),
        rmse.expect("rmse in report"),
    )
}

fn check(gt: PathBuf, est: PathBuf, pairs: usize, rmse: f64) {
    let g = read_trajectory(&gt).expect("gt");
    let e = read_trajectory(&est).expect("est");
    let r = ate(&g, &e, &AteParams::default()).expect("ate");
    println!(
        "{}: rmse {:.9} (expected {rmse}), pairs {} (expected {pairs})",
        est.display(),
        r.stats.rmse,
        r.stats.count
    );
    assert_eq!(r.stats.count, pairs, "{}", est.display());
    assert!(
        (r.stats.rmse - rmse).abs() <= 1e-6,
        "{}: {} vs {}",
        est.display(),
        r.stats.rmse,
        rmse
    );
    // The TUM tool prints "%f": the 6-decimal rounding must be the reported figure.
    assert_eq!(format!("{:.6}", r.stats.rmse), format!("{rmse:.6}"));
}

#[test]
fn dynaslam_walking_sequences_match_reported_ate() {
    let Some(d) = data_dir() else { return };
    let cases = [
        ("walking_xyz", "walk_xyz", 757, 0.016314),
        ("walking_static", "walk_static", 314, 0.007244),
        ("walking_rpy", "walk_rpy", 783, 0.038196),
        ("walking_halfsphere", "walk_halfsphere", 1018, 0.028747),
    ];
    for (seq, short, pairs, rmse) in cases {
        let gt = d.join(format!(
            "tum-walking-meta/rgbd_dataset_freiburg3_{seq}/groundtruth.txt"
        ));
        let est = d.join(format!(
            "reference-trajectories/dynaslam_rerun_yubaoliu/fr3_{short}_CameraTrajectory.txt"
        ));
        let report = d.join(format!(
            "reference-trajectories/dynaslam_rerun_yubaoliu/fr3_{short}_ate_reported.txt"
        ));
        // The brief's numbers and the shipped reports must agree too.
        assert_eq!(reported(&report), (pairs, rmse));
        check(gt, est, pairs, rmse);
    }
}

#[test]
fn rgbdslam_fr1_xyz_matches_reported_ate() {
    let Some(d) = data_dir() else { return };
    let e = d.join("reference-trajectories/evo_testdata");
    check(
        e.join("freiburg1_xyz-groundtruth.txt"),
        e.join("freiburg1_xyz-rgbdslam.txt"),
        786,
        0.013473,
    );
}

#[test]
fn removing_frames_gives_the_exact_missing_time() {
    let Some(d) = data_dir() else { return };
    let seq = d.join("tum-walking-meta/rgbd_dataset_freiburg3_walking_xyz");
    let reference = read_reference_stamps(&seq.join("associations.txt")).expect("assoc");
    let gt = read_trajectory(&seq.join("groundtruth.txt")).expect("gt");
    let (g0, g1) = (gt[0].0, gt[gt.len() - 1].0);
    let inside: Vec<f64> = reference
        .iter()
        .copied()
        .filter(|t| *t >= g0 && *t <= g1)
        .collect();
    assert!(inside.len() > 100);
    // A trajectory with a pose at every reference frame except: the first 5 frames (not
    // initialised), frames 100..110 (lost), frame 300 (a single drop) and the last frame.
    let n = inside.len();
    let removed = |k: usize| k < 5 || (100..110).contains(&k) || k == 300 || k == n - 1;
    // Write stamps with 6 decimals and re-read them, as a SLAM system's file would be.
    let est: Vec<f64> = (0..n)
        .filter(|&k| !removed(k))
        .map(|k| format!("{:.6}", inside[k]).parse().expect("number"))
        .collect();
    let expected = (inside[5] - inside[0])
        + (inside[110] - inside[99])
        + (inside[301] - inside[299])
        + (inside[n - 1] - inside[n - 2]);
    let p = TrackingParams {
        window: Some((g0, g1)),
        ..TrackingParams::default()
    };
    let r = tracking_rate(&reference, &est, &p).expect("tr");
    println!(
        "missing {:.6} s of {:.6} s, TR {:.6}",
        r.missing_time_s, r.duration_s, r.tracking_rate
    );
    assert!((r.missing_time_s - expected).abs() < 1e-9);
    assert_eq!(r.missing_frames, 5 + 10 + 1 + 1);
    assert!((r.duration_s - (inside[n - 1] - inside[0])).abs() < 1e-9);
    assert!((r.tracking_rate - (1.0 - expected / r.duration_s)).abs() < 1e-12);
}
