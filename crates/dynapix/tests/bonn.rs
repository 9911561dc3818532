//! DynaPix on real people: the 150-frame window of Bonn RGB-D Dynamic `crowd` in
//! `../shared/data/bonn/rgbd_bonn_crowd` (read its README entry), in process, with no ground
//! truth at run time. The default DynaPix must score at most half the motionless floor (the
//! ATE of a camera that never moves, on the same frames) and at most 0.3× ORB-SLAM2 mode,
//! with every frame tracked. Skips (with the reason) when the data is missing. Heavy: run in
//! release mode (`cargo test --release`).

use std::path::{Path, PathBuf};

use dynapix::{CameraChoice, Config, Input, Method, Trajectory};
use dynapix::{OfflineRunner, RunOptions};

fn window() -> Option<PathBuf> {
    let d = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/bonn/rgbd_bonn_crowd"
    ));
    if d.join("rgb.txt").is_file() {
        Some(d)
    } else {
        eprintln!(
            "skipped: {} is missing (the Bonn window of ../shared/data)",
            d.display()
        );
        None
    }
}

/// (ATE RMSE, motionless floor) against the camera poses of the Bonn ground truth (marker
/// poses converted).
fn ate(seq: &Path, traj: &Trajectory) -> (f64, f64) {
    let gt = dynapix_eval::files::read_camera_ground_truth(&seq.join("groundtruth.txt")).unwrap();
    let est: Vec<_> = traj.poses.iter().map(|p| (p.t, p.pose)).collect();
    let ev = dynapix_eval::evaluate(&gt, &est, None, &dynapix_eval::EvalParams::default()).unwrap();
    (ev.ate.stats.rmse, ev.motionless_floor())
}

#[test]
fn dynapix_on_the_bonn_window_is_far_below_the_floor_and_orbslam2() {
    if cfg!(debug_assertions) {
        eprintln!("skipped: heavy real-data test, run with --release");
        return;
    }
    let Some(seq) = window() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let options = RunOptions {
        cache_dir: Some(tmp.path().join("cache")),
        ..Default::default()
    };
    let run = |config: &Config| {
        let input = Input::open(&seq, &config.sequence, &CameraChoice::Sequence).unwrap();
        OfflineRunner::new(config, &input, options.clone())
            .unwrap()
            .run(&())
            .unwrap()
    };
    let orb = run(&Config::default().with_method(Method::Orbslam2));
    let dpx = run(&Config::default());
    let orb_pass = orb.final_pass().unwrap();
    let dpx_pass = dpx.final_pass().unwrap();
    let (a_orb, floor) = ate(&seq, &orb_pass.trajectory);
    let (a_dpx, _) = ate(&seq, &dpx_pass.trajectory);
    let first = dpx.first_pass.as_ref().unwrap();
    let (a_first, _) = ate(&seq, &first.trajectory);
    eprintln!(
        "Bonn window: floor {floor:.4} m, orbslam2 {a_orb:.4} m, dynapix first pass \
         {a_first:.4} m, final {a_dpx:.4} m ({} of {} frames tracked)",
        dpx_pass.stats.tracked, dpx_pass.stats.frames
    );
    assert_eq!(dpx.record.ground_truth_used_at_run_time, Some(false));
    assert_eq!(
        dpx_pass.stats.tracked, dpx_pass.stats.frames,
        "TR must be 1"
    );
    assert!(
        a_dpx <= 0.5 * floor,
        "dynapix {a_dpx:.4} m is not below half the motionless floor {floor:.4} m"
    );
    assert!(
        a_dpx <= 0.3 * a_orb,
        "dynapix {a_dpx:.4} m is not below 0.3 × orbslam2 {a_orb:.4} m"
    );
}
