//! A DynaPix run on a small generated sequence, logged to an `.rrd` file and decoded back:
//! the expected entities with the expected row counts, and the same results as without the
//! viewer (offline and online).

use std::path::Path;
use std::sync::Arc;

use dynapix::synthetic::{Realism, SynthOptions, SyntheticSequence};
use dynapix::{CameraChoice, Config, Input, RunObserver, Trajectory};
use dynapix::{FrameView, OfflineRunner, PassInfo, PassOutput, RunOptions};
use dynapix_rerun::read::read_rrd;
use dynapix_rerun::{RerunObserver, RerunParams, Target};

const FRAMES: usize = 36;

/// A walking sequence (movers in view, ground truth) of `FRAMES` frames at 320×240.
fn sequence(dir: &Path) {
    let opts = SynthOptions {
        preset: "walking_xyz".into(),
        frames: FRAMES,
        seed: 1,
        width: Some(320),
        height: None,
        realism: Realism::Kinect,
    };
    SyntheticSequence::new(&opts)
        .unwrap()
        .write(dir, &mut |_| {})
        .unwrap();
}

fn poses(t: &Trajectory) -> Vec<(u64, [u64; 7])> {
    t.poses
        .iter()
        .map(|p| {
            let v = p.pose.translation.vector;
            let q = p.pose.rotation;
            (
                p.t.to_bits(),
                [v.x, v.y, v.z, q.i, q.j, q.k, q.w].map(f64::to_bits),
            )
        })
        .collect()
}

/// Two observers of one run (one run, two recordings with different parameters).
struct Both(Arc<RerunObserver>, Arc<RerunObserver>);

impl RunObserver for Both {
    fn wants_images(&self, pass: &PassInfo<'_>) -> bool {
        self.0.wants_images(pass) || self.1.wants_images(pass)
    }
    fn pass_begins(&self, pass: &PassInfo<'_>) {
        self.0.pass_begins(pass);
        self.1.pass_begins(pass);
    }
    fn frame(&self, frame: &FrameView<'_>) {
        self.0.frame(frame);
        self.1.frame(frame);
    }
    fn pass_ends(&self, pass: &PassInfo<'_>, output: &PassOutput) {
        self.0.pass_ends(pass, output);
        self.1.pass_ends(pass, output);
    }
}

#[test]
fn an_offline_run_decodes_back_with_its_entities_and_counts() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("walking");
    sequence(&seq);
    let config = Config::default();
    let input = Input::open(&seq, &config.sequence, &CameraChoice::Sequence).unwrap();
    assert_eq!(input.len(), FRAMES);

    let plain = OfflineRunner::new(&config, &input, RunOptions::default())
        .unwrap()
        .run(&())
        .unwrap();

    // The default recording (images in the last pass only) and one with images in every
    // pass, every 4th frame.
    let rrd = tmp.path().join("run.rrd");
    let observer = Arc::new(
        RerunObserver::open(&Target::Save(rrd.clone()), "test", RerunParams::default()).unwrap(),
    );
    let rrd_all = tmp.path().join("all.rrd");
    let all_params = RerunParams {
        images_every: 4,
        images_in_all_passes: true,
        ..RerunParams::default()
    };
    let all =
        Arc::new(RerunObserver::open(&Target::Save(rrd_all.clone()), "test", all_params).unwrap());
    let watched = OfflineRunner::new(&config, &input, RunOptions::default())
        .unwrap()
        .with_observer(Arc::new(Both(observer.clone(), all.clone())) as Arc<dyn RunObserver>)
        .run(&())
        .unwrap();
    observer.finish().unwrap();
    all.finish().unwrap();
    drop((observer, all));

    // The viewer changes nothing.
    assert_eq!(plain.passes.len(), watched.passes.len());
    for (a, b) in plain.passes.iter().zip(&watched.passes) {
        assert_eq!(poses(&a.trajectory), poses(&b.trajectory));
    }

    // First pass (rigidity) + the weighted passes, each on its own timeline.
    let first = watched.first_pass.as_ref().and_then(|f| f.output.as_ref());
    let first = first.expect("a DynaPix run without cache runs its first pass");
    let passes: Vec<_> = std::iter::once(first).chain(&watched.passes).collect();
    let n = passes.len();
    assert_eq!(n, 1 + config.passes.weighted);
    let c = read_rrd(&rrd).unwrap();
    // Rerun adds its own `log_time`.
    let timelines: Vec<&str> = c
        .timelines
        .keys()
        .map(String::as_str)
        .filter(|t| *t != "log_time")
        .collect();
    let expected: Vec<String> = (1..=n).map(|k| format!("pass{k}")).collect();
    assert_eq!(timelines, expected, "{c:?}");
    assert_eq!(c.layouts, n, "one layout per pass");

    // One pose per tracked frame, one keypoint set and state per frame of every pass; one
    // image, P overlay and depth per frame of the last pass only; the static pinhole and P
    // colours once per recording.
    let tracked: usize = passes.iter().map(|p| p.stats.tracked).sum();
    assert!(tracked > n * FRAMES / 2, "tracked {tracked}");
    assert_eq!(c.rows("world/camera"), tracked);
    assert_eq!(c.rows("world/camera/image"), FRAMES + 1);
    assert_eq!(c.rows("world/camera/image/motion"), FRAMES + 1);
    assert_eq!(c.rows("world/camera/image/keypoints"), n * FRAMES);
    assert_eq!(c.rows("depth"), FRAMES);
    assert_eq!(c.rows("plots/tracking_state"), n * FRAMES);
    assert_eq!(c.rows("plots/tracked_map_points"), n * FRAMES);
    assert_eq!(c.rows("timings/track_ms"), n * FRAMES);
    // Map, keyframes, trajectories and the ATE so far: several times per pass.
    for path in [
        "world/map/points",
        "world/map/keyframes",
        "world/trajectory/estimate",
        "world/trajectory/ground_truth",
        "plots/ate_rmse_m",
        "plots/mean_p",
    ] {
        assert!(c.rows(path) >= n, "{path}: {} rows", c.rows(path));
    }
    // Events: a begin and an end per pass, one line per keyframe at least.
    let keyframes: usize = passes.iter().map(|p| p.stats.keyframes).sum();
    assert!(c.rows("events") >= 2 * n + keyframes, "{c:?}");

    // Images in every pass, of frames 0, 4, 8, …; the rest as in the default recording.
    let a = read_rrd(&rrd_all).unwrap();
    let sampled = FRAMES.div_ceil(4);
    assert_eq!(a.rows("world/camera/image"), n * sampled + 1);
    assert_eq!(a.rows("world/camera/image/motion"), n * sampled + 1);
    assert_eq!(a.rows("depth"), n * sampled);
    for path in [
        "world/camera",
        "world/camera/image/keypoints",
        "world/map/points",
        "events",
    ] {
        assert_eq!(a.rows(path), c.rows(path), "{path}");
    }
}

#[test]
fn an_online_run_decodes_back_and_keeps_its_results() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("walking");
    sequence(&seq);
    let config = Config::default();
    let input = Input::open(&seq, &config.sequence, &CameraChoice::Sequence).unwrap();
    let (plain, r) = dynapix::run_online(&input, &config, None, &(), &mut |_| {}, None);
    r.unwrap();

    let rrd = tmp.path().join("online.rrd");
    let observer = Arc::new(
        RerunObserver::open(&Target::Save(rrd.clone()), "test", RerunParams::default()).unwrap(),
    );
    let (watched, r) = dynapix::run_online(
        &input,
        &config,
        None,
        &(),
        &mut |_| {},
        Some(observer.clone()),
    );
    r.unwrap();
    observer.finish().unwrap();
    drop(observer);
    assert_eq!(poses(&plain.reported()), poses(&watched.reported()));
    assert_eq!(poses(&plain.refined), poses(&watched.refined));

    let c = read_rrd(&rrd).unwrap();
    assert_eq!(
        c.timelines.keys().collect::<Vec<_>>(),
        ["log_time", "pass1"]
    );
    assert_eq!(c.rows("world/camera"), watched.tracked());
    // An online run is its own last pass: images of every frame.
    assert_eq!(c.rows("world/camera/image/keypoints"), FRAMES);
    assert_eq!(c.rows("world/camera/image/motion"), FRAMES + 1);
    assert_eq!(c.rows("depth"), FRAMES);
    assert_eq!(c.rows("timings/motion_ms"), FRAMES);
    assert!(c.rows("world/trajectory/ground_truth") >= 1, "{c:?}");
}
