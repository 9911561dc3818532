//! DynaPix in process on a small synthetic walking sequence (`dynapix-synth`, 320×240,
//! generated here): the weighted offline run beats ORB-SLAM2 mode by a ratio, the online
//! mode keeps a real gain, the motion-map cache is reused only while nothing that determines
//! the maps changes, and maps made with ground-truth poses are reported as such.
//! Run in release mode (`cargo test --release`).

mod common;
use common::{ate, copy_dir};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use dynapix::{
    CameraChoice, Config, FlowPreset, Input, Method, OnlineDynaPix, PoseSource, RgbdFrame,
    Trajectory,
};
use dynapix::{OfflineRunner, RunOptions};
use dynapix_synth::{Preset, SceneParams, SynthParams};

const FRAMES: usize = 120;

/// A record as its JSON value (the keys `run.json` has).
fn json<T: serde::Serialize>(v: &T) -> serde_json::Value {
    serde_json::to_value(v).unwrap()
}

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

/// A copy of the sequence without `background/` and `depth_bg/` (a camera gives none).
fn camera_only(into: &Path) -> PathBuf {
    let dst = into.join("walking_rpy");
    copy_dir(sequence(), &dst);
    for d in ["background", "depth_bg"] {
        std::fs::remove_dir_all(dst.join(d)).unwrap();
    }
    dst
}

fn open(dir: &Path, config: &Config) -> Input {
    Input::open(dir, &config.sequence, &CameraChoice::Sequence).unwrap()
}

fn offline(config: &Config, input: &Input, cache: &Path) -> dynapix::OfflineOutput {
    let options = RunOptions {
        cache_dir: Some(cache.to_path_buf()),
        ..Default::default()
    };
    OfflineRunner::new(config, input, options)
        .unwrap()
        .run(&())
        .unwrap()
}

#[test]
fn decoded_frames_are_kept_within_their_budget_and_read_back_identical() {
    let seq = sequence();
    let mut config = Config::default();
    let fresh = open(seq, &config);
    let kept = open(seq, &config);
    // Nothing is kept until a run asks for it.
    kept.load_rgbd(0).unwrap();
    assert_eq!(kept.decoded_frames_kept(), 0);
    kept.keep_decoded_frames(true);
    for i in 0..kept.len() {
        kept.load_rgbd(i).unwrap();
    }
    // 120 frames of 320×240 (rgb 225 KiB + depth 300 KiB) fit the default 1 GiB.
    assert_eq!(kept.decoded_frames_kept(), kept.len());
    for i in [0, 7, kept.len() - 1] {
        let (a, b) = (kept.load_rgbd(i).unwrap(), fresh.load_rgbd(i).unwrap());
        assert!(a.0 == b.0 && a.1 == b.1, "frame {i} differs when read back");
        assert!(kept.load_depth(i).unwrap() == b.1, "depth of frame {i}");
    }
    // One MiB holds one frame; the first one read is kept.
    config.sequence.decoded_cache_mib = 1;
    let small = open(seq, &config);
    small.keep_decoded_frames(true);
    for i in 3..6 {
        small.load_rgbd(i).unwrap();
    }
    assert_eq!(small.decoded_frames_kept(), 1);
    assert!(small.load_depth(4).unwrap() == fresh.load_depth(4).unwrap());
    config.sequence.decoded_cache_mib = 0;
    let none = open(seq, &config);
    none.keep_decoded_frames(true);
    none.load_rgbd(0).unwrap();
    assert_eq!(none.decoded_frames_kept(), 0);
    // Stopping frees what was kept.
    kept.keep_decoded_frames(false);
    assert_eq!(kept.decoded_frames_kept(), 0);
}

#[test]
fn the_input_of_a_run_has_a_decoded_frame_cache_of_its_own() {
    let seq = sequence();
    let config = Config::default();
    let shared = open(seq, &config);
    shared.keep_decoded_frames(true);
    shared.load_rgbd(0).unwrap();
    // A run's copy starts empty and off, whatever the shared input keeps.
    let run = shared.for_run();
    assert_eq!(run.decoded_frames_kept(), 0);
    run.load_rgbd(1).unwrap();
    assert_eq!(run.decoded_frames_kept(), 0);
    run.keep_decoded_frames(true);
    for i in 1..4 {
        run.load_rgbd(i).unwrap();
    }
    assert_eq!(run.decoded_frames_kept(), 3);
    // Neither sees the other's frames, and switching one off leaves the other alone.
    assert_eq!(shared.decoded_frames_kept(), 1);
    shared.keep_decoded_frames(false);
    assert_eq!(run.decoded_frames_kept(), 3);
    assert!(run.load_rgbd(2).unwrap().0 == open(seq, &config).load_rgbd(2).unwrap().0);
}

#[test]
fn streamed_frames_come_in_order_and_an_error_stops_the_stream() {
    let seq = sequence();
    let input = open(seq, &Config::default());
    let loaded = std::sync::atomic::AtomicUsize::new(0);
    let load = |i: usize| {
        loaded.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        input.load_rgbd(i)
    };
    // Every frame, in order, the same images as a direct read.
    let mut seen = Vec::new();
    input
        .stream(2, load, |i, images| -> dynapix::Result<()> {
            let (rgb, depth) = images?;
            if i % 40 == 0 {
                let (r, d) = input.load_rgbd(i)?;
                assert!(rgb == r && depth == d, "frame {i}");
            }
            seen.push(i);
            Ok(())
        })
        .unwrap();
    assert_eq!(seen, (0..input.len()).collect::<Vec<_>>());
    // The consumer's first error is returned and the reader stops soon after.
    loaded.store(0, std::sync::atomic::Ordering::SeqCst);
    let err = input
        .stream(2, load, |i, _| {
            if i == 5 {
                Err(format!("stop at {i}"))
            } else {
                Ok(())
            }
        })
        .unwrap_err();
    assert_eq!(err, "stop at 5");
    let read = loaded.load(std::sync::atomic::Ordering::SeqCst);
    assert!(
        (6..=10).contains(&read),
        "{read} frames read for a stream stopped at frame 5"
    );
}

#[test]
fn a_stream_with_several_readers_gives_every_frame_in_order() {
    let seq = sequence();
    let input = open(seq, &Config::default());
    let n = input.len();
    for readers in [1, 2, 3] {
        // Each reader has its own loader (here: a counter of the frames it loaded).
        let made = std::sync::atomic::AtomicUsize::new(0);
        let mut seen = Vec::new();
        input
            .stream_parallel(
                2,
                readers,
                || {
                    made.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                    let mut mine = 0usize;
                    move |i: usize| {
                        mine += 1;
                        // Uneven loading times, so the readers finish out of order.
                        if i.is_multiple_of(3) {
                            std::thread::sleep(std::time::Duration::from_millis(1));
                        }
                        (i, mine)
                    }
                },
                |i, (j, mine)| -> Result<(), String> {
                    assert_eq!(i, j);
                    // Reader i % readers loads every readers-th frame, in order.
                    assert_eq!(mine, i / readers + 1, "frame {i}, {readers} readers");
                    seen.push(i);
                    Ok(())
                },
            )
            .unwrap();
        assert_eq!(seen, (0..n).collect::<Vec<_>>());
        assert_eq!(made.load(std::sync::atomic::Ordering::SeqCst), readers);
    }
    // The consumer's first error stops every reader soon after.
    let loaded = std::sync::atomic::AtomicUsize::new(0);
    let err = input
        .stream_parallel(
            2,
            2,
            || {
                |i: usize| {
                    loaded.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                    i
                }
            },
            |i, _| if i == 5 { Err(i) } else { Ok(()) },
        )
        .unwrap_err();
    assert_eq!(err, 5);
    let read = loaded.load(std::sync::atomic::Ordering::SeqCst);
    assert!(
        (6..=12).contains(&read),
        "{read} frames read for a stream stopped at frame 5"
    );
}

#[test]
fn a_stream_shows_the_next_frame_only_when_it_has_arrived() {
    let seq = sequence();
    let input = open(seq, &Config::default());
    let n = input.len();
    // A slow consumer: the reader is ahead, so the next frame is almost always shown, and
    // whenever it is, it is the frame consumed next.
    let mut seen = Vec::new();
    let mut shown: Vec<Option<usize>> = Vec::new();
    input
        .stream_with_next(
            2,
            |i| i,
            |i, item, next| -> Result<(), String> {
                assert_eq!(i, item);
                std::thread::sleep(std::time::Duration::from_millis(2));
                seen.push(i);
                shown.push(next.copied());
                Ok(())
            },
        )
        .unwrap();
    assert_eq!(seen, (0..n).collect::<Vec<_>>());
    for (i, s) in shown.iter().enumerate() {
        if let Some(j) = s {
            assert_eq!(*j, i + 1, "frame {i} was shown {j} as the next frame");
        }
    }
    assert_eq!(shown[n - 1], None, "nothing after the last frame");
    let known = shown.iter().filter(|s| s.is_some()).count();
    assert!(known + 5 >= n, "next frame shown for {known} of {n}");
    // A slow reader: the consumer never waits for the next frame, it goes on without it.
    let mut shown = Vec::new();
    input
        .stream_with_next(
            2,
            |i| {
                std::thread::sleep(std::time::Duration::from_millis(5));
                i
            },
            |_, _, next| -> Result<(), String> {
                shown.push(next.is_some());
                Ok(())
            },
        )
        .unwrap();
    assert_eq!(shown.len(), n);
    assert!(
        shown.iter().filter(|&&s| s).count() * 2 < n,
        "a consumer faster than its reader is mostly shown no next frame"
    );
    // The consumer's first error stops the stream.
    let err = input
        .stream_with_next(2, |i| i, |i, _, _| if i == 5 { Err(i) } else { Ok(()) })
        .unwrap_err();
    assert_eq!(err, 5);
}

#[test]
fn fast_corners_are_kept_for_later_passes_only_during_a_run() {
    let seq = sequence();
    let config = Config::default();
    let input = open(seq, &config);
    let gray = dynapix_slam::orb::rgb_to_gray_orbslam(&input.load_rgbd(2).unwrap().0);
    let extractor = dynapix_slam::orb::OrbExtractor::default();
    let mut corners = None;
    let first = extractor.extract_cached(&gray, None, &mut corners);
    let corners = corners.unwrap();
    // Outside a run nothing is kept.
    input.keep_fast_corners(2, corners.clone());
    assert!(input.fast_corners(2).is_none());
    input.keep_decoded_frames(true);
    input.keep_fast_corners(2, corners.clone());
    let back = input.fast_corners(2).unwrap();
    assert!(std::sync::Arc::ptr_eq(&back, &corners));
    assert!(input.fast_corners(3).is_none());
    // Reused, they give the features of a fresh extraction.
    let mut slot = Some(back);
    assert_eq!(extractor.extract_cached(&gray, None, &mut slot), first);
    input.keep_decoded_frames(false);
    assert!(input.fast_corners(2).is_none());
}

#[test]
fn fast_corners_are_kept_only_within_the_decoded_budget() {
    let mut config = Config::default();
    config.sequence.decoded_cache_mib = 0;
    let input = open(sequence(), &config);
    let gray = dynapix_slam::orb::rgb_to_gray_orbslam(&input.load_rgbd(2).unwrap().0);
    let mut corners = None;
    dynapix_slam::orb::OrbExtractor::default().extract_cached(&gray, None, &mut corners);
    input.keep_decoded_frames(true);
    input.keep_fast_corners(2, corners.unwrap());
    assert!(input.fast_corners(2).is_none());
    assert_eq!(input.decoded_peak_bytes(), 0);
}

/// An offline DynaPix run without a cache and with no decoded-frame budget keeps no frame's
/// map, decoded image or corners in memory: every map set holds O(1) bytes per frame (its
/// maps are in a temporary file, read back when a pass reaches the frame), the maps of the
/// passes before the last are released, and the same trajectory comes out as with the
/// default budget.
#[test]
fn an_offline_run_keeps_no_frame_data_in_memory() {
    let mut config = Config::default();
    config.sequence.decoded_cache_mib = 0;
    let input = open(sequence(), &config);
    let options = RunOptions {
        cache_dir: None,
        ..Default::default()
    };
    let runner = OfflineRunner::new(&config, &input, options).unwrap();
    let out = runner.run(&()).unwrap();
    let map_bytes = 320 * 240 * 2;
    let rigidity = runner.rigidity_maps(&()).unwrap().unwrap();
    let last = out.maps.last().unwrap();
    for (k, m) in out.maps.iter().chain([&rigidity]).enumerate() {
        // Far below one frame's map for the whole sequence.
        assert!(
            m.bytes_in_memory() < map_bytes / 16,
            "map set {k}: {} bytes in memory",
            m.bytes_in_memory()
        );
        assert!(m.dir().is_none());
    }
    assert!(out.maps.len() >= 2);
    assert!(
        out.maps[..out.maps.len() - 1]
            .iter()
            .all(|m| m.bytes_on_disk() == 0)
    );
    for m in [last, &rigidity] {
        assert_eq!(m.bytes_on_disk(), (FRAMES * map_bytes) as u64);
        assert_eq!(
            m.stored(&input, FRAMES - 1).unwrap().unwrap().dimensions(),
            (320, 240)
        );
    }
    // Neither decoded frames nor FAST corners were kept at any time (by the run's own
    // input, whose decoded-frame cache is the run's).
    assert_eq!(runner.input().decoded_peak_bytes(), 0);
    // The same trajectory with decoded frames and corners kept.
    let full = Config::default();
    let kept = open(sequence(), &full);
    let options = RunOptions {
        cache_dir: None,
        ..Default::default()
    };
    let runner = OfflineRunner::new(&full, &kept, options).unwrap();
    let again = runner.run(&()).unwrap();
    assert!(runner.input().decoded_peak_bytes() > FRAMES * 320 * 240 * 3);
    assert_eq!(
        out.final_pass().unwrap().trajectory,
        again.final_pass().unwrap().trajectory
    );
}

#[test]
fn weighted_offline_run_beats_orbslam2() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    let seq = camera_only(tmp.path());
    let orb_cfg = Config::default().with_method(Method::Orbslam2);
    let input = open(&seq, &orb_cfg);
    let orb = offline(&orb_cfg, &input, &cache);
    let dpx_cfg = Config::default();
    let dpx = offline(&dpx_cfg, &input, &cache);
    let (a_orb, a_dpx) = (
        ate(&seq, &orb.final_pass().unwrap().trajectory),
        ate(&seq, &dpx.final_pass().unwrap().trajectory),
    );
    eprintln!("offline ATE: orbslam2 {a_orb:.4} m, dynapix {a_dpx:.4} m");
    assert_eq!(orb.final_pass().unwrap().stats.tracked, FRAMES);
    assert_eq!(dpx.final_pass().unwrap().stats.tracked, FRAMES);
    assert!(a_dpx < 0.5 * a_orb, "dynapix {a_dpx} vs orbslam2 {a_orb}");
    // No ground truth at run time, and the record says where the poses came from.
    assert_eq!(json(&dpx.record)["ground_truth_used_at_run_time"], false);
    assert_eq!(json(&dpx.record)["prob"]["source"], "computed");
    assert_eq!(json(&dpx.record)["prob"]["poses"]["source"], "pass");
    assert_eq!(json(&dpx.record)["config"]["method"], "dynapix");
}

/// Every file and folder under `dir` with its size and modification time.
fn tree(dir: &Path) -> Vec<(PathBuf, u64, std::time::SystemTime)> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let e = e.unwrap();
        let m = e.metadata().unwrap();
        out.push((e.path(), m.len(), m.modified().unwrap()));
        if m.is_dir() {
            out.extend(tree(&e.path()));
        }
    }
    out.sort();
    out
}

/// Sets or clears the read-only bit of every file and folder under `dir` (and `dir`).
fn set_read_only(dir: &Path, ro: bool) {
    for e in std::fs::read_dir(dir).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_dir() {
            set_read_only(&e.path(), ro);
        } else {
            let mut p = e.metadata().unwrap().permissions();
            p.set_readonly(ro);
            std::fs::set_permissions(e.path(), p).unwrap();
        }
    }
    let mut p = std::fs::metadata(dir).unwrap().permissions();
    p.set_readonly(ro);
    std::fs::set_permissions(dir, p).unwrap();
}

#[test]
fn a_run_without_a_cache_writes_nothing_and_tracks_like_a_cached_run() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = camera_only(tmp.path());
    let mut config = Config::default();
    config.sequence.max_frames = Some(30);
    config.motion.flow = FlowPreset::Ultrafast;
    let input = open(&seq, &config);
    // A cold cache, then the same run from the cache.
    let cache = tmp.path().join("cache");
    let cold = offline(&config, &input, &cache);
    let warm = offline(&config, &input, &cache);
    assert_eq!(json(&warm.record)["prob"]["source"], "cache (key matched)");
    // The records round-trip through their types: the run's record through its JSON text,
    // and the motion.json of every map folder the cold run wrote.
    let text = serde_json::to_string_pretty(&cold.record).unwrap();
    let back: dynapix::RunRecord = serde_json::from_str(&text).unwrap();
    assert_eq!(
        json(&back),
        serde_json::from_str::<serde_json::Value>(&text).unwrap()
    );
    assert_eq!(
        back.passes.as_ref().map(Vec::len),
        Some(config.passes.weighted)
    );
    let mut folders = 0;
    for e in std::fs::read_dir(&cache).unwrap() {
        let path = e.unwrap().path().join("motion.json");
        if !path.is_file() {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let rec: dynapix::MotionRecord = serde_json::from_str(&text).unwrap();
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(json(&rec), v, "{} does not round-trip", path.display());
        assert_eq!(rec.status, dynapix::MapsStatus::Complete);
        assert_eq!(rec.files.as_ref().map(|f| f.len()), Some(input.len()));
        folders += 1;
    }
    // The rigidity maps and the maps of the weighted passes.
    assert!(folders >= 2, "{folders} map folders in the cache");
    // The whole run (rigidity maps, first pass, motion maps of both weighted passes) with
    // no cache folder, on a sequence folder it may not write to.
    set_read_only(&seq, true);
    let before = tree(&seq);
    let options = RunOptions {
        cache_dir: None,
        ..Default::default()
    };
    let runner = OfflineRunner::new(&config, &input, options).unwrap();
    assert_eq!(runner.cache_dir(), None);
    let none = runner.run(&());
    let after = tree(&seq);
    set_read_only(&seq, false);
    let none = none.unwrap();
    assert_eq!(before, after, "the sequence folder was written to");
    assert_eq!(json(&none.record)["prob"]["source"], "computed (no cache)");
    assert_eq!(
        json(&none.record)["first_pass"]["source"],
        "computed (no cache)"
    );
    assert!(none.maps.iter().all(|m| m.dir().is_none()));
    assert_eq!(none.passes.len(), config.passes.weighted);
    // The same trajectories to the bit: fresh, cached and folder-less runs read the same
    // quantised maps.
    for (k, p) in none.passes.iter().enumerate() {
        assert_eq!(p.trajectory, cold.passes[k].trajectory, "pass {}", k + 1);
        assert_eq!(p.trajectory, warm.passes[k].trajectory, "pass {}", k + 1);
    }
    assert_eq!(
        none.first_pass.as_ref().unwrap().trajectory,
        warm.first_pass.as_ref().unwrap().trajectory
    );
    // The maps in the temporary file are the cached files' values; the earlier passes'
    // were released.
    let m = none.maps.last().unwrap();
    let cached = warm.maps.last().unwrap();
    assert!(cached.bytes_on_disk() == 0 && m.bytes_on_disk() > 0);
    assert!(none.maps[0].bytes_on_disk() == 0);
    for i in [0, 13, 29] {
        assert_eq!(
            m.stored(&input, i).unwrap().unwrap(),
            cached.stored(&input, i).unwrap().unwrap(),
            "map of frame {i}"
        );
    }
}

#[test]
fn the_cache_is_reused_only_while_nothing_that_determines_the_maps_changes() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    let seq = camera_only(tmp.path());
    let mut config = Config::default();
    config.sequence.max_frames = Some(30);
    config.motion.flow = FlowPreset::Ultrafast;
    let input = open(&seq, &config);
    let first = offline(&config, &input, &cache);
    assert_eq!(json(&first.record)["prob"]["source"], "computed");
    assert_eq!(json(&first.record)["first_pass"]["source"], "computed");
    // Same configuration: maps and first pass come from the cache, same trajectory.
    let again = offline(&config, &input, &cache);
    assert_eq!(json(&again.record)["prob"]["source"], "cache (key matched)");
    assert_eq!(
        json(&again.record)["first_pass"]["source"],
        "cache (key matched)"
    );
    assert_eq!(
        again.final_pass().unwrap().trajectory,
        first.final_pass().unwrap().trajectory
    );
    // The maps of the first weighted pass (what `record["prob"]` describes).
    let dir1 = again.maps[0].dir().unwrap().to_path_buf();
    // A motion parameter changes: other key, maps recomputed.
    let mut changed = config.clone();
    changed.motion.params.movable.clip_hi += 5.0;
    let c = offline(&changed, &input, &cache);
    assert_eq!(json(&c.record)["prob"]["source"], "computed");
    assert_eq!(
        json(&c.record)["first_pass"]["source"],
        "cache (key matched)"
    );
    assert_ne!(c.maps[0].dir().unwrap(), dir1);
    // Another first pass (SLAM parameters changed) is run, not taken from the cache.
    let mut slam = config.clone();
    slam.slam.params.tracking.motion_th = 14.0;
    let r = offline(&slam, &input, &cache);
    assert_eq!(json(&r.record)["first_pass"]["source"], "computed");
    // Poses from a file: the same file is a cache hit, an edited one (same path) is not.
    let file = tmp.path().join("poses.txt");
    std::fs::copy(seq.join("groundtruth.txt"), &file).unwrap();
    let mut from_file = config.clone();
    from_file.motion.poses = PoseSource::File(file.clone());
    assert_eq!(
        json(&offline(&from_file, &input, &cache).record)["prob"]["source"],
        "computed"
    );
    assert_eq!(
        json(&offline(&from_file, &input, &cache).record)["prob"]["source"],
        "cache (key matched)"
    );
    let mut gt = Trajectory::read_tum(&file).unwrap();
    gt.poses[3].pose.translation.vector.x += 0.01;
    gt.write_tum(&file).unwrap();
    assert_eq!(
        json(&offline(&from_file, &input, &cache).record)["prob"]["source"],
        "computed"
    );
    // A map deleted from a cached folder: recomputed in place, same result.
    let victim = std::fs::read_dir(&dir1)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|x| x == "png"))
        .unwrap();
    std::fs::remove_file(&victim).unwrap();
    let d = offline(&config, &input, &cache);
    assert_eq!(json(&d.record)["prob"]["source"], "computed");
    assert!(victim.is_file());
    assert_eq!(
        d.final_pass().unwrap().trajectory,
        first.final_pass().unwrap().trajectory
    );
    // Fewer frames: another frame list, another key.
    let mut short = config.clone();
    short.sequence.max_frames = Some(20);
    let short_input = open(&seq, &short);
    let s = offline(&short, &short_input, &cache);
    assert_eq!(json(&s.record)["prob"]["source"], "computed");
    assert_eq!(s.final_pass().unwrap().status.len(), 20);
}

/// Issue 36 item 3: every cached item is checked before use. A truncated map, a map swapped
/// with another valid one and a truncated first-pass trajectory (also with a forged checksum)
/// are found, recomputed, and the result is the one of the intact cache.

#[test]
fn online_mode_keeps_a_real_gain() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = camera_only(tmp.path());
    // `map_at_once`: run each keyframe's local mapping right after its frame instead of
    // during the next push beside the next motion map.
    let run_with = |config: &Config, map_at_once: bool| -> (Trajectory, usize) {
        let input = open(&seq, config);
        let mut online = OnlineDynaPix::new(&input.camera, config).unwrap();
        let mut results = Vec::new();
        for i in 0..input.len() {
            let (rgb, depth) = input.load_rgbd(i).unwrap();
            let t = input.sequence.frames[i].t;
            results.extend(online.push(RgbdFrame::new(t, rgb, depth)).unwrap());
            if map_at_once {
                online.map_pending();
                assert!(!online.system().has_pending_mapping());
            }
        }
        results.extend(online.finish().unwrap());
        assert!(!online.system().has_pending_mapping());
        let keyframes = results.iter().filter(|r| r.keyframe).count();
        let mapped_beside = results.iter().filter(|r| r.mapping_ms > 0.0).count();
        if map_at_once {
            assert_eq!(mapped_beside, 0);
        } else {
            // Every keyframe but the last is mapped during the next push.
            assert!(
                mapped_beside + 1 >= keyframes && keyframes >= 3,
                "{mapped_beside} of {keyframes} keyframes mapped beside a motion map"
            );
        }
        assert!(results.windows(2).all(|w| w[0].index + 1 == w[1].index));
        let lag = results.iter().map(|r| r.latency_frames).max().unwrap_or(0);
        let traj = Trajectory::new(
            results
                .iter()
                .filter_map(|r| r.pose_wc.map(|p| dynapix_io::StampedPose::new(r.t, p)))
                .collect(),
        );
        (traj, lag)
    };
    let run = |config: &Config| run_with(config, false);
    let (orb, _) = run(&Config::default().with_method(Method::Orbslam2));
    let (dpx, lag) = run(&Config::default());
    let (at_once, _) = run_with(&Config::default(), true);
    assert_eq!(
        at_once.poses, dpx.poses,
        "mapping beside the next motion map changes no pose"
    );
    let (a_orb, a_dpx) = (ate(&seq, &orb), ate(&seq, &dpx));
    eprintln!("online ATE: orbslam2 {a_orb:.4} m, dynapix {a_dpx:.4} m");
    assert_eq!(lag, 0, "without lookahead every pose comes with its frame");
    assert_eq!(orb.len(), FRAMES);
    assert_eq!(dpx.len(), FRAMES);
    assert!(
        a_dpx < 0.6 * a_orb,
        "online dynapix {a_dpx} vs orbslam2 {a_orb}"
    );
}

/// How [`rigidity_ahead_changes_no_pose`] feeds the frames.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Feed {
    /// `push` only.
    Plain,
    /// `push_before` showing the frame pushed next.
    ShowNext,
    /// `push_before` showing the frame after the next one: never the frame pushed next.
    ShowWrong,
}

#[test]
fn rigidity_ahead_changes_no_pose() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = camera_only(tmp.path());
    let run = |config: &Config, feed: Feed| -> (Vec<Option<dynapix_geometry::Se3>>, usize) {
        let input = open(&seq, config);
        let frames: Vec<RgbdFrame> = (0..40.min(input.len()))
            .map(|i| {
                let (rgb, depth) = input.load_rgbd(i).unwrap();
                RgbdFrame::new(input.sequence.frames[i].t, rgb, depth)
            })
            .collect();
        let mut online = OnlineDynaPix::new(&input.camera, config).unwrap();
        let mut results = Vec::new();
        for (i, f) in frames.iter().enumerate() {
            let shown = match feed {
                Feed::Plain => None,
                Feed::ShowNext => frames.get(i + 1),
                Feed::ShowWrong => frames.get(i + 2),
            };
            results.extend(online.push_before(f.clone(), shown).unwrap());
        }
        results.extend(online.finish().unwrap());
        assert_eq!(results.len(), frames.len());
        let early = results.iter().filter(|r| r.rigidity_ahead).count();
        if early > 0 {
            assert!(results.iter().any(|r| r.next_rigidity_ms > 0.0));
        }
        (results.iter().map(|r| r.pose_wc).collect(), early)
    };
    let mut off = Config::default();
    off.online.rigidity_ahead = false;
    for lookahead in [0, 2, 4] {
        let mut on = Config::default();
        on.online.lookahead = lookahead;
        off.online.lookahead = lookahead;
        let (reference, none) = run(&off, Feed::ShowNext);
        assert_eq!(none, 0, "switched off, no cue is computed early");
        for feed in [Feed::Plain, Feed::ShowNext, Feed::ShowWrong] {
            let (poses, early) = run(&on, feed);
            assert_eq!(
                poses, reference,
                "lookahead {lookahead}, {feed:?}: the early cue changes no pose"
            );
            // Used for every frame but the first when the next frame is known and has the
            // same neighbours one push later. With lookahead 4 the next frame's furthest
            // future neighbour (+4) arrives only with its own push, so the early cue is
            // recomputed, except for the last frames (no frame arrives after them).
            match (lookahead, feed) {
                (0, Feed::ShowNext) | (2, _) => {
                    assert!(
                        early >= 35,
                        "lookahead {lookahead}, {feed:?}: {early} of 40"
                    )
                }
                (4, _) => assert!(early <= 4, "lookahead 4, {feed:?}: {early}"),
                _ => assert_eq!(early, 0, "lookahead {lookahead}, {feed:?}"),
            }
        }
    }
}

#[test]
fn lookahead_reports_every_frame_late_by_the_allowed_frames() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = camera_only(tmp.path());
    let mut config = Config::default();
    config.online.lookahead = 2;
    config.sequence.max_frames = Some(12);
    let input = open(&seq, &config);
    let mut online = OnlineDynaPix::new(&input.camera, &config).unwrap();
    let mut got = Vec::new();
    for i in 0..input.len() {
        let (rgb, depth) = input.load_rgbd(i).unwrap();
        let t = input.sequence.frames[i].t;
        let r = online
            .push(RgbdFrame::new(t, rgb.clone(), depth.clone()))
            .unwrap();
        match (i < 2, &r) {
            (true, None) => {}
            (false, Some(r)) => assert_eq!((r.index, r.latency_frames), (i - 2, 2)),
            _ => panic!("frame {i}: {r:?}"),
        }
        got.extend(r);
        if i == 5 {
            // Bad input is refused with a message and changes nothing.
            let small = image::RgbImage::new(10, 10);
            let e = online
                .push(RgbdFrame::new(t + 0.001, small, depth.clone()))
                .unwrap_err()
                .to_string();
            assert!(e.contains("320×240"), "{e}");
            let e = online
                .push(RgbdFrame::new(t, rgb, depth))
                .unwrap_err()
                .to_string();
            assert!(e.contains("not after"), "{e}");
        }
    }
    let tail = online.finish().unwrap();
    assert_eq!(
        tail.iter().map(|r| r.latency_frames).collect::<Vec<_>>(),
        vec![1, 0]
    );
    got.extend(tail);
    assert_eq!(got.len(), 12);
    assert!(got.iter().all(|r| r.pose_wc.is_some()));
}

#[test]
fn maps_made_with_ground_truth_poses_are_reported_as_such() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    copy_dir(sequence(), &seq);
    let mut config = Config::default();
    config.sequence.max_frames = Some(20);
    config.motion.flow = FlowPreset::Ultrafast;
    let input = open(&seq, &config);
    // `dynapix motion --poses gt` writes SEQ/prob with its record.
    let mut gt_config = config.clone();
    gt_config.motion.poses = PoseSource::GroundTruth;
    let made =
        dynapix::motion_maps(&input, &gt_config, &dynapix::MotionOptions::default(), &()).unwrap();
    assert_eq!(made.dir, seq.join("prob"));
    assert_eq!(made.frames_computed, 20);
    assert_eq!(made.poses.len(), 20);
    // Its record: the maps' key document, complete, the results as returned.
    let rec: dynapix::MotionRecord =
        serde_json::from_str(&std::fs::read_to_string(seq.join("prob/motion.json")).unwrap())
            .unwrap();
    assert_eq!(rec.status, dynapix::MapsStatus::Complete);
    assert_eq!(rec.config["poses"]["origin"]["source"], "ground_truth");
    assert_eq!(rec.results["frames_computed"], 20);
    assert_eq!(rec.results["frames_skipped"], 0);
    // Called again, every map is kept.
    let again =
        dynapix::motion_maps(&input, &gt_config, &dynapix::MotionOptions::default(), &()).unwrap();
    assert_eq!((again.frames_computed, again.frames_skipped), (0, 20));
    // A run with its own poses uses the sequence's maps and says that ground truth made them.
    let input = open(&seq, &config);
    let options = RunOptions {
        cache_dir: Some(tmp.path().join("cache")),
        ..Default::default()
    };
    let out = OfflineRunner::new(&config, &input, options.clone())
        .unwrap()
        .run(&())
        .unwrap();
    assert_eq!(json(&out.record)["prob"]["source"], "sequence prob/ folder");
    assert_eq!(json(&out.record)["prob"]["poses"], "ground truth");
    assert_eq!(json(&out.record)["ground_truth_used_at_run_time"], true);
    assert!(
        out.first_pass.is_none(),
        "the sequence's maps need no first pass"
    );
    // Without a record the provenance is unknown, not "no ground truth".
    std::fs::remove_file(seq.join("prob/motion.json")).unwrap();
    let input = open(&seq, &config);
    let out = OfflineRunner::new(&config, &input, options.clone())
        .unwrap()
        .run(&())
        .unwrap();
    assert!(json(&out.record)["ground_truth_used_at_run_time"].is_null());
    // Recomputing ignores them and records the own poses.
    let recompute = RunOptions {
        recompute_maps: true,
        ..options
    };
    let out = OfflineRunner::new(&config, &input, recompute)
        .unwrap()
        .run(&())
        .unwrap();
    assert_eq!(json(&out.record)["ground_truth_used_at_run_time"], false);
    assert_eq!(json(&out.record)["prob"]["source"], "computed");
    // Oracle poses are ground truth at run time.
    let mut oracle = config.clone();
    oracle.motion.poses = PoseSource::GroundTruth;
    let out = OfflineRunner::new(
        &oracle,
        &input,
        RunOptions {
            recompute_maps: true,
            cache_dir: Some(tmp.path().join("cache")),
            ..Default::default()
        },
    )
    .unwrap()
    .run(&())
    .unwrap();
    assert_eq!(json(&out.record)["ground_truth_used_at_run_time"], true);
    assert_eq!(json(&out.record)["oracle_poses"], true);
}

/// A frame whose depth file is no image stops a run naming it and keeps the pass up to it;
/// with `sequence.skip_bad_frames` the frame is found up front, recorded lost, and the run
/// goes on.
#[test]
fn a_bad_frame_stops_the_run_or_is_skipped() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = camera_only(tmp.path());
    let mut config =
        Config::from_yaml_str("method: orbslam2\nsequence: {max_frames: 20}\n").unwrap();
    let input = open(&seq, &config);
    std::fs::write(&input.sequence.frames[5].depth, b"no image").unwrap();
    let cache = tmp.path().join("cache");
    let options = RunOptions {
        cache_dir: Some(cache.clone()),
        ..Default::default()
    };
    let e = OfflineRunner::new(&config, &input, options.clone())
        .unwrap()
        .run(&())
        .unwrap_err();
    let bad = e.bad_frame().expect("the error names the frame");
    assert_eq!(bad.index, 5);
    assert_eq!(bad.file, input.sequence.frames[5].depth);
    assert!(e.to_string().contains("frame 5"), "{e}");
    let partial = e.partial_pass().expect("the pass so far");
    assert_eq!(partial.status.len(), 5);
    assert_eq!(partial.stats.tracked, 5);
    assert!(
        input.bad_frames().is_empty(),
        "not looked for unless skipping"
    );

    config = Config::from_yaml_str(
        "method: orbslam2\nsequence: {max_frames: 20, skip_bad_frames: true}\n",
    )
    .unwrap();
    let input = open(&seq, &config);
    assert!(input.skip_bad_frames);
    let found: Vec<usize> = input.bad_frames().iter().map(|b| b.index).collect();
    assert_eq!(found, vec![5]);
    let out = OfflineRunner::new(&config, &input, options)
        .unwrap()
        .run(&())
        .unwrap();
    let pass = out.final_pass().unwrap();
    assert_eq!(pass.skipped.len(), 1);
    assert_eq!(pass.skipped[0].index, 5);
    assert_eq!(pass.stats.frames_skipped, 1);
    assert_eq!(pass.status.len(), 20);
    assert_eq!(pass.status[5].status, dynapix_io::FrameStatus::Lost);
    assert_eq!(pass.stats.tracked, 19);
}

/// `dynapix slam` through the library: one ORB-SLAM2 pass, its files, the map saved and
/// loaded again for localisation, and `slam.json` round-tripping through `SlamRecord`.
#[test]
fn a_slam_pass_saves_a_map_that_localises_and_its_record_round_trips() {
    let tmp = tempfile::tempdir().unwrap();
    let mut config = Config::default().with_method(Method::Orbslam2);
    config.sequence.max_frames = Some(40);
    let input = open(sequence(), &config);
    let mut slam = dynapix::SlamPass::new(&input, &config).unwrap();
    let pass = slam.run(&input, &(), None).unwrap();
    assert_eq!(pass.stats.frames, 40);
    assert!(pass.stats.tracked > 30, "{:?}", pass.stats);
    let out = tmp.path().join("out");
    pass.write_files(&out).unwrap();
    pass.write_timing(&out.join("timing.csv")).unwrap();
    let back = Trajectory::read_tum(out.join("trajectory.txt")).unwrap();
    assert_eq!(back.len(), pass.trajectory.len());
    let timing = std::fs::read_to_string(out.join("timing.csv")).unwrap();
    assert_eq!(timing.lines().count(), 41);
    let map = tmp.path().join("map.bin");
    let saved = slam.save_map(&map).unwrap();
    assert_eq!(saved.keyframes, pass.stats.keyframes);
    assert_eq!(saved.bytes as u64, std::fs::metadata(&map).unwrap().len());
    let names: Vec<&str> = saved.steps_ms.iter().map(|s| s.0).collect();
    assert_eq!(names, ["encode", "write"]);

    // Localisation in the saved map: nothing is added to it.
    let mut again = dynapix::SlamPass::new(&input, &config).unwrap();
    let loaded = again.load_map(&map).unwrap();
    assert_eq!(
        (loaded.keyframes, loaded.points),
        (saved.keyframes, saved.points)
    );
    let local = again.run(&input, &(), None).unwrap();
    assert_eq!(local.stats.keyframes, saved.keyframes);
    assert!(local.stats.tracked > 30, "{:?}", local.stats);

    // The record: written, read back equal, the same keys as its JSON value.
    let mut record = dynapix::SlamRecord::new(&input, &config);
    record.save_map = Some(map.clone());
    record.set_pass(&pass, true);
    let path = out.join("slam.json");
    record.write(&path).unwrap();
    let read = dynapix::SlamRecord::read(&path).unwrap();
    assert_eq!(json(&read), json(&record));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert_eq!(json(&read), v);
    assert_eq!(v["command"], "slam");
    assert!(v["localize"].is_null());
    assert_eq!(v["stats"]["frames"], 40);
    assert_eq!(v["complete"], true);
    assert!(v.get("failed_frame").is_none());
    // A stopped pass: incomplete, with the error and the frame.
    record.mark_incomplete("stopped".into(), pass.skipped.first().cloned());
    record.write(&path).unwrap();
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert_eq!(
        (v["complete"].clone(), v["error"].clone()),
        (false.into(), "stopped".into())
    );
}
