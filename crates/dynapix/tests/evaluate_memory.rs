//! `dynapix run` scores its trajectories from memory (`dynapix::evaluate::score_run`) against
//! the ground truth read once with the sequence: on the real sequences of `../shared/data`
//! (Bonn window: marker poses converted; TUM fr1_xyz: camera poses) the figures must be those
//! of the file evaluation of earlier versions (`dynapix_eval::files::evaluate_run`: write `trajectory.txt`,
//! read it and `groundtruth.txt` back), to the last digit. Skips (with the reason) when the
//! data is missing.

use std::path::PathBuf;

use dynapix::{CameraChoice, Config, Input, Trajectory};
use dynapix_io::StampedPose;
use nalgebra::{Translation3, UnitQuaternion, Vector3};

fn sequence(rel: &str) -> Option<PathBuf> {
    let d = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data")).join(rel);
    if d.join("rgb.txt").is_file() {
        Some(d)
    } else {
        eprintln!("skipped: {} is missing (../shared/data)", d.display());
        None
    }
}

/// An estimate of the frames of `input`: the ground truth at every frame time outside a lost
/// stretch (a sixth of the frames, untracked), drifting by a few centimetres and a degree, with digits beyond what the
/// TUM text keeps, in a frame of its own (rotated and shifted: the alignment must undo it).
fn estimate(input: &Input) -> Trajectory {
    let gt = input.sequence.groundtruth.as_ref().expect("ground truth");
    let offset = dynapix_geometry::Se3::from_parts(
        Translation3::new(0.3, -1.2, 0.7),
        UnitQuaternion::from_euler_angles(0.2, -0.4, 1.1),
    );
    let n = input.len();
    let poses = input
        .timestamps()
        .iter()
        .enumerate()
        .filter(|(i, _)| !(n / 3..n / 2).contains(i))
        .filter_map(|(i, &t)| {
            let p = gt.interpolate(t, 0.05)?;
            let k = i as f64;
            let drift = dynapix_geometry::Se3::from_parts(
                Translation3::from(Vector3::new(0.02 * (k * 0.1).sin(), 0.0004 * k, 1e-11 * k)),
                UnitQuaternion::from_euler_angles(0.0, 0.01 * (k * 0.05).cos(), 0.0),
            );
            Some(StampedPose::new(t + 1.7e-8, offset * p * drift))
        })
        .collect();
    Trajectory::new(poses)
}

fn check(rel: &str) {
    let Some(dir) = sequence(rel) else { return };
    let config = Config::default();
    let input = Input::open(&dir, &config.sequence, &CameraChoice::Sequence).unwrap();
    let est = estimate(&input);
    assert!(est.len() > 40, "{rel}: {} poses", est.len());
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("trajectory.txt");
    est.write_tum(&file).unwrap();
    let gt = dynapix_eval::files::read_camera_ground_truth(&dir.join("groundtruth.txt")).unwrap();
    let from_files = dynapix_eval::files::evaluate_run(
        &gt,
        &file,
        Some(&input.timestamps()),
        &dynapix_eval::EvalParams::default(),
    );
    let score = dynapix::evaluate::score_run(&input.sequence, &est, &file)
        .unwrap()
        .expect("the sequence has ground truth");
    let (a, b) = (
        serde_json::to_string(&from_files).unwrap(),
        serde_json::to_string(&score.run).unwrap(),
    );
    assert_eq!(a, b, "{rel}");
    // A real score: the drift shows, the lost stretch is missing.
    let ate = score.run.result.ate_rmse_m.expect("ATE");
    assert!(ate > 0.003 && ate < 0.1, "{rel}: {ate}");
    let tr = score.run.result.tracking_rate.expect("tracking rate");
    assert!(tr > 0.7 && tr < 0.95, "{rel}: {tr}");
    // The evaluation behind it (for the plots) is the one scored.
    let ev = score.evaluation.expect("evaluation");
    assert_eq!(ev.ate.stats.rmse, ate);
}

#[test]
fn bonn_window_scores_from_memory_like_from_files() {
    check("bonn/rgbd_bonn_crowd");
}

#[test]
fn fr1_xyz_scores_from_memory_like_from_files() {
    check("tum/rgbd_dataset_freiburg1_xyz");
}
