//! The ways of driving the system that are meant to give the same trajectory do, bit for bit,
//! on a generated walking sequence (people in front of a moving camera, 320×240): features
//! extracted ahead on another thread ([`System::process_features`]) against
//! [`System::process`], and one rayon thread against two. Run in release mode
//! (`cargo test --release`).

use std::sync::mpsc::sync_channel;

use dynapix_slam::frame::DepthImage;

use dynapix_slam::camera::RgbdCamera;
use dynapix_slam::orb::{OrbExtractor, rgb_to_gray_orbslam};
use dynapix_slam::system::{FrameInput, System, SystemParams};
use dynapix_slam::vocab::Vocabulary;
use image::GrayImage;

const FRAMES: usize = 40;

/// Frames of a synthetic `walking_xyz` sequence at 320×240 and its camera.
fn sequence() -> (Vec<(f64, GrayImage, DepthImage)>, RgbdCamera) {
    let params =
        dynapix_synth::SynthParams::at_size(dynapix_synth::Preset::WalkingXyz, FRAMES, 0, 320, 240);
    let seq = dynapix_synth::Sequence::new(params).expect("sequence");
    let st = dynapix_synth::output::camera_settings(&seq.params.camera, seq.params.fps);
    let rgbd = RgbdCamera::new(st.camera(), st.bf, st.th_depth, st.fps);
    let frames = (0..FRAMES)
        .map(|i| {
            let (f, _) = seq.frame(i, None);
            let gray = rgb_to_gray_orbslam(&f.rgb);
            let depth = f.depth_metres();
            (seq.time(i), gray, depth)
        })
        .collect();
    (frames, rgbd)
}

fn system(cam: &RgbdCamera, params: &SystemParams) -> System<OrbExtractor> {
    let vocab = Vocabulary::embedded_default().expect("vocabulary");
    System::new(OrbExtractor::default(), cam.clone(), params.clone()).with_vocabulary(vocab)
}

/// Everything a run leaves that must agree: per frame `(t, T_wc)` as raw bits, and the
/// keyframe trajectory.
type Outcome = (Vec<(u64, Option<[u64; 7]>)>, Vec<(u64, [u64; 7])>);

fn bits(p: &dynapix_geometry::Se3) -> [u64; 7] {
    let q = p.rotation.coords;
    let t = p.translation.vector;
    [q[0], q[1], q[2], q[3], t[0], t[1], t[2]].map(f64::to_bits)
}

fn outcome(sys: &System<OrbExtractor>) -> Outcome {
    let traj = sys
        .trajectory()
        .iter()
        .map(|e| (e.timestamp.to_bits(), e.pose_wc.as_ref().map(bits)))
        .collect();
    let kfs = sys
        .keyframe_trajectory()
        .iter()
        .map(|(t, p)| (t.to_bits(), bits(p)))
        .collect();
    (traj, kfs)
}

fn input<'a>(f: &'a (f64, GrayImage, DepthImage)) -> FrameInput<'a> {
    FrameInput {
        timestamp: f.0,
        gray: &f.1,
        depth: &f.2,
        weights: None,
        masks: None,
    }
}

/// Every frame through [`System::process`].
fn sequential(
    frames: &[(f64, GrayImage, DepthImage)],
    cam: &RgbdCamera,
    p: &SystemParams,
) -> Outcome {
    let mut sys = system(cam, p);
    for f in frames {
        sys.process(input(f)).expect("frame");
    }
    outcome(&sys)
}

/// Features extracted on a helper thread a few frames ahead, tracking on this one.
fn pipelined(
    frames: &[(f64, GrayImage, DepthImage)],
    cam: &RgbdCamera,
    p: &SystemParams,
) -> Outcome {
    let mut sys = system(cam, p);
    let mut stage = sys.feature_stage();
    std::thread::scope(|scope| {
        let (tx, rx) = sync_channel(3);
        scope.spawn(move || {
            for f in frames {
                if tx.send(stage.extract(&f.1, None)).is_err() {
                    break;
                }
            }
        });
        for (f, features) in frames.iter().zip(rx) {
            sys.process_features(input(f), features).expect("frame");
        }
    });
    outcome(&sys)
}

fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    match rayon::ThreadPoolBuilder::new().num_threads(threads).build() {
        Ok(pool) => pool.install(f),
        Err(e) => panic!("thread pool: {e}"),
    }
}

#[test]
fn features_extracted_ahead_and_thread_counts_give_the_same_trajectory() {
    let (frames, cam) = sequence();
    let p = SystemParams::default();
    let reference = sequential(&frames, &cam, &p);
    let tracked = reference.0.iter().filter(|(_, p)| p.is_some()).count();
    assert!(
        tracked > FRAMES / 2,
        "only {tracked} of {FRAMES} frames tracked"
    );
    assert!(reference.1.len() > 3, "{} keyframes", reference.1.len());
    assert!(
        reference == pipelined(&frames, &cam, &p),
        "pipelined run differs"
    );
    assert!(
        reference == in_pool(1, || sequential(&frames, &cam, &p)),
        "1 thread differs"
    );
    assert!(
        reference == in_pool(2, || pipelined(&frames, &cam, &p)),
        "2 threads differ"
    );
}
