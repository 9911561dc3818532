//! Unit tests of the crate's internal stages on a small synthetic walking sequence
//! (`dynapix-synth`, 320×240, generated once): the geometric cue over a window of depths and
//! the rigidity cue's shared pairs. Run in release mode (`cargo test --release`).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use dynapix_synth::{Preset, SceneParams, SynthParams};

use crate::cues::{GeometricInput, RigidityJob};
use crate::poses::{FramePoses, PoseOrigin};
use crate::store::{CacheCheck, MapFolder};
use crate::{CameraChoice, Config, FlowPreset, Input, OfflineRunner, RunOptions};

const FRAMES: usize = 120;

/// The sequence, generated once per test binary (walking_rpy: the camera turns while two
/// people walk through the view; ORB-SLAM2 is pulled by them).
fn sequence() -> &'static Path {
    static DIR: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    let (_, dir) = DIR.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("walking_rpy");
        let cam = dynapix_geometry::PinholeCamera::tum_fr3();
        let (s, w, h) = (0.5, 320, 240);
        let camera = dynapix_geometry::PinholeCamera::new(
            w,
            h,
            cam.fx * s,
            cam.fy * s,
            cam.cx * s,
            cam.cy * s,
        );
        let p = SynthParams {
            preset: Preset::WalkingRpy,
            frames: FRAMES,
            seed: 0,
            scene: SceneParams::for_width(w),
            camera,
            ..SynthParams::default()
        };
        let seq = dynapix_synth::Sequence::new(p).unwrap();
        dynapix_synth::output::write_sequence(&seq, &dir, None, &mut |_| {}).unwrap();
        (tmp, dir)
    });
    dir
}

fn open(dir: &Path, config: &Config) -> Input {
    Input::open(dir, &config.sequence, &CameraChoice::Sequence).unwrap()
}

/// A record as its JSON value (the keys `run.json` has).
fn json<T: serde::Serialize>(v: &T) -> serde_json::Value {
    serde_json::to_value(v).unwrap()
}

/// Copies the folder `src` into `dst`, recursively.
fn copy_dir(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let e = e.unwrap();
        let to = dst.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to);
        } else {
            std::fs::copy(e.path(), to).unwrap();
        }
    }
}

/// A copy of the sequence without `background/` and `depth_bg/` (a camera gives none).
fn camera_only(into: &Path) -> PathBuf {
    let dst = into.join("walking_rpy");
    copy_dir(sequence(), &dst);
    for d in ["background", "depth_bg"] {
        std::fs::remove_dir_all(dst.join(d)).unwrap();
    }
    dst
}

fn offline(config: &Config, input: &Input, cache: &Path) -> crate::OfflineOutput {
    let options = RunOptions {
        cache_dir: Some(cache.to_path_buf()),
        ..Default::default()
    };
    OfflineRunner::new(config, input, options)
        .unwrap()
        .run(&())
        .unwrap()
}

/// The geometric cue read over a window of depths (what the offline maps do) gives every
/// frame the map it gets with every depth read, and holds a window, not the sequence.
#[test]
fn the_geometric_cue_over_a_window_equals_the_cue_over_the_sequence() {
    let seq = sequence();
    let config = Config::default();
    let input = open(seq, &config);
    let gt = input.sequence.groundtruth.clone().unwrap();
    let poses = FramePoses::from_trajectory(
        &gt,
        &input.timestamps(),
        0.05,
        PoseOrigin::GroundTruth {
            path: seq.join("groundtruth.txt"),
        },
    )
    .unwrap();
    let mut params = config.motion.static_depth.clone();
    params.window_s = 0.5;
    let all = GeometricInput::load(&input, &poses, &params).unwrap();
    assert_eq!(all.frames_held(), FRAMES);
    let win = GeometricInput::windowed(&input, &poses, &params).unwrap();
    assert_eq!(win.frames_held(), 0);
    let frames: Vec<usize> = (0..FRAMES).collect();
    let mut most = 0;
    for part in frames.chunks(16) {
        win.prepare(&input, part).unwrap();
        most = most.max(win.frames_held());
        for &i in part.iter().step_by(5) {
            assert_eq!(win.frame(i).unwrap(), all.frame(i).unwrap(), "frame {i}");
        }
    }
    // 16 frames and their views within ±0.5 s (30 Hz).
    assert!(most <= 16 + 2 * 16, "{most} depths held at once");
    // A frame outside the window is refused, not computed from missing depths.
    assert!(win.frame(0).is_err());
}

#[test]
fn shared_rigidity_pairs_give_every_frame_the_map_it_gets_alone() {
    // `motion.rigidity.shared_pairs` (the default): the chunked run computes each pair once
    // for both of its frames; a frame computed alone must get the same map, and the maps
    // stay close to those of the frames' own flows.
    let config = Config::default();
    assert!(config.motion.rigidity.shared_pairs);
    let input = open(sequence(), &config);
    let mut params = config.motion.rigidity.clone();
    let shared = RigidityJob::new(&input, params.clone());
    params.shared_pairs = false;
    let own = RigidityJob::new(&input, params);
    assert_ne!(
        own.key(),
        shared.key(),
        "the option is part of the cache key"
    );
    let maps = std::sync::Mutex::new(std::collections::BTreeMap::new());
    let stats = shared
        .run(&(), "rigidity", |i, p| {
            maps.lock().unwrap().insert(i, p);
            Ok(())
        })
        .unwrap();
    let maps = maps.into_inner().unwrap();
    assert_eq!(maps.len(), FRAMES);
    assert!(stats.pairs_used > 3 * FRAMES, "{stats:?}");
    let (mut diff, mut n, mut same) = (0.0, 0usize, 0usize);
    for i in [0, 1, 4, 40, 77, FRAMES - 2, FRAMES - 1] {
        let alone = shared.frame(i).unwrap();
        assert!(
            alone.as_raw() == maps[&i].as_raw(),
            "frame {i}: shared run against alone"
        );
        let mine = own.frame(i).unwrap();
        same += usize::from(mine.as_raw() == alone.as_raw());
        for (a, b) in mine.iter().zip(alone.iter()) {
            diff += (a - b).abs() as f64;
            n += 1;
        }
    }
    // Frame 0 has only later neighbours, so the same flows; the others differ.
    assert_eq!(same, 1, "only frame 0 is computed the same way");
    let mean = diff / n as f64;
    eprintln!("mean |ΔP| shared pairs against own flows: {mean:.4}");
    assert!(mean < 0.03, "{mean}");
}

#[test]
fn a_damaged_cache_is_found_and_recomputed() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    let seq = camera_only(tmp.path());
    let mut config = Config::default();
    config.sequence.max_frames = Some(30);
    config.motion.flow = FlowPreset::Ultrafast;
    let input = open(&seq, &config);
    let first = offline(&config, &input, &cache);
    let reference = first.final_pass().unwrap().trajectory.clone();
    let dir = first.maps[0].folder.clone().unwrap().dir;
    let folder = MapFolder::new(&dir);
    let rec: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("motion.json")).unwrap()).unwrap();
    let key_doc = rec["config"].clone();
    assert_eq!(folder.check_cache(&input, &key_doc), CacheCheck::Valid);
    let map = |i: usize| folder.map_path(&input, i).unwrap();

    // A truncated map: named, recomputed, same result.
    let bytes = std::fs::read(map(5)).unwrap();
    std::fs::write(map(5), &bytes[..bytes.len() / 2]).unwrap();
    match folder.check_cache(&input, &key_doc) {
        CacheCheck::Damaged(why) => {
            let name = map(5).file_name().unwrap().to_string_lossy().into_owned();
            assert!(why.contains(&name), "{why}");
        }
        other => panic!("{other:?}"),
    }
    let r = offline(&config, &input, &cache);
    assert_eq!(json(&r.record)["prob"]["source"], "computed");
    assert_eq!(std::fs::read(map(5)).unwrap(), bytes);
    assert_eq!(r.final_pass().unwrap().trajectory, reference);

    // A map swapped with another valid one (both decode).
    std::fs::copy(map(12), map(11)).unwrap();
    assert!(matches!(
        folder.check_cache(&input, &key_doc),
        CacheCheck::Damaged(_)
    ));
    let r = offline(&config, &input, &cache);
    assert_eq!(json(&r.record)["prob"]["source"], "computed");
    assert_eq!(r.final_pass().unwrap().trajectory, reference);
    assert_eq!(folder.check_cache(&input, &key_doc), CacheCheck::Valid);

    // A truncated first-pass trajectory: run again, not used.
    let fp = PathBuf::from(json(&r.record)["first_pass"]["dir"].as_str().unwrap());
    let traj = fp.join("trajectory.txt");
    let full = std::fs::read_to_string(&traj).unwrap();
    let half: String = full
        .lines()
        .take(full.lines().count() / 2)
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(&traj, &half).unwrap();
    let r = offline(&config, &input, &cache);
    assert_eq!(json(&r.record)["first_pass"]["source"], "computed");
    assert_eq!(std::fs::read_to_string(&traj).unwrap(), full);
    assert_eq!(r.final_pass().unwrap().trajectory, reference);
    // The same with a record whose checksum was made to match: the pose count tells.
    std::fs::write(&traj, &half).unwrap();
    let pass_json = fp.join("pass.json");
    let mut rec: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&pass_json).unwrap()).unwrap();
    rec["trajectory"] = json(&crate::FileFingerprint::of(half.as_bytes()));
    std::fs::write(&pass_json, rec.to_string()).unwrap();
    let r = offline(&config, &input, &cache);
    assert_eq!(json(&r.record)["first_pass"]["source"], "computed");
    assert_eq!(r.final_pass().unwrap().trajectory, reference);
    // Intact again: reused.
    let r = offline(&config, &input, &cache);
    assert_eq!(
        json(&r.record)["first_pass"]["source"],
        "cache (key matched)"
    );
    assert_eq!(json(&r.record)["prob"]["source"], "cache (key matched)");
}
