//! Depth at the sensor's saturation value is no measurement (issue 36, item 2): ten frames
//! whose depth image holds 65535 everywhere, in a 60-frame synthetic walking sequence
//! (`dynapix-synth`, 320×240, generated here), are read as frames without depth by every
//! consumer, so they no longer poison the motion cues and the weighted passes: the final
//! pass tracks about as well as on the clean sequence, offline and online.
//! Run in release mode (`cargo test --release`).

mod common;
use common::{ate, copy_dir};
use std::path::{Path, PathBuf};

use dynapix::{CameraChoice, Config, Input, OnlineDynaPix, RgbdFrame, Trajectory};
use dynapix::{OfflineRunner, RunOptions};
use dynapix_io::FrameStatus;
use dynapix_synth::{Preset, SceneParams, SynthParams};

const FRAMES: usize = 60;
/// The frames whose depth is replaced by the saturation value.
const SATURATED: [usize; 10] = [10, 14, 18, 22, 26, 30, 34, 38, 42, 46];

/// A clean sequence and a copy with [`SATURATED`] frames at depth 65535.
fn sequences(tmp: &Path) -> (PathBuf, PathBuf) {
    let clean = tmp.join("clean");
    let cam = dynapix_geometry::PinholeCamera::tum_fr3();
    let (s, w, h) = (0.5, 320, 240);
    let camera =
        dynapix_geometry::PinholeCamera::new(w, h, cam.fx * s, cam.fy * s, cam.cx * s, cam.cy * s);
    let p = SynthParams {
        preset: Preset::WalkingXyz,
        frames: FRAMES,
        seed: 0,
        scene: SceneParams::for_width(w),
        camera,
        ..SynthParams::default()
    };
    let seq = dynapix_synth::Sequence::new(p).unwrap();
    dynapix_synth::output::write_sequence(&seq, &clean, None, &mut |_| {}).unwrap();
    let sat = tmp.join("saturated");
    copy_dir(&clean, &sat);
    // A camera gives no background: the cues reconstruct it from the (damaged) frames.
    for d in ["background", "depth_bg"] {
        let _ = std::fs::remove_dir_all(clean.join(d));
        let _ = std::fs::remove_dir_all(sat.join(d));
    }
    let opened = dynapix_io::Sequence::open(&sat).unwrap();
    for &i in &SATURATED {
        let path = &opened.frames[i].depth;
        let (w, h) = dynapix_io::images::image_size(path).unwrap();
        let full = dynapix_io::Gray16Image::from_pixel(w, h, image::Luma([u16::MAX]));
        dynapix_io::images::write_gray16(path, &full).unwrap();
    }
    (clean, sat)
}

/// ATE and tracking rate of the final offline pass, and the frames read with invalid depth.
fn offline(seq: &Path, config: &Config) -> (f64, f64, usize) {
    let input = Input::open(seq, &config.sequence, &CameraChoice::Sequence).unwrap();
    let cache = tempfile::tempdir().unwrap();
    let options = RunOptions {
        cache_dir: Some(cache.path().to_path_buf()),
        ..Default::default()
    };
    let out = OfflineRunner::new(config, &input, options)
        .unwrap()
        .run(&())
        .unwrap();
    let last = out.final_pass().unwrap();
    let tracked = last
        .status
        .iter()
        .filter(|s| s.status == FrameStatus::Tracked)
        .count();
    (
        ate(seq, &last.trajectory),
        tracked as f64 / FRAMES as f64,
        input.sequence.invalid_depth().frames,
    )
}

/// ATE and tracking rate of an online run.
fn online(seq: &Path, config: &Config) -> (f64, f64) {
    let input = Input::open(seq, &config.sequence, &CameraChoice::Sequence).unwrap();
    let mut system = OnlineDynaPix::new(&input.camera, config).unwrap();
    let mut results = Vec::new();
    for i in 0..input.len() {
        let (rgb, depth) = input.load_rgbd(i).unwrap();
        let t = input.sequence.frames[i].t;
        results.extend(system.push(RgbdFrame::new(t, rgb, depth)).unwrap());
    }
    results.extend(system.finish().unwrap());
    let traj = Trajectory::new(
        results
            .iter()
            .filter_map(|r| r.pose_wc.map(|p| dynapix_io::StampedPose::new(r.t, p)))
            .collect(),
    );
    (ate(seq, &traj), traj.poses.len() as f64 / FRAMES as f64)
}

#[test]
fn saturated_depth_is_missing_depth_and_does_not_ruin_tracking() {
    let tmp = tempfile::tempdir().unwrap();
    let (clean, sat) = sequences(tmp.path());
    let config = Config::default();

    let (ate_clean, tr_clean, bad_clean) = offline(&clean, &config);
    let (ate_sat, tr_sat, bad_sat) = offline(&sat, &config);
    eprintln!(
        "offline: clean ATE {ate_clean:.4} m, TR {tr_clean:.2}; saturated ATE {ate_sat:.4} m, \
         TR {tr_sat:.2}"
    );
    assert_eq!(bad_clean, 0);
    assert_eq!(
        bad_sat,
        SATURATED.len(),
        "every saturated frame is reported"
    );
    assert!(tr_sat >= 0.8, "offline tracking rate {tr_sat:.2}");
    assert!(
        ate_sat <= 2.0 * ate_clean.max(0.01),
        "offline ATE {ate_sat:.4} m against {ate_clean:.4} m clean"
    );

    let (ate_clean, tr_clean) = online(&clean, &config);
    let (ate_sat, tr_sat) = online(&sat, &config);
    eprintln!(
        "online: clean ATE {ate_clean:.4} m, TR {tr_clean:.2}; saturated ATE {ate_sat:.4} m, \
         TR {tr_sat:.2}"
    );
    assert!(tr_sat >= 0.8, "online tracking rate {tr_sat:.2}");
    assert!(
        ate_sat <= 2.0 * ate_clean.max(0.01),
        "online ATE {ate_sat:.4} m against {ate_clean:.4} m clean"
    );
}

/// The rule is the reader's: with it (the default) a saturated frame reaches every reader
/// as a frame without depth and is counted once; switched off
/// (`sequence.depth_saturation: null`) the frame reads as a wall at 13.1 m, as before; a
/// smaller `sequence.max_depth` drops farther pixels.
#[test]
fn without_the_rule_the_saturated_frames_are_read_as_depth() {
    let tmp = tempfile::tempdir().unwrap();
    let (_, sat) = sequences(tmp.path());
    let config =
        Config::from_yaml_str("sequence: {depth_saturation: null, max_depth: 20}\n").unwrap();
    let input = Input::open(&sat, &config.sequence, &CameraChoice::Sequence).unwrap();
    let d = input.load_depth(SATURATED[0]).unwrap();
    assert!(d.iter().all(|&z| (z - 65535.0 / 5000.0).abs() < 1e-3));
    assert_eq!(input.sequence.invalid_depth().frames, 0);
    let on = Input::open(&sat, &Config::default().sequence, &CameraChoice::Sequence).unwrap();
    assert!(
        on.load_depth(SATURATED[0])
            .unwrap()
            .iter()
            .all(|&z| z == 0.0)
    );
    let (_, rgb_depth) = on.load_rgbd(SATURATED[1]).unwrap();
    assert!(rgb_depth.iter().all(|&z| z == 0.0));
    assert_eq!(on.sequence.invalid_depth().frames, 2);
    // Depth beyond sequence.max_depth is missing too.
    let near = Config::from_yaml_str("sequence: {max_depth: 2.0}\n").unwrap();
    let input = Input::open(&sat, &near.sequence, &CameraChoice::Sequence).unwrap();
    let d = input.load_depth(0).unwrap();
    assert!(d.iter().all(|&z| z <= 2.0));
    assert!(d.iter().any(|&z| z > 0.0));
}
