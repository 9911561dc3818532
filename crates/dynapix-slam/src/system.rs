//! The SLAM system: owns the map and the stages and runs them in a fixed order per frame
//! (feature extraction, tracking, then local mapping and loop closing on a new keyframe), so the same input
//! always gives the same trajectory (design §7, spec §7.22). Frame poses are stored relative
//! to their reference keyframe and recomposed on demand, so later BA corrections reach them
//! (ORB-SLAM2 `SaveTrajectoryTUM`).

use std::time::Instant;

use dynapix_geometry::Se3;
use image::GrayImage;

use dynapix_io::StaticWeights;

use crate::camera::{ImageBounds, RgbdCamera};
use crate::feature_stage::{FeatureStage, Features};
use crate::features::FeatureExtractor;
use crate::frame::{DepthImage, Frame};
use crate::ids::{KeyFrameId, MapPointId};
use crate::local_mapping::{LocalMapper, LocalMappingParams, MappingStats};
use crate::loop_closing::{LoopCloser, LoopClosingParams, LoopEvent};
use crate::map::{Map, MapParams};
use crate::tracking::{Tracker, TrackingParams, TrackingState};
use crate::vocab::Vocabulary;
use dynapix_optim::Observation;

/// Parameters of all stages.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SystemParams {
    /// Tracking.
    pub tracking: TrackingParams,
    /// Local mapping.
    pub mapping: LocalMappingParams,
    /// Map bookkeeping.
    pub map: MapParams,
    /// Loop closing.
    pub loop_closing: LoopClosingParams,
    /// DynaPix feature budget: with a weight map, keypoints are detected only where the static
    /// weight w = 1 − P is at least this value, so the extractor spends its whole budget on
    /// the static scene (None: everywhere, as ORB-SLAM2).
    pub static_features_min_weight: Option<f32>,
    /// Offline refinement at the end of a sequence: one robust, weighted global bundle
    /// adjustment over every keyframe and map point (see [`System::finish`]). ORB-SLAM2 runs a
    /// global BA only after a loop; off in ORB-SLAM2 mode.
    pub final_global_ba: bool,
    /// Offline refinement of every tracked frame that is not a keyframe, at the end of a
    /// sequence (see [`System::finish`]): its pose is optimised again (pose-only, weighted,
    /// with the outlier rounds of tracking) against the final positions of the map points it
    /// was tracked with, leaving out the points that were culled since (e.g. removed because
    /// they started moving). Off in ORB-SLAM2 mode.
    pub final_pose_refinement: bool,
}

impl SystemParams {
    /// These parameters with the DynaPix behaviour `p` (tracking, local and global BA and the
    /// map rules all follow [`crate::map::MapParams::dynapix`]).
    pub fn with_dynapix(mut self, p: crate::weighting::params::DynaPixParams) -> Self {
        self.map.dynapix = p;
        self
    }
}

/// One input frame.
pub struct FrameInput<'a> {
    /// Timestamp in seconds.
    pub timestamp: f64,
    /// Grey image.
    pub gray: &'a GrayImage,
    /// Depth in metres (0 = missing), registered to the grey image.
    pub depth: &'a DepthImage,
    /// Optional DynaPix static weights w = 1 − P (None = all 1).
    pub weights: Option<&'a StaticWeights>,
    /// Optional DynaPix+ semantic mask (non-zero = dynamic class; gates map-point birth only).
    pub masks: Option<&'a GrayImage>,
}

/// Why [`System::process`] refused a frame.
#[derive(Debug, thiserror::Error)]
pub enum ProcessError {
    /// A map given with the frame does not have the grey image's size.
    #[error(
        "frame {index} (t = {timestamp:.6}): {what} is {got:?}, the grey image is {expected:?}"
    )]
    SizeMismatch {
        /// Index of the frame in the input order.
        index: u64,
        /// Timestamp of the frame.
        timestamp: f64,
        /// Which input is wrong (`depth`, `weights`, `mask`).
        what: &'static str,
        /// The grey image's `(width, height)`.
        expected: (u32, u32),
        /// The map's `(width, height)`.
        got: (u32, u32),
    },
    /// The grey image does not have the camera's size.
    #[error("frame {index} (t = {timestamp:.6}): the image is {got:?}, the camera is {expected:?}")]
    ImageSize {
        /// Index of the frame in the input order.
        index: u64,
        /// Timestamp of the frame.
        timestamp: f64,
        /// The camera's `(width, height)`.
        expected: (u32, u32),
        /// The image's `(width, height)`.
        got: (u32, u32),
    },
}

/// Wall-clock time of the steps of one frame, in seconds (measurement only).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepTimes {
    /// Feature extraction.
    pub extract: f64,
    /// Tracking (frame construction, tracking, keyframe decision), without extraction.
    pub track: f64,
    /// Local mapping (0 when no keyframe was created).
    pub mapping: f64,
    /// Loop closing: detection, and correction when a loop was closed (0 without a keyframe).
    pub loop_closing: f64,
}

/// Result of processing one frame.
#[derive(Clone, Debug)]
pub struct FrameResult {
    /// Index of the frame in the input order.
    pub index: u64,
    /// Timestamp.
    pub timestamp: f64,
    /// State after the frame.
    pub state: TrackingState,
    /// Pose `T_cw` at the time of tracking (later BA may refine it; see
    /// [`System::trajectory`]).
    pub pose_cw: Option<Se3>,
    /// A keyframe was created from this frame.
    pub new_keyframe: bool,
    /// Keypoints extracted.
    pub num_keypoints: usize,
    /// Inlier map-point matches.
    pub inliers: usize,
    /// The map was reset (lost right after initialisation).
    pub reset: bool,
    /// The frame was relocalised against the map.
    pub relocalised: bool,
    /// Step timings.
    pub times: StepTimes,
    /// Local-mapping counters when a keyframe was processed.
    pub mapping: Option<MappingStats>,
    /// The loop closed at this frame's keyframe, if any.
    pub loop_closure: Option<LoopEvent>,
}

impl FrameResult {
    /// Reports the local mapping and loop closing of the frame's keyframe with the frame.
    fn add_mapping(&mut self, done: MappingOutcome) {
        self.times.mapping = done.mapping_seconds;
        self.times.loop_closing = done.loop_closing_seconds;
        self.mapping = Some(done.mapping);
        self.loop_closure = done.loop_closure;
    }
}

/// One trajectory entry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrajectoryEntry {
    /// Timestamp.
    pub timestamp: f64,
    /// State of the frame.
    pub state: TrackingState,
    /// Camera-to-world pose `T_wc` for tracked frames.
    pub pose_wc: Option<Se3>,
}

#[derive(Clone, Debug)]
struct Record {
    timestamp: f64,
    state: TrackingState,
    /// Reference keyframe and `T_cr`.
    relative: Option<(KeyFrameId, Se3)>,
    /// Absolute `T_cw` frozen at a map reset.
    frozen: Option<Se3>,
    /// The frame's inlier map-point matches (kept with
    /// [`SystemParams::final_pose_refinement`] for frames that are not keyframes).
    matches: Vec<(MapPointId, Observation)>,
}

/// Fewest surviving matches (and inliers) for [`System::refine_frame_poses`] to replace a
/// frame's pose (ORB-SLAM2's bar for a tracked frame, 30 inliers).
pub const MIN_REFINE_MATCHES: usize = 30;

/// A tracked frame's inlier map-point matches as pose-only observations.
fn frame_matches(f: &Frame, map: &Map) -> Vec<(MapPointId, Observation)> {
    let pyr = &map.pyramid;
    (0..f.len())
        .filter_map(|i| {
            let id = f.map_points[i]?;
            if f.outlier[i] {
                return None;
            }
            let kp = &f.keys_un[i];
            let ur = f.u_right[i];
            Some((
                id,
                Observation {
                    uv: [kp.x as f64, kp.y as f64],
                    u_right: (ur >= 0.0).then_some(ur as f64),
                    inv_sigma2: pyr.inv_sigma2_of(kp.octave as usize) as f64,
                    weight: f.weights[i] as f64,
                },
            ))
        })
        .collect()
}

/// The SLAM system.
pub struct System<E> {
    features: FeatureStage<E>,
    cam: RgbdCamera,
    bounds: ImageBounds,
    map: Map,
    tracker: Tracker,
    mapper: LocalMapper,
    closer: LoopCloser,
    records: Vec<Record>,
    next_index: u64,
    vocab: Option<Vocabulary>,
    /// Localisation mode: track a fixed map, never map (see [`System::from_map`]).
    localization: bool,
    /// See [`SystemParams::final_global_ba`].
    final_global_ba: bool,
    /// See [`SystemParams::final_pose_refinement`].
    final_pose_refinement: bool,
    /// Pose-only parameters of the final refinement (tracking's, with the map's weight mode).
    refine_params: dynapix_optim::PoseOnlyParams,
    /// A keyframe made by [`System::track_features`] whose local mapping and loop closing
    /// have not run yet, with the index of its frame.
    pending: Option<(u64, KeyFrameId)>,
}

/// What [`System::map_pending`] did: the local mapping and loop closing of one keyframe.
#[derive(Clone, Debug)]
pub struct MappingOutcome {
    /// Index of the frame the keyframe was made from.
    pub index: u64,
    /// Local-mapping counters.
    pub mapping: MappingStats,
    /// The loop closed at this keyframe, if any.
    pub loop_closure: Option<LoopEvent>,
    /// Wall-clock seconds of the local mapping (measurement only).
    pub mapping_seconds: f64,
    /// Wall-clock seconds of the loop closing (measurement only).
    pub loop_closing_seconds: f64,
}

impl<E: FeatureExtractor> System<E> {
    /// A system for `cam` using `extractor`.
    pub fn new(extractor: E, cam: RgbdCamera, params: SystemParams) -> Self {
        let pyramid = extractor.pyramid();
        Self {
            bounds: cam.image_bounds(),
            map: Map::new(pyramid, params.map.clone()),
            tracker: Tracker::new(cam.clone(), params.tracking.clone()),
            mapper: LocalMapper::new(cam.clone(), params.mapping.clone()),
            closer: LoopCloser::new(cam.clone(), params.loop_closing.clone()),
            features: FeatureStage {
                extractor,
                static_features_min_weight: params.static_features_min_weight,
            },
            cam,
            records: Vec::new(),
            next_index: 0,
            vocab: None,
            localization: false,
            final_global_ba: params.final_global_ba,
            final_pose_refinement: params.final_pose_refinement,
            refine_params: crate::weighting::pose_params(
                &params.tracking.pose,
                &params.map.dynapix,
            ),
            pending: None,
        }
    }

    /// Ends an offline sequence: with [`SystemParams::final_global_ba`], one robust weighted
    /// global bundle adjustment over the whole map, after which [`System::trajectory`] reports
    /// every frame relative to its refined reference keyframe. Returns the BA's counters
    /// (`None` when it is off, in localisation mode, or the map is empty).
    ///
    /// With [`SystemParams::final_pose_refinement`], afterwards every tracked non-keyframe
    /// frame is re-optimised against the final map ([`System::refine_frame_poses`]).
    pub fn finish(&mut self) -> Option<crate::loop_closing::correct::global_ba::Output> {
        self.map_pending();
        let ba = self.final_global_ba();
        if self.final_pose_refinement && !self.localization {
            let _stage =
                tracing::info_span!(target: "dynapix::stage", "final pose refinement").entered();
            let n = self.refine_frame_poses();
            tracing::info!("final pose refinement: {n} frames re-optimised against the final map");
        }
        ba
    }

    fn final_global_ba(&mut self) -> Option<crate::loop_closing::correct::global_ba::Output> {
        if !self.final_global_ba || self.localization || self.map.num_keyframes() < 2 {
            return None;
        }
        let _stage = tracing::info_span!(target: "dynapix::stage", "final global BA").entered();
        let params = crate::loop_closing::correct::CorrectionParams {
            global_ba_robust: true,
            ..self.closer.params().correction.clone()
        };
        Some(crate::loop_closing::correct::global_ba::run(
            &mut self.map,
            &self.cam,
            &params,
        ))
    }

    /// A system in localisation mode on a previously built `map` (e.g. from
    /// [`crate::persist::SavedMap::into_map`]): frames are relocalised into the map and then
    /// tracked against it; no keyframe, map point or local mapping is ever created
    /// (ORB-SLAM2 `ActivateLocalizationMode`). `vocab` must be the one the map was built with.
    pub fn from_map(
        extractor: E,
        cam: RgbdCamera,
        params: SystemParams,
        map: Map,
        vocab: Option<Vocabulary>,
    ) -> Self {
        let mut s = Self::new(extractor, cam, params);
        s.vocab = vocab;
        s.enter_localization(map);
        s
    }

    /// Switches to localisation mode on `map` (see [`System::from_map`]), replacing the current
    /// map and tracking state; meant to be called before the first frame. Poses of frames
    /// already processed are frozen.
    pub fn enter_localization(&mut self, map: Map) {
        self.map_pending();
        self.freeze_records();
        self.map = map;
        let removed = self.tracker.removed.take();
        self.tracker = Tracker::new(self.cam.clone(), self.tracker.params.clone());
        self.tracker.removed = removed;
        self.mapper.reset();
        self.localization = true;
    }

    /// True in localisation mode.
    pub fn is_localization(&self) -> bool {
        self.localization
    }

    /// The vocabulary, if any.
    pub fn vocabulary(&self) -> Option<&Vocabulary> {
        self.vocab.as_ref()
    }

    /// Uses `vocab` for bag-of-words matching and relocalisation candidates (without one,
    /// keyframe matching is brute force and relocalisation tries the most recent keyframes).
    pub fn with_vocabulary(mut self, vocab: Vocabulary) -> Self {
        self.vocab = Some(vocab);
        self
    }

    /// The map. After [`System::track_features`] it lacks the local mapping and loop closing
    /// of the newest keyframe until [`System::map_pending`] (or the next frame) runs them.
    pub fn map(&self) -> &Map {
        &self.map
    }

    /// The camera.
    pub fn camera(&self) -> &RgbdCamera {
        &self.cam
    }

    /// Tracking state.
    pub fn state(&self) -> TrackingState {
        self.tracker.state()
    }

    /// The last frame tracking saw (keypoints, weights, map-point matches and outlier flags
    /// as tracking left them), for a viewer.
    pub fn last_frame(&self) -> Option<&crate::frame::Frame> {
        self.tracker.last_frame()
    }

    /// Records (or stops recording) the map points removed as moving at each frame
    /// ([`System::removed_points`]); off by default (nothing recorded, no cost).
    pub fn record_removed_points(&mut self, on: bool) {
        self.tracker.record_removed_points(on);
    }

    /// World positions of the map points removed as moving (γ_del) while tracking the last
    /// frame; empty unless [`System::record_removed_points`] is on.
    pub fn removed_points(&self) -> &[nalgebra::Vector3<f64>] {
        self.tracker.removed_points()
    }

    /// Checks that the depth, weight and mask maps of `input` have the grey image's size, and
    /// the grey image the camera's (when the camera states one).
    fn check_sizes(&self, input: &FrameInput<'_>) -> Result<(), ProcessError> {
        let (index, timestamp) = (self.next_index, input.timestamp);
        let expected = input.gray.dimensions();
        let cam = (self.cam.pinhole.width, self.cam.pinhole.height);
        if cam != (0, 0) && cam != expected {
            return Err(ProcessError::ImageSize {
                index,
                timestamp,
                expected: cam,
                got: expected,
            });
        }
        let maps = [
            ("depth", Some(input.depth.dimensions())),
            ("weights", input.weights.map(StaticWeights::dimensions)),
            ("mask", input.masks.map(|m| m.dimensions())),
        ];
        for (what, got) in maps {
            if let Some(got) = got
                && got != expected
            {
                return Err(ProcessError::SizeMismatch {
                    index,
                    timestamp,
                    what,
                    expected,
                    got,
                });
            }
        }
        Ok(())
    }

    /// A copy of this system's feature extraction, to run ahead of tracking (e.g. on another
    /// thread) and hand its output to [`System::process_features`].
    pub fn feature_stage(&self) -> FeatureStage<E>
    where
        E: Clone,
    {
        self.features.clone()
    }

    /// Processes one frame: extraction, tracking, then local mapping and loop closing on a new
    /// keyframe. A depth, weight or mask map of another size than the grey image (or a grey
    /// image of another size than the camera) is refused before anything changes.
    pub fn process(&mut self, input: FrameInput<'_>) -> Result<FrameResult, ProcessError> {
        self.check_sizes(&input)?;
        let features = self.features.extract(input.gray, input.weights);
        self.track_and_map(input, features)
    }

    /// [`System::process`] with the frame's features already extracted by a copy of this
    /// system's [`System::feature_stage`] from the same `input`: the same result, without the
    /// extraction. Inputs of the wrong size are refused as by [`System::process`].
    pub fn process_features(
        &mut self,
        input: FrameInput<'_>,
        features: Features,
    ) -> Result<FrameResult, ProcessError> {
        self.check_sizes(&input)?;
        self.track_and_map(input, features)
    }

    /// [`System::process_features`] up to the keyframe decision: when the frame makes a
    /// keyframe, its local mapping and loop closing are left pending, for the caller to run
    /// with [`System::map_pending`] while it does other work (e.g. the next frame's motion
    /// map on another thread). They run at the latest when the next frame is tracked, or at
    /// [`System::finish`], [`System::refine_frame_poses`] and
    /// [`System::enter_localization`]: each keyframe is mapped before the next frame is
    /// tracked, so the results are those of [`System::process_features`], whenever the caller
    /// runs the mapping. The returned [`FrameResult::mapping`] and
    /// [`FrameResult::loop_closure`] are `None` while the mapping is pending.
    pub fn track_features(
        &mut self,
        input: FrameInput<'_>,
        features: Features,
    ) -> Result<FrameResult, ProcessError> {
        self.check_sizes(&input)?;
        self.map_pending();
        self.track(input, features)
    }

    /// True while a keyframe made by [`System::track_features`] waits for its local mapping.
    pub fn has_pending_mapping(&self) -> bool {
        self.pending.is_some()
    }

    /// Runs the local mapping and loop closing of the keyframe left pending by
    /// [`System::track_features`], if any, and reports them.
    pub fn map_pending(&mut self) -> Option<MappingOutcome> {
        let (index, kf) = self.pending.take()?;
        if rayon::current_thread_index().is_none() {
            // Called from outside the thread pool (e.g. the main thread of an offline pass):
            // run the mapping on a worker. Its parallel loops (local BA: four per iteration)
            // then split work from that worker's own queue instead of handing every loop to
            // the pool and sleeping until it is done, a wake-up across threads each time. The
            // loops' results do not depend on the thread that runs them.
            let (map, mapper, closer, vocab) = (
                &mut self.map,
                &mut self.mapper,
                &mut self.closer,
                self.vocab.as_ref(),
            );
            return Some(rayon::scope(|_| {
                Self::map_keyframe(map, mapper, closer, vocab, index, kf)
            }));
        }
        Some(Self::map_keyframe(
            &mut self.map,
            &mut self.mapper,
            &mut self.closer,
            self.vocab.as_ref(),
            index,
            kf,
        ))
    }

    /// The local mapping and loop closing of keyframe `kf` (made from frame `index`).
    fn map_keyframe(
        map: &mut Map,
        mapper: &mut LocalMapper,
        closer: &mut LoopCloser,
        vocab: Option<&Vocabulary>,
        index: u64,
        kf: KeyFrameId,
    ) -> MappingOutcome {
        let t0 = Instant::now();
        let mapping = {
            let _stage = tracing::info_span!(target: "dynapix::stage", "local mapping").entered();
            mapper.process(map, kf, vocab)
        };
        let t1 = Instant::now();
        let mut loop_closure = None;
        if map.keyframe(kf).is_some() {
            let _stage = tracing::info_span!(target: "dynapix::stage", "loop closing").entered();
            loop_closure = closer.step(map, kf, vocab);
        }
        MappingOutcome {
            index,
            mapping,
            loop_closure,
            mapping_seconds: (t1 - t0).as_secs_f64(),
            loop_closing_seconds: t1.elapsed().as_secs_f64(),
        }
    }

    /// Tracking, local mapping and loop closing of a checked frame with its features.
    fn track_and_map(
        &mut self,
        input: FrameInput<'_>,
        features: Features,
    ) -> Result<FrameResult, ProcessError> {
        self.map_pending();
        let mut result = self.track(input, features)?;
        if let Some(done) = self.map_pending() {
            result.add_mapping(done);
        }
        Ok(result)
    }

    /// Tracking of a checked frame with its features; a new keyframe is left pending (see
    /// [`System::track_features`]), except when tracking asks for a map reset: then its
    /// mapping and loop closing run first, and the reset after them. The frame's record is
    /// kept before the mapping, which never reads the records.
    fn track(
        &mut self,
        input: FrameInput<'_>,
        features: Features,
    ) -> Result<FrameResult, ProcessError> {
        let index = self.next_index;
        self.next_index += 1;
        let Features {
            keys,
            descriptors: descs,
            seconds: extract_seconds,
        } = features;
        let t1 = Instant::now();
        let stage = tracing::info_span!(target: "dynapix::stage", "tracking").entered();
        let mut frame = Frame::new(
            index,
            input.timestamp,
            keys,
            descs,
            input.depth,
            input.weights.map(StaticWeights::as_image),
            &self.cam,
            self.bounds,
        );
        if let Some(m) = input.masks {
            crate::weighting::apply_class_mask(&mut frame, m);
        }
        let num_keypoints = frame.len();
        let out = if self.localization {
            self.tracker
                .track_localization(&mut self.map, frame, self.vocab.as_ref())
        } else {
            self.tracker
                .track(&mut self.map, frame, self.vocab.as_ref())
        };
        let t2 = Instant::now();
        // The frame pose relative to its reference keyframe is taken at tracking time, before
        // local BA or a loop correction moves the keyframe (ORB-SLAM2 stores `Tcr` in
        // `Tracking`), so later keyframe corrections carry the frame along.
        let relative = match (out.pose, out.reference) {
            (Some(p), Some(r)) if out.state == TrackingState::Ok => {
                self.map.keyframe_pose(r).map(|rp| (r, p * rp.inverse()))
            }
            _ => None,
        };
        let matches =
            if self.final_pose_refinement && relative.is_some() && out.new_keyframe.is_none() {
                self.tracker
                    .last_frame()
                    .map(|f| frame_matches(f, &self.map))
                    .unwrap_or_default()
            } else {
                Vec::new()
            };
        drop(stage);
        self.pending = out.new_keyframe.map(|kf| (index, kf));
        let mut mapped = None;
        let mut reset = false;
        if out.reset_requested {
            // The order of `process`: mapping and loop closing, the reset, then the record.
            mapped = self.map_pending();
            self.freeze_records();
            self.map.clear();
            self.tracker.reset();
            self.mapper.reset();
            self.closer.reset();
            reset = true;
        }
        self.records.push(Record {
            timestamp: input.timestamp,
            state: out.state,
            relative,
            frozen: None,
            matches,
        });
        let mut result = FrameResult {
            index,
            timestamp: input.timestamp,
            state: out.state,
            pose_cw: out.pose,
            new_keyframe: out.new_keyframe.is_some(),
            num_keypoints,
            inliers: out.inliers,
            reset,
            relocalised: out.relocalised,
            times: StepTimes {
                extract: extract_seconds,
                track: (t2 - t1).as_secs_f64(),
                mapping: 0.0,
                loop_closing: 0.0,
            },
            mapping: None,
            loop_closure: None,
        };
        if let Some(done) = mapped {
            result.add_mapping(done);
        }
        Ok(result)
    }

    fn freeze_records(&mut self) {
        for r in self.records.iter_mut() {
            if r.frozen.is_none()
                && let Some((k, tcr)) = r.relative
            {
                r.frozen = self.map.keyframe_pose(k).map(|kp| tcr * kp);
            }
            r.relative = None;
            r.matches = Vec::new();
        }
    }

    /// Re-optimises every tracked frame that kept its matches (see
    /// [`SystemParams::final_pose_refinement`]) against the current map: pose-only, weighted,
    /// with tracking's outlier rounds, starting from the frame's current estimate. Matches to
    /// points culled or never added to the map are left out; a frame with fewer than
    /// [`MIN_REFINE_MATCHES`] surviving matches, or fewer inliers after the optimisation,
    /// keeps its pose. Returns the number of frames whose pose was replaced.
    pub fn refine_frame_poses(&mut self) -> usize {
        self.map_pending();
        let camera = crate::camera::stereo_camera(&self.cam);
        let mut n = 0;
        for r in self.records.iter_mut() {
            let matches = std::mem::take(&mut r.matches);
            let Some((k, tcr)) = r.relative else { continue };
            let Some(kp) = self.map.keyframe_pose(k) else {
                continue;
            };
            let (points, observations): (Vec<_>, Vec<_>) = matches
                .iter()
                .filter_map(|(id, o)| {
                    let id = self.map.resolve(*id)?;
                    let p = self.map.point(id)?;
                    (p.num_obs > 0).then_some((p.position, *o))
                })
                .unzip();
            if points.len() < MIN_REFINE_MATCHES {
                continue;
            }
            let problem = dynapix_optim::PoseOnlyProblem {
                camera,
                pose: tcr * kp,
                points,
                observations,
            };
            let res = dynapix_optim::optimize_pose(&problem, &self.refine_params);
            if res.num_inliers < MIN_REFINE_MATCHES {
                continue;
            }
            let tcw = crate::pose::normalized(&res.pose);
            if self.tracker.params.pose_consistency
                && self.map.keyframe(k).is_some_and(|kf| {
                    let th = self.tracker.params.local_th_reloc;
                    crate::tracking::moves_the_map(&self.cam, &self.map, kf, &(tcr * kp), &tcw, th)
                })
            {
                continue;
            }
            r.relative = Some((k, tcw * kp.inverse()));
            n += 1;
        }
        n
    }

    /// The trajectory so far, one entry per processed frame, with the current (BA-refined)
    /// estimate of every tracked frame.
    pub fn trajectory(&self) -> Vec<TrajectoryEntry> {
        self.records
            .iter()
            .map(|r| {
                let tcw = r.frozen.or_else(|| {
                    let (k, tcr) = r.relative?;
                    Some(tcr * self.map.keyframe_pose(k)?)
                });
                let tracked = r.state == TrackingState::Ok;
                TrajectoryEntry {
                    timestamp: r.timestamp,
                    state: r.state,
                    pose_wc: if tracked {
                        tcw.map(|t| t.inverse())
                    } else {
                        None
                    },
                }
            })
            .collect()
    }

    /// Loops closed so far, in order.
    pub fn loop_events(&self) -> &[LoopEvent] {
        self.closer.events()
    }

    /// Keyframes in the map, sorted by creation: `(timestamp, T_wc)`.
    pub fn keyframe_trajectory(&self) -> Vec<(f64, Se3)> {
        self.map
            .keyframes_sorted()
            .into_iter()
            .map(|(_, k)| (k.timestamp, k.pose.inverse()))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::orb::OrbExtractor;
    use dynapix_geometry::PinholeCamera;

    fn system() -> System<OrbExtractor> {
        let pinhole = PinholeCamera::new(64, 48, 50.0, 50.0, 32.0, 24.0);
        let cam = RgbdCamera::new(pinhole, 40.0, 40.0, 30.0);
        System::new(OrbExtractor::default(), cam, SystemParams::default())
    }

    /// 40 frames of the synthetic `static` preset at 320×240 through a system with the final
    /// pose refinement, and the system.
    fn refined_run() -> System<OrbExtractor> {
        let params =
            dynapix_synth::SynthParams::at_size(dynapix_synth::Preset::Static, 40, 0, 320, 240);
        let seq = dynapix_synth::Sequence::new(params).expect("sequence");
        let st = dynapix_synth::output::camera_settings(&seq.params.camera, seq.params.fps);
        let cam = RgbdCamera::new(st.camera(), st.bf, st.th_depth, st.fps);
        let params = SystemParams {
            final_pose_refinement: true,
            ..SystemParams::default()
        };
        let mut sys = System::new(OrbExtractor::default(), cam, params);
        for i in 0..40 {
            process_synth(&mut sys, &seq, i);
        }
        sys
    }

    /// `n` frames of the synthetic `walking_xyz` preset at 320×240 (seed 0) and its camera.
    fn walking_sequence(n: usize) -> (dynapix_synth::Sequence, RgbdCamera) {
        let params =
            dynapix_synth::SynthParams::at_size(dynapix_synth::Preset::WalkingXyz, n, 0, 320, 240);
        let seq = dynapix_synth::Sequence::new(params).expect("sequence");
        let st = dynapix_synth::output::camera_settings(&seq.params.camera, seq.params.fps);
        let cam = RgbdCamera::new(st.camera(), st.bf, st.th_depth, st.fps);
        (seq, cam)
    }

    /// Frame `i` of `seq` through [`System::process`].
    fn process_synth(
        sys: &mut System<OrbExtractor>,
        seq: &dynapix_synth::Sequence,
        i: usize,
    ) -> FrameResult {
        let (f, _) = seq.frame(i, None);
        let gray = crate::orb::rgb_to_gray_orbslam(&f.rgb);
        let depth = f.depth_metres();
        sys.process(FrameInput {
            timestamp: seq.time(i),
            gray: &gray,
            depth: &depth,
            weights: None,
            masks: None,
        })
        .expect("frame")
    }

    /// How [`deferred_mapping_gives_the_results_of_process`] feeds a system.
    #[derive(Clone, Copy, Debug, PartialEq)]
    enum Feed {
        /// `process` on every frame.
        Process,
        /// `track_features`, then `map_pending` at once.
        MapAtOnce,
        /// `track_features` only: each keyframe is mapped when the next frame is tracked.
        Deferred,
    }

    /// Per-frame (pose, keyframe, mapping counters), the trajectory and the map's size of a
    /// run over 40 frames of the synthetic `walking_xyz` preset at 320×240 fed as `feed`.
    #[allow(clippy::type_complexity)]
    fn fed_run(
        feed: Feed,
    ) -> (
        Vec<(Option<Se3>, bool, Option<MappingStats>)>,
        Vec<TrajectoryEntry>,
        Vec<(f64, Se3)>,
        (usize, usize),
        usize,
    ) {
        let n = 40;
        let (seq, cam) = walking_sequence(n);
        let mut sys = System::new(OrbExtractor::default(), cam, SystemParams::default());
        let mut stage = sys.feature_stage();
        let mut frames = Vec::new();
        let mut pending_seen = 0;
        for i in 0..n {
            let (f, _) = seq.frame(i, None);
            let gray = crate::orb::rgb_to_gray_orbslam(&f.rgb);
            let depth = f.depth_metres();
            let input = FrameInput {
                timestamp: seq.time(i),
                gray: &gray,
                depth: &depth,
                weights: None,
                masks: None,
            };
            let mut r = match feed {
                Feed::Process => sys.process(input).expect("frame"),
                Feed::MapAtOnce | Feed::Deferred => {
                    let feats = stage.extract(&gray, None);
                    sys.track_features(input, feats).expect("frame")
                }
            };
            if sys.has_pending_mapping() {
                pending_seen += 1;
                assert!(r.new_keyframe && r.mapping.is_none());
            }
            if feed == Feed::MapAtOnce
                && let Some(done) = sys.map_pending()
            {
                assert_eq!(done.index, r.index);
                r.mapping = Some(done.mapping);
            }
            frames.push((r.pose_cw, r.new_keyframe, r.mapping));
        }
        if feed == Feed::Deferred {
            // The last keyframe waits until something needs the map.
            assert!(sys.has_pending_mapping() == frames.last().is_some_and(|f| f.1));
            sys.finish();
            assert!(!sys.has_pending_mapping());
        }
        let size = (sys.map().num_keyframes(), sys.map().num_points());
        (
            frames,
            sys.trajectory(),
            sys.keyframe_trajectory(),
            size,
            pending_seen,
        )
    }

    #[test]
    fn deferred_mapping_gives_the_results_of_process() {
        let (frames, traj, kfs, size, pending) = fed_run(Feed::Process);
        assert_eq!(pending, 0, "process maps every keyframe at once");
        let keyframes = frames.iter().filter(|f| f.1).count();
        assert!(keyframes >= 5, "{keyframes} keyframes");
        assert!(frames.iter().all(|f| f.0.is_some()), "every frame tracked");
        let (at_once, traj_a, kfs_a, size_a, pending_a) = fed_run(Feed::MapAtOnce);
        assert_eq!(pending_a, keyframes, "every keyframe waits for its mapping");
        assert_eq!(
            at_once, frames,
            "same poses, keyframes and mapping counters"
        );
        assert_eq!((traj_a, kfs_a, size_a), (traj.clone(), kfs.clone(), size));
        // Mapping each keyframe only when the next frame comes: the poses at tracking time
        // are the same; the mapping counters are not reported with the frame.
        let (deferred, traj_d, kfs_d, size_d, _) = fed_run(Feed::Deferred);
        let strip = |v: &[(Option<Se3>, bool, Option<MappingStats>)]| {
            v.iter().map(|f| (f.0, f.1)).collect::<Vec<_>>()
        };
        assert_eq!(strip(&deferred), strip(&frames));
        assert!(deferred.iter().all(|f| f.2.is_none()));
        assert_eq!((traj_d, kfs_d, size_d), (traj, kfs, size));
    }

    /// `(time, keyframe, mapping counters)` per frame of 40 synthetic `walking_xyz` frames
    /// at 320×240 (30 frames/s) run with `params`.
    fn run_with(params: SystemParams) -> Vec<(f64, bool, Option<MappingStats>)> {
        let n = 40;
        let (seq, cam) = walking_sequence(n);
        let mut sys = System::new(OrbExtractor::default(), cam, params);
        (0..n)
            .map(|i| {
                let r = process_synth(&mut sys, &seq, i);
                assert!(r.pose_cw.is_some(), "frame {i} tracked");
                (seq.time(i), r.new_keyframe, r.mapping)
            })
            .collect()
    }

    #[test]
    fn local_ba_waits_for_the_next_keyframe_within_the_minimum_interval() {
        let mut params = SystemParams::default();
        assert_eq!(params.mapping.ba_min_interval_s, 0.05);
        params.mapping.ba_min_keyframes = 0;
        let frames = run_with(params.clone());
        let mapped: Vec<(f64, bool)> = frames
            .iter()
            .filter_map(|(t, _, m)| m.as_ref().map(|m| (*t, m.ba_skipped)))
            .collect();
        assert!(mapped.len() >= 4, "{} keyframes: {mapped:?}", mapped.len());
        // Every BA ran at least 0.05 s after the one before, and every skipped one within
        // 0.05 s of it: at 30 frames/s, never on two consecutive frames, and never skipped
        // twice in a row.
        let mut last_ba: Option<f64> = None;
        let mut skipped = 0;
        for &(t, skip) in &mapped {
            match (skip, last_ba) {
                (true, Some(l)) => {
                    assert!(t - l < 0.05, "skipped at {t}, last BA at {l}");
                    skipped += 1;
                }
                (true, None) => panic!("the first keyframe's BA was skipped"),
                (false, l) => {
                    assert!(l.is_none_or(|l| t - l >= 0.05), "BA at {t} after {l:?}");
                    last_ba = Some(t);
                }
            }
        }
        assert!(
            skipped > 0,
            "keyframes on consecutive frames make some BA wait"
        );
        // 0 runs it on every keyframe.
        params.mapping.ba_min_interval_s = 0.0;
        let every = run_with(params);
        assert!(
            every
                .iter()
                .all(|f| f.2.as_ref().is_none_or(|m| !m.ba_skipped))
        );
        assert!(every.iter().filter(|f| f.2.is_some()).count() >= 4);
    }

    fn positions(sys: &System<OrbExtractor>) -> Vec<Option<nalgebra::Vector3<f64>>> {
        sys.trajectory()
            .iter()
            .map(|e| e.pose_wc.map(|p| p.translation.vector))
            .collect()
    }

    #[test]
    fn final_pose_refinement_pulls_a_wrong_frame_pose_back_to_the_map() {
        let mut sys = refined_run();
        let before = positions(&sys);
        assert!(before.iter().all(Option::is_some), "every frame tracked");
        // Move every frame that kept its matches by 3 cm: refinement must bring it back.
        let shift = Se3::translation(0.03, 0.0, 0.0);
        let mut moved = 0;
        for r in sys.records.iter_mut() {
            if let (Some((k, tcr)), false) = (r.relative, r.matches.is_empty()) {
                r.relative = Some((k, shift * tcr));
                moved += 1;
            }
        }
        assert!(moved >= 20, "{moved} frames kept matches");
        let refined = sys.refine_frame_poses();
        assert_eq!(refined, moved, "every moved frame is refined");
        let after = positions(&sys);
        let worst = before
            .iter()
            .zip(&after)
            .map(|(a, b)| (a.unwrap() - b.unwrap()).norm())
            .fold(0.0, f64::max);
        assert!(
            worst < 0.003,
            "a frame stayed {worst} m from its tracked pose"
        );
        // The matches are used once: a second call changes nothing.
        assert_eq!(sys.refine_frame_poses(), 0);
    }

    #[test]
    fn final_pose_refinement_leaves_out_points_culled_since() {
        let mut sys = refined_run();
        let before = positions(&sys);
        for id in sys.map.point_ids() {
            sys.map.cull_point(id);
        }
        assert_eq!(
            sys.refine_frame_poses(),
            0,
            "no surviving point, no refinement"
        );
        assert_eq!(positions(&sys), before);
    }

    #[test]
    fn maps_of_the_wrong_size_are_refused_not_ignored() {
        let mut sys = system();
        let gray = GrayImage::new(64, 48);
        let depth = DepthImage::new(64, 48);
        let small = DepthImage::new(32, 24);
        let input = |depth, weights, masks| FrameInput {
            timestamp: 1.0,
            gray: &gray,
            depth,
            weights,
            masks,
        };
        let e = sys.process(input(&small, None, None)).unwrap_err();
        assert!(
            matches!(
                e,
                ProcessError::SizeMismatch {
                    what: "depth",
                    got: (32, 24),
                    ..
                }
            ),
            "{e}"
        );
        let w = StaticWeights::ones(63, 48);
        let e = sys.process(input(&depth, Some(&w), None)).unwrap_err();
        assert!(e.to_string().contains("weights"), "{e}");
        let m = GrayImage::new(64, 47);
        let e = sys.process(input(&depth, None, Some(&m))).unwrap_err();
        assert!(e.to_string().contains("mask"), "{e}");
        let big = GrayImage::new(128, 96);
        let e = sys
            .process(FrameInput {
                timestamp: 1.0,
                gray: &big,
                depth: &DepthImage::new(128, 96),
                weights: None,
                masks: None,
            })
            .unwrap_err();
        assert!(matches!(e, ProcessError::ImageSize { .. }), "{e}");
        // Refused frames change nothing: the next good frame is frame 0.
        let w = StaticWeights::ones(64, 48);
        let r = sys.process(input(&depth, Some(&w), None)).unwrap();
        assert_eq!(r.index, 0);
        assert_eq!(sys.trajectory().len(), 1);
    }
}
