//! Depth limits per camera (issue 36, item 2): a sequence's `camera.yaml` may state the
//! camera's saturation value (`depth_saturation`) and largest plausible depth
//! (`depth_max_m`); a run's configuration overrides them only where it sets
//! `sequence.depth_saturation` / `sequence.max_depth`, and the run records the values used
//! and where they came from.

use std::path::{Path, PathBuf};

use dynapix::{CameraChoice, Config, Input};
use dynapix_synth::{Preset, SceneParams, SynthParams};

/// A 3-frame synthetic walking sequence at 160×120 (with its `camera.yaml`).
fn sequence(tmp: &Path) -> PathBuf {
    let dir = tmp.join("seq");
    let cam = dynapix_geometry::PinholeCamera::tum_fr3();
    let s = 0.25;
    let camera = dynapix_geometry::PinholeCamera::new(
        160,
        120,
        cam.fx * s,
        cam.fy * s,
        cam.cx * s,
        cam.cy * s,
    );
    let p = SynthParams {
        preset: Preset::WalkingXyz,
        frames: 3,
        seed: 0,
        scene: SceneParams::for_width(160),
        camera,
        ..SynthParams::default()
    };
    let seq = dynapix_synth::Sequence::new(p).unwrap();
    dynapix_synth::output::write_sequence(&seq, &dir, None, &mut |_| {}).unwrap();
    dir
}

/// Appends `lines` to the sequence's `camera.yaml`.
fn add_to_camera(dir: &Path, lines: &str) {
    let f = dir.join("camera.yaml");
    let mut text = std::fs::read_to_string(&f).unwrap();
    text.push_str(lines);
    std::fs::write(&f, text).unwrap();
}

fn open(dir: &Path, config: &str) -> dynapix::Result<Input> {
    let c = Config::from_yaml_str(config).unwrap();
    Input::open(dir, &c.sequence, &CameraChoice::Sequence)
}

fn farthest(input: &Input) -> f32 {
    input
        .load_depth(0)
        .unwrap()
        .iter()
        .copied()
        .fold(0.0, f32::max)
}

#[test]
fn the_cameras_limits_apply_and_the_configuration_overrides_them_key_by_key() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = sequence(tmp.path());
    let plain = open(&dir, "{}").unwrap();
    let far = farthest(&plain);
    let rec = plain.record().depth_validity.unwrap();
    assert_eq!((rec.saturation, rec.max_depth_m), (Some(65535), 20.0));
    assert_eq!(
        (&*rec.saturation_from, &*rec.max_depth_from),
        ("default", "default")
    );
    // The synthetic room is deeper than 2 m: a camera that measures to 2 m loses those pixels.
    assert!(far > 3.0, "farthest depth {far}");
    add_to_camera(&dir, "depth_max_m: 2.0\ndepth_saturation: 4000\n");
    let near = open(&dir, "{}").unwrap();
    let d = near.load_depth(0).unwrap();
    assert!(d.iter().all(|&z| z <= 2.0) && d.iter().any(|&z| z > 0.0));
    assert!(near.sequence.invalid_depth().pixels > 0);
    let rec = near.record().depth_validity.unwrap();
    assert_eq!((rec.saturation, rec.max_depth_m), (Some(4000), 2.0));
    assert_eq!(
        (&*rec.saturation_from, &*rec.max_depth_from),
        ("camera", "camera")
    );
    // The configuration wins where it sets a limit, the camera keeps the other.
    let over = open(&dir, "sequence: {max_depth: 3.0}\n").unwrap();
    let d = over.load_depth(0).unwrap();
    assert!(d.iter().all(|&z| z <= 3.0) && d.iter().any(|&z| z > 2.0));
    let rec = over.record().depth_validity.unwrap();
    assert_eq!((rec.saturation, rec.max_depth_m), (Some(4000), 3.0));
    assert_eq!(
        (&*rec.saturation_from, &*rec.max_depth_from),
        ("camera", "config")
    );
    let off = open(&dir, "sequence: {depth_saturation: null}\n").unwrap();
    let rec = off.record().depth_validity.unwrap();
    assert_eq!((rec.saturation, rec.max_depth_m), (None, 2.0));
    assert_eq!(&*rec.saturation_from, "config");
    // "camera" is the default and may be written out.
    let same = open(
        &dir,
        "sequence: {max_depth: camera, depth_saturation: camera}\n",
    )
    .unwrap();
    assert_eq!(same.record().depth_validity, near.record().depth_validity);
    // The run's configuration keeps "camera" (what run.json shows).
    let c = Config::from_yaml_str("{}").unwrap().to_json_value();
    assert_eq!(c["sequence"]["max_depth"], "camera");
}

#[test]
fn a_bad_limit_in_camera_yaml_is_refused_naming_the_file_and_the_key() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = sequence(tmp.path());
    let good = std::fs::read_to_string(dir.join("camera.yaml")).unwrap();
    for (bad, key) in [
        ("depth_max_m: -1.0\n", "depth_max_m"),
        ("depth_saturation: 70000\n", "depth_saturation"),
        ("depth_max_m: far\n", "depth_max_m"),
    ] {
        std::fs::write(dir.join("camera.yaml"), format!("{good}{bad}")).unwrap();
        let e = open(&dir, "{}").unwrap_err().to_string();
        assert!(
            e.contains(&dir.join("camera.yaml").display().to_string()) && e.contains(key),
            "{bad}: {e}"
        );
    }
    // A bad value in the configuration names its key too.
    let e = Config::from_yaml_str("sequence: {max_depth: -1}\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("max_depth"), "{e}");
}
