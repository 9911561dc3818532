//! Loop detection on whole sequences: the SLAM system runs frame by frame (embedded
//! vocabulary) and two detectors are called on every new keyframe. Generated data comes from
//! `dynapix-synth` (the `loop` preset must close its loop, the walking presets must not), real
//! data from `../shared/data` fr1_xyz (skipped with a message when missing).

use std::path::{Path, PathBuf};

use dynapix_geometry::{PinholeCamera, Se3};
use image::{GrayImage, Luma};
use rayon::prelude::*;

use super::{DetectionDiagnostics, DetectionOutcome, DetectionParams, LoopDetector};
use crate::features::{Descriptor, KeyPoint};
use crate::frame::{DepthImage, RgbdCamera, ScalePyramid};
use crate::loop_closing::LoopMatch;
use crate::orb::{OrbExtractor, OrbParams, rgb_to_gray_orbslam};
use crate::system::{FeatureExtractor, FrameInput, System, SystemParams};
use crate::vocab::Vocabulary;

struct Orb(OrbExtractor);

impl FeatureExtractor for Orb {
    fn extract(&mut self, image: &GrayImage) -> (Vec<KeyPoint>, Vec<Descriptor>) {
        self.0.extract(image)
    }
    fn pyramid(&self) -> ScalePyramid {
        ScalePyramid::new(self.0.nlevels(), self.0.scale_factor())
    }
}

/// One accepted loop with the keyframes' frame indices.
struct Found {
    m: LoopMatch,
    cur_frame: u64,
    loop_frame: u64,
    cur_seq: u64,
    loop_seq: u64,
    /// Estimated pose of the loop keyframe (T_mw) and current keyframe before correction.
    loop_pose: Se3,
    cur_pose: Se3,
    diag: DetectionDiagnostics,
}

/// What a run saw.
#[derive(Default)]
struct Run {
    keyframes: usize,
    found: Vec<Found>,
    diags: Vec<DetectionDiagnostics>,
}

impl Run {
    fn count(&self, o: DetectionOutcome) -> usize {
        self.diags.iter().filter(|d| d.outcome == o).count()
    }

    fn summary(&self, name: &str) {
        let cands: usize = self.diags.iter().map(|d| d.candidates.len()).sum();
        let with_cands = self
            .diags
            .iter()
            .filter(|d| !d.candidates.is_empty())
            .count();
        let consistent: usize = self
            .diags
            .iter()
            .map(|d| d.consistent_candidates.len())
            .sum();
        let max_groups = self
            .diags
            .iter()
            .map(|d| d.consistent_groups)
            .max()
            .unwrap_or(0);
        let trials: Vec<String> = self
            .diags
            .iter()
            .flat_map(|d| {
                d.trials.iter().map(move |t| {
                    format!(
                        "kf{}→kf{}: bow {} ransac {} guided {} refined {} hyp {} total {}",
                        d.seq,
                        t.seq,
                        t.bow_matches,
                        t.ransac_inliers,
                        t.guided_matches,
                        t.refined_inliers,
                        t.hypotheses,
                        d.total_matches
                    )
                })
            })
            .collect();
        eprintln!(
            "{name}: {} keyframes examined {}, too soon {}, no candidates {}, candidates {cands} \
             (in {with_cands} keyframes), max groups {max_groups}, not consistent {}, \
             consistent candidates {consistent}, geometry rejected {}, too few total {}, \
             accepted {}",
            self.keyframes,
            self.diags.len(),
            self.count(DetectionOutcome::TooSoon),
            self.count(DetectionOutcome::NoCandidates),
            self.count(DetectionOutcome::NotConsistent),
            self.count(DetectionOutcome::GeometryRejected),
            self.count(DetectionOutcome::TooFewTotalMatches),
            self.count(DetectionOutcome::Accepted),
        );
        for t in trials {
            eprintln!("  {name} trial {t}");
        }
        for f in &self.found {
            eprintln!(
                "  {name} loop: kf{} (frame {}) → kf{} (frame {}), total matches {}",
                f.cur_seq, f.cur_frame, f.loop_seq, f.loop_frame, f.diag.total_matches
            );
        }
    }
}

/// Runs the system on `frames` (timestamp, grey, depth) and two detectors on each new
/// keyframe; asserts that both detectors agree on every call (determinism).
fn run_sequence(
    cam: RgbdCamera,
    frames: impl Iterator<Item = (f64, GrayImage, DepthImage)>,
) -> Run {
    let vocab = Vocabulary::embedded_default().expect("embedded vocabulary");
    let orb = OrbExtractor::new(OrbParams::default()).expect("ORB extractor");
    let mut system =
        System::new(Orb(orb), cam.clone(), SystemParams::default()).with_vocabulary(vocab.clone());
    let mut a = LoopDetector::new(cam.clone(), DetectionParams::default());
    let mut b = LoopDetector::new(cam, DetectionParams::default());
    let mut run = Run::default();
    for (t, gray, depth) in frames {
        let res = system.process(FrameInput {
            timestamp: t,
            gray: &gray,
            depth: &depth,
            weights: None,
            masks: None,
        });
        if res.reset {
            a.reset();
            b.reset();
        }
        if !res.new_keyframe {
            continue;
        }
        run.keyframes += 1;
        let map = system.map();
        let Some(&(kf, _)) = map.keyframes_sorted().last() else {
            continue;
        };
        let ra = a.detect(map, kf, Some(&vocab));
        let rb = b.detect(map, kf, Some(&vocab));
        assert_eq!(ra, rb, "two detectors disagree");
        assert_eq!(a.last_diagnostics(), b.last_diagnostics());
        run.diags.push(a.last_diagnostics().clone());
        if let Some(m) = ra {
            let (Some(ck), Some(lk)) = (map.keyframe(m.current), map.keyframe(m.loop_kf)) else {
                panic!("loop keyframes must exist");
            };
            assert_eq!(m.current, kf);
            assert_eq!(m.matched_points.len(), ck.keys_un.len());
            assert!(m.matched_points.iter().flatten().count() >= 40);
            assert!(!m.loop_points.is_empty());
            run.found.push(Found {
                cur_frame: ck.frame_id,
                loop_frame: lk.frame_id,
                cur_seq: ck.seq,
                loop_seq: lk.seq,
                loop_pose: lk.pose,
                cur_pose: ck.pose,
                diag: a.last_diagnostics().clone(),
                m,
            });
            a.loop_closed(map, kf);
            b.loop_closed(map, kf);
        }
    }
    run
}

/// A synthetic sequence at 320×240 (the CLI's scaling of the fr3 intrinsics).
fn synth_sequence(preset: &str, frames: usize) -> (dynapix_synth::Sequence, RgbdCamera) {
    let preset: dynapix_synth::Preset = preset.parse().expect("preset");
    let full = PinholeCamera::tum_fr3();
    let s = 320.0 / full.width as f64;
    let cam = PinholeCamera::new(320, 240, full.fx * s, full.fy * s, full.cx * s, full.cy * s);
    let params = dynapix_synth::SynthParams {
        preset,
        frames,
        seed: 0,
        scene: dynapix_synth::SceneParams::for_width(cam.width),
        camera: cam.clone(),
        ..dynapix_synth::SynthParams::default()
    };
    let seq = dynapix_synth::Sequence::new(params).expect("sequence");
    let st = dynapix_synth::output::camera_settings(&cam, seq.params.fps);
    let rgbd = RgbdCamera::new(st.camera(), st.bf, st.th_depth, st.fps);
    (seq, rgbd)
}

/// Frames `0..n` of `seq` (n may exceed the sequence length: the camera motion goes on),
/// rendered in parallel chunks.
fn synth_frames(
    seq: &dynapix_synth::Sequence,
    n: usize,
) -> impl Iterator<Item = (f64, GrayImage, DepthImage)> + '_ {
    const CHUNK: usize = 16;
    (0..n.div_ceil(CHUNK)).flat_map(move |c| {
        let idx: Vec<usize> = (c * CHUNK..((c + 1) * CHUNK).min(n)).collect();
        let out: Vec<(f64, GrayImage, DepthImage)> =
            idx.par_iter()
                .map(|&i| {
                    let (f, _) = seq.frame(i, None);
                    let gray = rgb_to_gray_orbslam(&f.rgb);
                    let depth = DepthImage::from_fn(f.depth.width(), f.depth.height(), |x, y| {
                        Luma([f.depth.get_pixel(x, y)[0] as f32
                            / dynapix_synth::sequence::DEPTH_FACTOR])
                    });
                    (seq.time(i), gray, depth)
                })
                .collect();
        out
    })
}

fn angle_deg(t: &Se3) -> f64 {
    t.rotation.angle().to_degrees()
}

#[test]
fn loop_preset_closes_its_loop_with_the_ground_truth_transform() {
    // One loop takes 400 frames (13.3 s); the camera goes on for another 120 frames past its
    // start so that several keyframes revisit the first part of the sequence.
    let (seq, cam) = synth_sequence("loop", 400);
    let run = run_sequence(cam, synth_frames(&seq, 520));
    run.summary("loop");
    assert!(!run.found.is_empty(), "no loop accepted");
    for f in &run.found {
        // The loop keyframe is from the beginning of the first lap, the current one from its
        // end or the second lap.
        assert!(
            f.loop_frame < 150,
            "loop keyframe at frame {}",
            f.loop_frame
        );
        assert!(
            f.cur_frame > 300,
            "current keyframe at frame {}",
            f.cur_frame
        );
        // Ground truth T_cm mapped through the estimated loop-keyframe pose.
        let gt_cur = seq.pose(f.cur_frame as usize);
        let gt_loop = seq.pose(f.loop_frame as usize);
        let t_cm = gt_cur.inverse() * gt_loop;
        let expected = t_cm * f.loop_pose;
        let d = f.m.corrected_pose * expected.inverse();
        let dc = (f.m.corrected_pose.inverse().translation.vector
            - expected.inverse().translation.vector)
            .norm();
        let before = (f.cur_pose.inverse().translation.vector
            - expected.inverse().translation.vector)
            .norm();
        eprintln!(
            "loop kf{}→kf{}: corrected pose vs GT: {:.4} m, {:.3}°; uncorrected: {:.4} m, {:.3}°",
            f.cur_seq,
            f.loop_seq,
            dc,
            angle_deg(&d),
            before,
            angle_deg(&(f.cur_pose * expected.inverse()))
        );
        assert!(dc < 0.03, "corrected pose {dc} m from ground truth");
        assert!(angle_deg(&d) < 1.5, "corrected pose {}° off", angle_deg(&d));
    }
}

fn assert_no_loop(name: &str, run: &Run) {
    run.summary(name);
    assert!(
        run.found.is_empty(),
        "{name}: false loop(s) accepted: {:?}",
        run.found
            .iter()
            .map(|f| (f.cur_frame, f.loop_frame))
            .collect::<Vec<_>>()
    );
}

#[test]
fn no_false_loops_on_walking_presets() {
    for preset in ["walking_xyz", "walking_halfsphere"] {
        let (seq, cam) = synth_sequence(preset, 300);
        let run = run_sequence(cam, synth_frames(&seq, 300));
        assert_no_loop(preset, &run);
    }
}

fn fr1_xyz() -> Option<PathBuf> {
    let d = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/tum/rgbd_dataset_freiburg1_xyz"
    ));
    if d.join("rgb.txt").exists() && d.join("depth.txt").exists() {
        Some(d)
    } else {
        eprintln!(
            "skipping the fr1_xyz false-loop test: {} not found",
            d.display()
        );
        None
    }
}

fn read_tum_frames(dir: &Path) -> Vec<(f64, PathBuf, PathBuf)> {
    use dynapix_io::tum::{DEFAULT_MAX_DIFF, associate_nearest, read_list, resolve_path};
    let rgb = read_list(dir.join("rgb.txt")).expect("rgb.txt");
    let depth = read_list(dir.join("depth.txt")).expect("depth.txt");
    associate_nearest(&rgb, &depth, DEFAULT_MAX_DIFF)
        .into_iter()
        .map(|a| {
            (
                a.t_rgb,
                resolve_path(dir, &a.rgb),
                resolve_path(dir, &a.depth),
            )
        })
        .collect()
}

#[test]
fn no_false_loops_on_fr1_xyz() {
    let Some(dir) = fr1_xyz() else { return };
    let st = dynapix_io::Settings::tum1();
    let cam = RgbdCamera::new(st.camera(), st.bf, st.th_depth, st.fps);
    let list = read_tum_frames(&dir);
    let factor = st.depth_map_factor;
    let frames = list.chunks(16).flat_map(move |chunk| {
        let out: Vec<(f64, GrayImage, DepthImage)> = chunk
            .par_iter()
            .map(|(t, r, d)| {
                let (rgb, depth) =
                    dynapix_io::images::read_rgbd(r, d, factor).expect("fr1_xyz frame");
                (*t, rgb_to_gray_orbslam(&rgb), depth)
            })
            .collect();
        out
    });
    let run = run_sequence(cam, frames);
    assert_no_loop("fr1_xyz", &run);
}
