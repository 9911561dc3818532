//! Loop detection on whole sequences: the SLAM system runs frame by frame (embedded
//! vocabulary) and two detectors are called on every new keyframe. Generated data comes from
//! `dynapix-synth` (the `loop` preset must close its loop, the walking presets must not), real
//! data from `../shared/data` fr1_xyz (skipped with a message when missing).

use std::path::{Path, PathBuf};

use dynapix_geometry::{PinholeCamera, Se3};
use image::GrayImage;
use rayon::prelude::*;

use super::{DetectionDiagnostics, DetectionOutcome, DetectionParams, LoopDetector};
use crate::camera::RgbdCamera;
use crate::features::FeatureExtractor;
use crate::features::ScalePyramid;
use crate::features::{Descriptor, KeyPoint};
use crate::frame::DepthImage;
use crate::loop_closing::LoopMatch;
use crate::map::{KeyFrame, Map, MapParams};
use crate::orb::{OrbExtractor, OrbParams, rgb_to_gray_orbslam};
use crate::system::{FrameInput, System, SystemParams};
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
    /// Frame index of each examined keyframe.
    frames: Vec<u64>,
    /// Wall time of the first detector's calls (measurement only).
    detect_seconds: f64,
    /// Wall time of the calls that accepted a loop, ms (measurement only).
    accepted_ms: Vec<f64>,
    /// The system at the end of the run (its map).
    system: Option<System<Orb>>,
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
             accepted {}; detection {:.1} ms per keyframe, accepting calls {:?} ms",
            self.keyframes,
            self.diags.len(),
            self.count(DetectionOutcome::TooSoon),
            self.count(DetectionOutcome::NoCandidates),
            self.count(DetectionOutcome::NotConsistent),
            self.count(DetectionOutcome::GeometryRejected),
            self.count(DetectionOutcome::TooFewTotalMatches),
            self.count(DetectionOutcome::Accepted),
            1e3 * self.detect_seconds / self.diags.len().max(1) as f64,
            self.accepted_ms,
        );
        for (d, f) in self.diags.iter().zip(&self.frames) {
            if !d.candidates.is_empty() {
                eprintln!(
                    "  {name} kf{} (frame {f}): candidates {:?}, {} groups, {} consistent, {:?}",
                    d.seq,
                    d.candidate_seqs,
                    d.consistent_groups,
                    d.consistent_candidates.len(),
                    d.outcome
                );
            }
        }
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
    stop_at_first_loop: bool,
) -> Run {
    let vocab = Vocabulary::embedded_default().expect("embedded vocabulary");
    let orb = OrbExtractor::new(OrbParams::default()).expect("ORB extractor");
    // The system's own loop closer is off: these detectors must see the uncorrected map.
    let mut params = SystemParams::default();
    params.loop_closing.enabled = false;
    let mut system = System::new(Orb(orb), cam.clone(), params).with_vocabulary(vocab.clone());
    let mut a = LoopDetector::new(cam.clone(), DetectionParams::default());
    let mut b = LoopDetector::new(cam, DetectionParams::default());
    let mut run = Run::default();
    let mut detect_time = std::time::Duration::ZERO;
    for (t, gray, depth) in frames {
        let res = system
            .process(FrameInput {
                timestamp: t,
                gray: &gray,
                depth: &depth,
                weights: None,
                masks: None,
            })
            .expect("frames of the camera's size");
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
        let t0 = std::time::Instant::now();
        let ra = a.detect(map, kf, Some(&vocab));
        let dt = t0.elapsed();
        detect_time += dt;
        if ra.is_some() {
            run.accepted_ms.push(dt.as_secs_f64() * 1e3);
        }
        let rb = b.detect(map, kf, Some(&vocab));
        assert_eq!(ra, rb, "two detectors disagree");
        assert_eq!(a.last_diagnostics(), b.last_diagnostics());
        run.diags.push(a.last_diagnostics().clone());
        run.frames.push(map.keyframe(kf).map_or(0, |k| k.frame_id));
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
            if stop_at_first_loop {
                break;
            }
        }
    }
    run.detect_seconds = detect_time.as_secs_f64();
    run.system = Some(system);
    run
}

/// A synthetic sequence at 320×240 (the CLI's scaling of the fr3 intrinsics).
fn synth_sequence(preset: &str, frames: usize) -> (dynapix_synth::Sequence, RgbdCamera) {
    let preset: dynapix_synth::Preset = preset.parse().expect("preset");
    let params = dynapix_synth::SynthParams::at_size(preset, frames, 0, 320, 240);
    let seq = dynapix_synth::Sequence::new(params).expect("sequence");
    let st = dynapix_synth::output::camera_settings(&seq.params.camera, seq.params.fps);
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
        let out: Vec<(f64, GrayImage, DepthImage)> = idx
            .par_iter()
            .map(|&i| {
                let (f, _) = seq.frame(i, None);
                let gray = rgb_to_gray_orbslam(&f.rgb);
                let depth = f.depth_metres();
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
    // A 600-frame `loop` sequence has a 400-frame lap (13.3 s, 1.5 laps); only its first
    // 520 frames are rendered, so that enough keyframes revisit the beginning; the run stops
    // at the first accepted loop (keyframe 13 at frame 369, inside the lap).
    let (seq, cam) = synth_sequence("loop", 600);
    let run = run_sequence(cam, synth_frames(&seq, 520), true);
    run.summary("loop");
    assert!(!run.found.is_empty(), "no loop accepted");
    for f in &run.found {
        // The loop keyframe is from the beginning of the lap, the current one from its end.
        assert!(
            f.loop_frame < 100,
            "loop keyframe at frame {}",
            f.loop_frame
        );
        assert!(
            f.cur_frame > 300,
            "current keyframe at frame {}",
            f.cur_frame
        );
        let gt_cur = seq.pose(f.cur_frame as usize);
        let gt_loop = seq.pose(f.loop_frame as usize);
        let t_cm = gt_cur.inverse() * gt_loop;
        // A real revisit: the two views are close in ground truth.
        assert!(t_cm.translation.vector.norm() < 0.6 && angle_deg(&t_cm) < 50.0);
        // Ground-truth T_cm mapped through the estimated loop-keyframe pose.
        let expected = t_cm * f.loop_pose;
        let d = f.m.corrected_pose * expected.inverse();
        let center = |t: &Se3| t.inverse().translation.vector;
        let dc = (center(&f.m.corrected_pose) - center(&expected)).norm();
        let before = (center(&f.cur_pose) - center(&expected)).norm();
        eprintln!(
            "loop kf{}→kf{}: GT relative motion {:.3} m, {:.1}°; corrected pose vs GT {:.4} m, \
             {:.3}°; tracked pose vs GT {:.4} m, {:.3}°",
            f.cur_seq,
            f.loop_seq,
            t_cm.translation.vector.norm(),
            angle_deg(&t_cm),
            dc,
            angle_deg(&d),
            before,
            angle_deg(&(f.cur_pose * expected.inverse()))
        );
        // The map points behind the estimate carry a few centimetres of depth noise at
        // 2.5-3 m, which leaves a coupled rotation/translation error of about 1.5° / 8 cm
        // for the wide-baseline revisit found today.
        assert!(dc < 0.12, "corrected pose {dc} m from ground truth");
        assert!(angle_deg(&d) < 2.5, "corrected pose {}° off", angle_deg(&d));
    }
    verification_rejects_other_places(&run, &seq);
}

/// Forces the geometric verification of the loop's current keyframe against every other
/// keyframe of the map (bypassing the database and the consistency test): keyframes whose
/// ground-truth view points elsewhere (> 75° apart) must be rejected, and anything accepted
/// must be a real revisit (< 60°).
fn verification_rejects_other_places(run: &Run, seq: &dynapix_synth::Sequence) {
    let (Some(system), Some(f)) = (&run.system, run.found.first()) else {
        return;
    };
    let map = system.map();
    let cur = f.m.current;
    let Some(ck) = map.keyframe(cur) else { return };
    let gt_cur = seq.pose(ck.frame_id as usize);
    let (mut far, mut near_ok) = (0, 0);
    for (id, k) in map.keyframes_sorted() {
        if id == cur || ck.connections.contains_key(&id) {
            continue;
        }
        let mut det = LoopDetector::new(system.camera().clone(), DetectionParams::default());
        let got = det.compute_se3(map, cur, &[id]);
        let rel = gt_cur.inverse() * seq.pose(k.frame_id as usize);
        let ang = angle_deg(&rel);
        let t = det
            .last_diagnostics()
            .trials
            .first()
            .cloned()
            .unwrap_or_default();
        // Error of the estimate against the ground-truth relative pose (as in the loop test).
        let err = got.as_ref().map(|m| {
            let expected = rel * k.pose;
            let c = |t: &Se3| t.inverse().translation.vector;
            (
                (c(&m.corrected_pose) - c(&expected)).norm(),
                angle_deg(&(m.corrected_pose * expected.inverse())),
            )
        });
        eprintln!(
            "  forced kf{}→kf{} (GT {:.0}°, {:.2} m): bow {} ransac {} refined {} total {} → {} {err:.3?}",
            ck.seq,
            k.seq,
            ang,
            rel.translation.vector.norm(),
            t.bow_matches,
            t.ransac_inliers,
            t.refined_inliers,
            det.last_diagnostics().total_matches,
            if got.is_some() {
                "accepted"
            } else {
                "rejected"
            }
        );
        if ang > 75.0 {
            far += 1;
            assert!(got.is_none(), "kf{} accepted a view {ang:.0}° away", k.seq);
        }
        if let Some((dc, da)) = err {
            assert!(ang < 60.0, "kf{} accepted a view {ang:.0}° away", k.seq);
            // Wide baselines (up to ~45°) let depth errors of the map points through the χ²
            // test, hence the loose bound; see the loop test.
            assert!(
                dc < 0.25 && da < 5.0,
                "kf{}: estimate {dc} m, {da}° off",
                k.seq
            );
            near_ok += 1;
        }
    }
    eprintln!("forced verification: {far} distant keyframes rejected, {near_ok} near accepted");
    assert!(far >= 3, "too few distant keyframes to test");
    assert!(near_ok >= 1);
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
        let run = run_sequence(cam, synth_frames(&seq, 300), false);
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
    let run = run_sequence(cam, frames, false);
    assert_no_loop("fr1_xyz", &run);
}

/// A keyframe with `n` keypoints and the given bag-of-words words (equal weights).
fn small_keyframe(n: usize, words: &[u32]) -> KeyFrame {
    let kp = KeyPoint {
        x: 10.0,
        y: 10.0,
        angle: 0.0,
        response: 1.0,
        octave: 0,
        size: 31.0,
    };
    let w = 1.0 / words.len().max(1) as f64;
    KeyFrame {
        seq: 0,
        frame_id: 0,
        timestamp: 0.0,
        pose: Se3::identity(),
        keys: vec![kp; n],
        keys_un: vec![kp; n],
        descriptors: vec![[0; 32]; n],
        depth: vec![1.0; n],
        u_right: vec![5.0; n],
        weights: vec![1.0; n],
        dynamic_class: vec![false; n],
        map_points: vec![None; n],
        grid: crate::frame::FeatureGrid::empty(),
        bow: words.iter().map(|&x| (x, w)).collect(),
        feat: vec![],
        connections: Default::default(),
        ordered: vec![],
        parent: None,
        children: Default::default(),
        loop_edges: Default::default(),
    }
}

fn small_camera() -> RgbdCamera {
    RgbdCamera::new(
        PinholeCamera::new(320, 240, 260.0, 260.0, 160.0, 120.0),
        40.0,
        40.0,
        30.0,
    )
}

#[test]
fn database_skips_and_prunes_culled_keyframes() {
    let mut map = Map::new(ScalePyramid::new(8, 1.2), MapParams::default());
    let words = [1, 2, 3, 4, 5, 6];
    let ids: Vec<_> = (0..4)
        .map(|_| map.insert_keyframe(small_keyframe(4, &words)))
        .collect();
    let mut db = super::database::KeyFrameDatabase::default();
    for &id in &ids[..3] {
        db.add(id, map.keyframe(id).unwrap());
    }
    let settings = super::database::CandidateSettings {
        common_words_ratio: 0.8,
        accumulated_score_ratio: 0.75,
        covisibles: 10,
    };
    let q = ids[3];
    let cands = db.loop_candidates(&map, q, &map.keyframe(q).unwrap().clone(), 0.5, &settings);
    assert_eq!(cands, vec![ids[0], ids[1], ids[2]]);
    map.cull_keyframe(ids[1]);
    // The freed slot is reused by a new keyframe: the old id must stay stale.
    let reuse = map.insert_keyframe(small_keyframe(4, &[9]));
    assert!(map.keyframe(ids[1]).is_none() && map.keyframe(reuse).is_some());
    assert_eq!(db.entries(), 3 * words.len());
    let cands = db.loop_candidates(&map, q, &map.keyframe(q).unwrap().clone(), 0.5, &settings);
    assert_eq!(cands, vec![ids[0], ids[2]], "culled keyframe returned");
    assert_eq!(db.entries(), 2 * words.len(), "stale entries not pruned");
}

#[test]
fn without_vocabulary_or_too_soon_nothing_is_detected() {
    let mut map = Map::new(ScalePyramid::new(8, 1.2), MapParams::default());
    let vocab = Vocabulary::embedded_default().expect("embedded vocabulary");
    let mut det = LoopDetector::new(small_camera(), DetectionParams::default());
    let mut last = None;
    for _ in 0..12 {
        let id = map.insert_keyframe(small_keyframe(4, &[]));
        assert_eq!(det.detect(&map, id, None), None);
        assert_eq!(
            det.last_diagnostics().outcome,
            DetectionOutcome::NoVocabulary
        );
        last = Some(id);
    }
    // With a vocabulary but within 10 keyframes of a loop: skipped.
    let id = map.insert_keyframe(small_keyframe(4, &[1, 2]));
    det.loop_closed(&map, last.unwrap());
    assert_eq!(det.detect(&map, id, Some(&vocab)), None);
    assert_eq!(det.last_diagnostics().outcome, DetectionOutcome::TooSoon);
    det.reset();
    assert_eq!(det.last_diagnostics().outcome, DetectionOutcome::NotRun);
}
