//! One SLAM pass over a sequence: the ORB-SLAM2-class system of `dynapix-slam` fed frame by
//! frame, optionally with static weights (DynaPix) and semantic masks (DynaPix+), and what a
//! pass leaves: the trajectory, per-frame status and timing, keyframes, closed loops.
//!
//! Images (and weight maps) are decoded, converted to grey and their ORB features extracted
//! on a helper thread a few frames ahead of tracking (extraction depends on nothing but the
//! frame); the system itself runs tracking, mapping and loop closing in a fixed order on the
//! calling thread, so a pass is deterministic.

use std::path::{Path, PathBuf};
use std::time::Instant;

use dynapix_io::images::read_mask;
use dynapix_io::{DepthImage, FrameStatus, StampedPose, StampedStatus, StaticWeights, Trajectory};
use dynapix_slam::orb::{OrbExtractor, rgb_to_gray_orbslam};
use dynapix_slam::system::{FrameInput, FrameResult, System, SystemParams};
use dynapix_slam::tracking::TrackingState;
use dynapix_slam::vocab::Vocabulary;
use dynapix_slam::{FeatureStage, Features};
use image::{GrayImage, RgbImage};

use crate::config::VocabularyChoice;
use crate::error::{BadFrame, Error, Result};
use crate::input::{Camera, Input};
use crate::observe::{FrameView, PassInfo, RunObserver, StageTimes};
pub use crate::pass::{FrameTiming, PassOutput, PassStats};
use crate::progress::{Progress, Task};
use crate::store::MapSet;

/// The status-file value of a tracking state.
pub fn frame_status(state: TrackingState) -> FrameStatus {
    match state {
        TrackingState::Ok => FrameStatus::Tracked,
        TrackingState::Lost => FrameStatus::Lost,
        TrackingState::NotInitialized => FrameStatus::NotInitialized,
    }
}

/// Loads the vocabulary of a run.
pub fn load_vocabulary(choice: &VocabularyChoice) -> Result<Option<Vocabulary>> {
    match choice {
        VocabularyChoice::None => Ok(None),
        VocabularyChoice::Embedded => {
            Vocabulary::embedded_default()
                .map(Some)
                .map_err(|source| Error::Vocabulary {
                    path: PathBuf::from("<embedded>"),
                    source,
                })
        }
        VocabularyChoice::File(p) => {
            Vocabulary::load(p)
                .map(Some)
                .map_err(|source| Error::Vocabulary {
                    path: p.clone(),
                    source,
                })
        }
    }
}

/// A SLAM system being fed frames, with the bookkeeping of a pass.
pub struct SlamSession {
    system: System<OrbExtractor>,
    /// The system's feature extraction, for [`SlamSession::track`].
    features: FeatureStage<OrbExtractor>,
    status: Vec<StampedStatus>,
    timings: Vec<FrameTiming>,
    started: Instant,
    missing_weights: usize,
    skipped: Vec<BadFrame>,
}

impl SlamSession {
    /// A system for `camera` (its ORB settings and intrinsics) with `params`.
    pub fn new(
        camera: &Camera,
        params: SystemParams,
        vocabulary: Option<Vocabulary>,
    ) -> Result<Self> {
        let extractor = OrbExtractor::new(camera.orb_params()?)?;
        let mut system = System::new(extractor, camera.rgbd(), params);
        if let Some(v) = vocabulary {
            system = system.with_vocabulary(v);
        }
        Ok(Self {
            features: system.feature_stage(),
            system,
            status: Vec::new(),
            timings: Vec::new(),
            started: Instant::now(),
            missing_weights: 0,
            skipped: Vec::new(),
        })
    }

    /// The system.
    pub fn system(&self) -> &System<OrbExtractor> {
        &self.system
    }

    /// The system, mutably (e.g. to enter localisation mode before the first frame).
    pub fn system_mut(&mut self) -> &mut System<OrbExtractor> {
        &mut self.system
    }

    /// A short status of the map, for progress messages.
    pub fn summary(&self) -> String {
        let st = self.status.last().map_or("-", |s| s.status.as_str());
        format!(
            "{st} kf {} mp {}",
            self.system.map().num_keyframes(),
            self.system.map().num_points()
        )
    }

    /// A copy of the system's feature extraction, to extract frames ahead on another thread
    /// ([`SlamSession::track_features`]).
    pub fn feature_stage(&self) -> FeatureStage<OrbExtractor> {
        self.features.clone()
    }

    /// Tracks one frame whose grey image (from [`rgb_to_gray_orbslam`]) and features (from
    /// [`SlamSession::feature_stage`], with the same `weights`) were computed ahead: the same
    /// result as [`SlamSession::track`].
    pub fn track_features(
        &mut self,
        t: f64,
        gray: &GrayImage,
        features: Features,
        depth: &DepthImage,
        weights: Option<&StaticWeights>,
        mask: Option<&GrayImage>,
    ) -> Result<FrameResult> {
        let res = self.system.process_features(
            FrameInput {
                timestamp: t,
                gray,
                depth,
                weights,
                masks: mask,
            },
            features,
        )?;
        let st = frame_status(res.state);
        self.status.push(StampedStatus { t, status: st });
        self.timings.push(FrameTiming {
            index: res.index,
            timestamp: t,
            extract_ms: res.times.extract * 1e3,
            track_ms: res.times.track * 1e3,
            mapping_ms: res.times.mapping * 1e3,
            loop_ms: res.times.loop_closing * 1e3,
            keyframe: res.new_keyframe,
            status: st,
        });
        Ok(res)
    }

    /// Loads the saved map `path` (`dynapix_slam::persist`), checks it against this
    /// session's camera (with `depth_factor`), ORB pyramid and vocabulary, and switches the
    /// system to localisation mode on it (only tracking against the map). Errors name the
    /// file.
    pub fn load_map(&mut self, path: &Path, depth_factor: f64) -> Result<MapFileStats> {
        use dynapix_slam::persist::{PersistError, decode};
        let t0 = Instant::now();
        let bytes = std::fs::read(path).map_err(|source| PersistError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let t1 = Instant::now();
        let saved = decode(&bytes).map_err(|source| Error::Map {
            context: format!("cannot load map {}", path.display()),
            source,
        })?;
        let system = &mut self.system;
        let pyramid = system.map().pyramid.clone();
        saved
            .check_compatible(system.camera(), depth_factor, &pyramid, system.vocabulary())
            .map_err(|source| Error::Map {
                context: format!("cannot use map {} for this run", path.display()),
                source,
            })?;
        let t2 = Instant::now();
        let (keyframes, points) = (saved.num_keyframes(), saved.num_points());
        let params = system.map().params.clone();
        system.enter_localization(saved.into_map(params));
        let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
        Ok(MapFileStats {
            keyframes,
            points,
            bytes: bytes.len(),
            steps_ms: vec![
                ("read", ms(t0, t1)),
                ("decode + check", ms(t1, t2)),
                ("rebuild", t2.elapsed().as_secs_f64() * 1e3),
            ],
        })
    }

    /// Encodes the system's map (`dynapix_slam::persist`, with `depth_factor`) and writes it
    /// atomically to `path`.
    pub fn save_map(&self, path: &Path, depth_factor: f64) -> Result<MapFileStats> {
        let context = || format!("cannot save map {}", path.display());
        let system = &self.system;
        let t0 = Instant::now();
        let bytes = dynapix_slam::persist::encode(
            system.map(),
            system.camera(),
            depth_factor,
            system.vocabulary(),
        )
        .map_err(|source| Error::Map {
            context: context(),
            source,
        })?;
        let t1 = Instant::now();
        dynapix_io::write_atomic(path, &bytes).map_err(|e| Error::file(path, e.to_string()))?;
        Ok(MapFileStats {
            keyframes: system.map().num_keyframes(),
            points: system.map().num_points(),
            bytes: bytes.len(),
            steps_ms: vec![
                ("encode", (t1 - t0).as_secs_f64() * 1e3),
                ("write", t1.elapsed().as_secs_f64() * 1e3),
            ],
        })
    }

    /// Ends the sequence (the system's final refinement, if its parameters ask for one).
    pub fn finish(&mut self) {
        if let Some(g) = self.system.finish() {
            tracing::info!(
                "final global BA: {} observations, {} outliers",
                g.edges,
                g.outliers
            );
        }
    }

    /// Records a frame that is not tracked because its files cannot be used: lost in the
    /// status, listed in the pass's output; the system goes on with the next frame.
    pub fn skip(&mut self, bad: BadFrame) {
        self.status.push(StampedStatus {
            t: bad.timestamp,
            status: FrameStatus::Lost,
        });
        self.skipped.push(bad);
    }

    /// Counts a frame that ran unweighted because its map was missing.
    pub fn note_missing_weights(&mut self) {
        self.missing_weights += 1;
    }

    /// What the pass has produced so far.
    pub fn output(&self) -> PassOutput {
        let trajectory = Trajectory::new(
            self.system
                .trajectory()
                .into_iter()
                .filter_map(|e| e.pose_wc.map(|p| StampedPose::new(e.timestamp, p)))
                .collect(),
        );
        let keyframes = Trajectory::new(
            self.system
                .keyframe_trajectory()
                .into_iter()
                .map(|(t, p)| StampedPose::new(t, p))
                .collect(),
        );
        let tracked = self
            .status
            .iter()
            .filter(|s| s.status == FrameStatus::Tracked)
            .count();
        PassOutput {
            trajectory,
            status: self.status.clone(),
            keyframes,
            loops: self.system.loop_events().to_vec(),
            timings: self.timings.clone(),
            stats: PassStats {
                frames: self.status.len(),
                tracked,
                keyframes: self.system.map().num_keyframes(),
                map_points: self.system.map().num_points(),
                loops_closed: self.system.loop_events().len(),
                seconds: self.started.elapsed().as_secs_f64(),
                frames_without_prob_map: self.missing_weights,
                frames_skipped: self.skipped.len(),
            },
            skipped: self.skipped.clone(),
        }
    }
}

/// A map file loaded or saved ([`crate::SlamPass::load_map`], [`crate::SlamPass::save_map`]):
/// its size and where the time went.
#[derive(Clone, Debug, PartialEq)]
pub struct MapFileStats {
    /// Keyframes in the map.
    pub keyframes: usize,
    /// Map points in the map.
    pub points: usize,
    /// Size of the file.
    pub bytes: usize,
    /// Milliseconds per step, in order (loading: `read`, `decode + check`, `rebuild`;
    /// saving: `encode`, `write`).
    pub steps_ms: Vec<(&'static str, f64)>,
}

/// The weights of a pass.
#[derive(Clone, Copy, Debug)]
pub enum PassWeights<'a> {
    /// None (ORB-SLAM2).
    None,
    /// Probability maps of the frames (in memory or in a folder).
    Maps {
        /// The maps.
        maps: &'a MapSet,
        /// Threshold ablation: P > γ drops a keypoint, the rest weighs 1.
        threshold: Option<f32>,
        /// A missing map runs its frame unweighted (counted) instead of stopping the pass.
        allow_missing: bool,
    },
}

/// A frame's grey image, depth and features, ready for tracking.
struct Prepared {
    /// The colour image, kept only for an observer that wants it.
    rgb: Option<RgbImage>,
    gray: GrayImage,
    depth: DepthImage,
    features: Features,
}

/// One decoded frame of a pass.
struct Decoded {
    t: f64,
    images: Result<Prepared>,
    weights: Result<Option<StaticWeights>>,
    mask: Result<Option<GrayImage>>,
    missing: bool,
}

/// Decodes frame `i` and, when its images and weights are usable, extracts its features with
/// `stage` (which depends on nothing but the frame, so this can run ahead of tracking).
fn decode(
    input: &Input,
    i: usize,
    weights: PassWeights<'_>,
    masks: Option<&Path>,
    stage: &mut FeatureStage<OrbExtractor>,
    keep_rgb: bool,
) -> Decoded {
    let t = input.sequence.frames[i].t;
    let (rgb, depth) = match input.load_rgbd(i) {
        Ok(images) => images,
        Err(e) => {
            // The frame is skipped or stops the pass: its map and mask do not matter.
            return Decoded {
                t,
                images: Err(e),
                weights: Ok(None),
                mask: Ok(None),
                missing: false,
            };
        }
    };
    let name = input.map_name(i);
    let mut missing = false;
    let weights = match (weights, &name) {
        (PassWeights::None, _) => Ok(None),
        (PassWeights::Maps { .. }, None) => {
            Err(Error::Input(format!("frame {i} has no file name")))
        }
        (
            PassWeights::Maps {
                maps,
                threshold,
                allow_missing,
            },
            Some(_),
        ) => match maps.static_weights(input, i) {
            Ok(Some(w)) => Ok(Some(match threshold {
                Some(g) => w.thresholded(g),
                None => w,
            })),
            Ok(None) if allow_missing => {
                missing = true;
                Ok(None)
            }
            Ok(None) => Err(maps.missing(input, i)),
            Err(e) => Err(e),
        },
    };
    let mask = match masks {
        None => Ok(None),
        Some(d) => match input.sequence.rgb_name(i) {
            Some(n) => read_mask(d.join(n)).map(Some).map_err(Error::from),
            None => Err(Error::Input(format!("frame {i} has no file name"))),
        },
    };
    let gray = rgb_to_gray_orbslam(&rgb);
    let rgb = keep_rgb.then_some(rgb);
    let features = match &weights {
        Ok(w) => {
            // Every pass detects the same FAST corners on this image: reuse them.
            let mut corners = input.fast_corners(i);
            let f = stage.extract_cached(&gray, w.as_ref(), &mut corners);
            if let Some(c) = corners {
                input.keep_fast_corners(i, c);
            }
            f
        }
        // The pass stops at this frame: no features needed.
        Err(_) => Features {
            keys: Vec::new(),
            descriptors: Vec::new(),
            seconds: 0.0,
        },
    };
    Decoded {
        t,
        images: Ok(Prepared {
            rgb,
            gray,
            depth,
            features,
        }),
        weights,
        mask,
        missing,
    }
}

/// Reader threads of a SLAM pass ([`Input::stream_parallel`]).
const PASS_READERS: usize = 2;

/// An observer of a pass, the pass's number in the run ([`PassInfo::number`]) and whether it
/// is the run's last pass ([`PassInfo::last`]).
#[derive(Clone, Copy)]
pub struct Watch<'a> {
    /// The observer.
    pub observer: &'a dyn RunObserver,
    /// The pass's number in the run, from 1.
    pub number: usize,
    /// The pass is the run's last one (its trajectory is the result).
    pub last: bool,
}

/// Runs `session` over every frame of `input` with `weights` and DynaPix+ `masks` (a folder of
/// masks named like the rgb images), reporting progress as `label`.
///
/// A frame whose rgb or depth file cannot be used is skipped when `input` skips bad frames
/// ([`SlamSession::skip`]: lost, listed in [`PassOutput::skipped`]), its weight map and mask
/// unread. Otherwise, and for any other error, the pass stops there with
/// [`Error::Stopped`], which keeps the pass up to the frame before.
///
/// Shown to an observer (`watch`): the pass's start and end and every tracked frame; with
/// one the results are the same.
pub fn run_pass_observed(
    input: &Input,
    session: &mut SlamSession,
    weights: PassWeights<'_>,
    masks: Option<&Path>,
    label: &str,
    progress: &dyn Progress,
    watch: Option<Watch<'_>>,
) -> Result<PassOutput> {
    let pinhole = input.camera.pinhole();
    let info = watch.map(|w| PassInfo {
        number: w.number,
        label,
        frames: input.len(),
        camera: &pinhole,
        ground_truth: input.sequence.groundtruth.as_ref(),
        weighted: matches!(weights, PassWeights::Maps { .. }),
        last: w.last,
    });
    let keep_rgb = match (watch, &info) {
        (Some(w), Some(info)) => w.observer.wants_images(info),
        _ => false,
    };
    if let (Some(w), Some(info)) = (watch, &info) {
        session.system_mut().record_removed_points(true);
        w.observer.pass_begins(info);
    }
    let n = input.len();
    let task = Task::begin(progress, label, n);
    let stage = session.feature_stage();
    // Two readers: one frame's decoding, weight map and feature extraction overlap the
    // next one's (a single reader was the pass's bottleneck, not tracking). Each has its
    // own copy of the extraction, which depends on nothing but the frame.
    let fed = input.stream_parallel(
        2,
        PASS_READERS,
        || {
            let mut stage = stage.clone();
            move |i| decode(input, i, weights, masks, &mut stage, keep_rgb)
        },
        |i, d| -> Result<()> {
            let prepared = match d.images {
                Ok(images) => images,
                Err(Error::Frame(bad)) if input.skip_bad_frames => {
                    tracing::warn!("skipped {bad}");
                    session.skip(bad);
                    task.step(&session.summary());
                    return Ok(());
                }
                Err(e) => return Err(e),
            };
            let (w, m) = (d.weights?, d.mask?);
            if d.missing {
                session.note_missing_weights();
            }
            let res = session.track_features(
                d.t,
                &prepared.gray,
                prepared.features,
                &prepared.depth,
                w.as_ref(),
                m.as_ref(),
            )?;
            if let Some(watch) = watch {
                let times = StageTimes {
                    motion_ms: None,
                    extract_ms: res.times.extract * 1e3,
                    track_ms: res.times.track * 1e3,
                    mapping_ms: res.times.mapping * 1e3,
                    loop_ms: res.times.loop_closing * 1e3,
                };
                watch.observer.frame(&FrameView::new(
                    i,
                    d.t,
                    &res,
                    prepared.rgb.as_ref(),
                    &prepared.depth,
                    w.as_ref(),
                    times,
                    session.system(),
                ));
            }
            task.step(&session.summary());
            Ok(())
        },
    );
    drop(task);
    let out = match fed {
        Ok(()) => {
            session.finish();
            Ok(session.output())
        }
        Err(error) => Err(Error::Stopped {
            label: label.to_string(),
            error: Box::new(error),
            partial: Box::new(session.output()),
        }),
    };
    if let (Some(w), Some(info)) = (watch, &info) {
        session.system_mut().record_removed_points(false);
        match &out {
            Ok(o) => w.observer.pass_ends(info, o),
            Err(Error::Stopped { partial, .. }) => w.observer.pass_ends(info, partial),
            Err(_) => {}
        }
    }
    out
}
