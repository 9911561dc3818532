//! DynaPix against ORB-SLAM2 mode on a hard scene of issue 33, end to end in process: the
//! synthetic `crowd` (six people 1–3 m from the camera, over half of the image moving in many
//! frames) rendered small, camera-only (no `background/`, `depth_bg/`, `mask/`, `instance/`),
//! both methods run offline with the default configuration. DynaPix must keep tracking every
//! frame and beat its baseline by a ratio. Run in release mode (`cargo test --release`).

use std::path::{Path, PathBuf};

use dynapix::{CameraChoice, Config, Input, Method, OfflineRunner, RunOptions, Trajectory};
use dynapix_synth::{Preset, SceneParams, SynthParams};

/// Frames of the test sequence (30 Hz): the whole preset. Cut to 150 frames the scene is not
/// hard enough to separate the methods (seed 0: DynaPix 0.1092 m, ORB-SLAM2 mode 0.1734 m).
const FRAMES: usize = 300;

/// The largest DynaPix / ORB-SLAM2 ATE ratio accepted. Measured with `dynapix synth --preset
/// crowd --width 320 --height 240 --seed S` (background/ depth_bg/ mask/ instance/ removed) and
/// `dynapix run --method orbslam2|dynapix`, main build `dbbec5f`, 2026-12-06 09:56–10:20 UTC:
/// seed 0: 0.0382 / 0.3492 m (ratio 0.109), seed 1: 0.0205 / 0.2142 (0.096), seed 2:
/// 0.0199 / 0.3525 (0.056), all tracking rate 1.00. The bound leaves 2.7× above the worst
/// seed, as one run can move by up to 2× when the maps change imperceptibly (issue 33).
/// Cost: about 46 s of CPU (render 12.6 s, ORB-SLAM2 mode 4.7 s, DynaPix 28.5 s user time).
const MAX_RATIO: f64 = 0.3;

/// Renders `crowd` at 320×240 (the `dynapix synth --preset crowd --width 320 --height 240`
/// sequence, cut to `FRAMES`) into `into` and removes what a camera does not give.
fn camera_only_crowd(into: &Path, seed: u64) -> PathBuf {
    let dir = into.join("crowd");
    let camera = dynapix_geometry::PinholeCamera::tum_fr3().resized(320, 240);
    let p = SynthParams {
        preset: Preset::Crowd,
        frames: FRAMES,
        seed,
        scene: SceneParams::for_width(camera.width),
        camera,
        ..SynthParams::default()
    };
    let seq = dynapix_synth::Sequence::new(p).unwrap();
    dynapix_synth::output::write_sequence(&seq, &dir, None, &mut |_| {}).unwrap();
    for d in ["background", "depth_bg", "mask", "instance"] {
        let sub = dir.join(d);
        if sub.exists() {
            std::fs::remove_dir_all(sub).unwrap();
        }
    }
    dir
}

/// ATE RMSE of `traj` against the sequence's `groundtruth.txt`.
fn ate(seq: &Path, traj: &Trajectory) -> f64 {
    let gt = dynapix_eval::files::read_trajectory(&seq.join("groundtruth.txt")).unwrap();
    let est: Vec<_> = traj.poses.iter().map(|p| (p.t, p.pose)).collect();
    let ev = dynapix_eval::evaluate(&gt, &est, None, &dynapix_eval::EvalParams::default()).unwrap();
    ev.ate.stats.rmse
}

/// ATE and tracked frames of one offline run with `config`.
fn run(config: &Config, seq: &Path, cache: &Path) -> (f64, usize) {
    let input = Input::open(seq, &config.sequence, &CameraChoice::Sequence).unwrap();
    let options = RunOptions {
        cache_dir: Some(cache.to_path_buf()),
        ..Default::default()
    };
    let out = OfflineRunner::new(config, &input, options)
        .unwrap()
        .run(&())
        .unwrap();
    let last = out.final_pass().unwrap();
    (ate(seq, &last.trajectory), last.stats.tracked)
}

#[test]
fn dynapix_beats_orbslam2_mode_on_a_camera_only_crowd_by_a_ratio() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = camera_only_crowd(tmp.path(), 0);
    for d in ["background", "depth_bg", "mask", "instance"] {
        assert!(!seq.join(d).exists(), "{d}/ must not reach the run");
    }
    let cache = tmp.path().join("cache");
    let (a_orb, _) = run(
        &Config::default().with_method(Method::Orbslam2),
        &seq,
        &cache,
    );
    let (a_dpx, tracked) = run(&Config::default(), &seq, &cache);
    let ratio = a_dpx / a_orb;
    eprintln!(
        "crowd 320×240 seed 0, {FRAMES} frames: ORB-SLAM2 mode {a_orb:.4} m, DynaPix {a_dpx:.4} m (ratio {ratio:.3}), {tracked} frames tracked"
    );
    // Tracking rate ≥ 0.99.
    assert!(
        tracked as f64 >= 0.99 * FRAMES as f64,
        "DynaPix tracked {tracked} of {FRAMES} frames"
    );
    assert!(
        ratio <= MAX_RATIO,
        "DynaPix {a_dpx:.4} m against ORB-SLAM2 mode {a_orb:.4} m: ratio {ratio:.3} > {MAX_RATIO}"
    );
}
