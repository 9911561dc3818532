//! The online (streaming) schedule of DynaPix: frames are pushed one at a time and the pose of
//! each frame is returned as soon as the allowed latency permits, with the same per-frame
//! algorithms as the offline runner but only information the system has at that moment
//! (design §1: one code path, two schedules).
//!
//! For frame m (processed when frame m + `lookahead` has arrived):
//! - its pose for splatting is **predicted** from the two latest tracked poses (constant
//!   velocity, like ORB-SLAM2's motion model), since the system tracks m only after its
//!   weights exist; the frames inside the lookahead are predicted the same way;
//! - its **background** is reconstructed ([`dynapix_motion::reconstruct_background`]) from
//!   frames it has seen: the frames waiting in the lookahead, recent frames of the window
//!   (every `reconstruct.step`-th) and the images of past keyframes, each splatted with the
//!   poses the running system gave them (predicted for the waiting frames);
//! - its **moving term** uses past neighbours (`online.past_offsets`), with the backgrounds
//!   kept from when they were processed. Future frames as moving-term neighbours (with
//!   backgrounds reconstructed for them from predicted poses) cost a background per frame of
//!   lookahead and measured no better on the synth walking presets (walking_xyz with one
//!   frame of lookahead: 0.055 m against 0.032 m as background sources);
//! - the **rigidity cue** uses the neighbours of `motion.rigidity.offsets` that the system has
//!   seen: past frames of the window and frames waiting in the lookahead (no poses needed);
//! - the **geometric cue** takes the static depth from the depths of the window, the kept
//!   keyframes and the waiting frames, splatted with the poses the running system gave them;
//! - the enabled cues ([`crate::Cues`]; the paper's terms P = D·M only when that cue is on)
//!   combine by noisy-or ([`crate::combine`], the offline runner's combiner) into static weights (quantised like the map files) and the SLAM
//!   system tracks m with them;
//! - the local mapping and loop closing of the keyframe made from the frame before m run
//!   while m's motion map is computed (with m's FAST corners), and the system tracks m only
//!   after them: the same results as mapping each keyframe at once
//!   ([`dynapix_slam::system::System::track_features`]);
//! - when the next frame has already arrived (waiting in the lookahead, or shown by the caller
//!   with [`OnlineDynaPix::push_before`]), its rigidity cue, which needs images but no pose,
//!   is computed while m's features are extracted and m is tracked, and used by the next
//!   push if the frame and its neighbours are the same (`online.rigidity_ahead`; the same
//!   results either way).
//!
//! Memory is bounded by the window (`online.window` frames with their backgrounds, plus
//! `online.background_keyframes` keyframe images and the `lookahead` frames waiting), not by
//! the length of the stream; the SLAM map grows with the keyframes as in any SLAM system.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Instant;

use dynapix_flow::dis::DisFlow;
use dynapix_geometry::{PinholeCamera, Se3};
use dynapix_io::{DepthImage, FrameStatus, MotionProbability, StaticWeights};
use dynapix_motion::moving::to_gray;
use dynapix_motion::static_depth::{DepthView, WorkingDepth, geometric_term, static_depth};
use dynapix_motion::{
    FloatImage, FrameImages, MotionParams, Neighbour, ReconstructParams, RgbdImages, RigidFrame,
    RigidityParams, Source, StaticBackground, motion_probability, reconstruct_background,
};
use dynapix_slam::FeatureStage;
use dynapix_slam::orb::{OrbExtractor, rgb_to_gray_orbslam};
use dynapix_slam::system::{FrameInput, MappingOutcome, System, SystemParams};
use image::{GrayImage, RgbImage};

use crate::combine::FrameCues;
use crate::config::{Config, Cues};
use crate::error::{Error, Result};
use crate::input::Camera;
use crate::observe::{FrameView, RunObserver, StageTimes};
use crate::slam::{frame_status, load_vocabulary};

mod steps;

/// One RGB-D frame as it arrives.
#[derive(Clone, Debug)]
pub struct RgbdFrame {
    /// Capture time (s).
    pub t: f64,
    /// Colour image.
    pub rgb: RgbImage,
    /// Depth in metres (0 = no depth), registered to the colour image.
    pub depth: DepthImage,
    /// DynaPix+ semantic mask (non-zero = dynamic class), when the method uses one.
    pub mask: Option<GrayImage>,
}

impl RgbdFrame {
    /// A frame without a mask.
    pub fn new(t: f64, rgb: RgbImage, depth: DepthImage) -> Self {
        Self {
            t,
            rgb,
            depth,
            mask: None,
        }
    }
}

/// What the online system reports for one frame.
#[derive(Clone, Debug)]
pub struct FrameResult {
    /// Index of the frame in push order.
    pub index: usize,
    /// Its time (s).
    pub t: f64,
    /// Tracked, lost or not initialised.
    pub status: FrameStatus,
    /// Camera-to-world pose at tracking time (`None` unless tracked).
    pub pose_wc: Option<Se3>,
    /// A keyframe was created from the frame.
    pub keyframe: bool,
    /// Frames pushed after this one before it was processed (the latency in frames).
    pub latency_frames: usize,
    /// Mean motion probability of the frame's pixels (0 for ORB-SLAM2).
    pub mean_probability: f32,
    /// Milliseconds spent on the motion map (background, flows, splats), `background_ms`
    /// included; the previous keyframe's mapping and this frame's FAST corners run beside it.
    /// Without the rigidity cue when that was computed during the push before
    /// ([`FrameResult::rigidity_ahead`]).
    pub motion_ms: f64,
    /// Milliseconds spent reconstructing the frame's background.
    pub background_ms: f64,
    /// Milliseconds from the frame's motion map to its pose: the rest of the feature
    /// extraction and tracking. A new keyframe is mapped during the next push.
    pub slam_ms: f64,
    /// Milliseconds of the local mapping and loop closing of the previous frame's keyframe,
    /// which ran during this push beside the motion map (0 when it made none).
    pub mapping_ms: f64,
    /// The frame's rigidity cue was computed during the push before, beside the tracking of
    /// the frame before it (see [`OnlineDynaPix::push_before`]).
    pub rigidity_ahead: bool,
    /// Milliseconds of the next frame's rigidity cue, computed beside this frame's tracking
    /// (0 when the next frame had not arrived).
    pub next_rigidity_ms: f64,
}

/// The motion map of one frame and what the window keeps of it.
struct FrameMotion {
    /// Predicted camera-to-world pose the maps were splatted with.
    t_wc: Se3,
    /// Static weights for tracking (`None` for ORB-SLAM2).
    weights: Option<StaticWeights>,
    background: Option<Arc<StaticBackground>>,
    gray: Option<Arc<GrayImage>>,
    working: Option<Arc<WorkingDepth>>,
    mean_probability: f32,
    background_ms: f64,
}

/// A processed frame kept in the window.
struct Past {
    index: usize,
    images: Arc<RgbdImages>,
    /// Grey image (rigidity cue).
    gray: Option<Arc<GrayImage>>,
    /// Depth at the working resolution of the geometric cue.
    working: Option<Arc<WorkingDepth>>,
    background: Option<Arc<StaticBackground>>,
    /// Camera-to-world pose: tracked, or the prediction when tracking failed.
    pose_wc: Se3,
    /// A keyframe was made from it (its images stay as a background source after it leaves
    /// the window).
    keyframe: bool,
}

/// Online DynaPix: push frames, get poses.
///
/// Each push runs three jobs side by side: the local mapping and loop closing of the previous
/// frame's keyframe, the new frame's motion map, and its FAST corners. The motion map reads
/// nothing of the SLAM map (only the poses tracking gave the past frames) and the corners do
/// not depend on the weights, while the system maps a keyframe before it tracks the next
/// frame in any case: the results are those of mapping each keyframe at once
/// ([`OnlineDynaPix::map_pending`] after every push gives the same poses).
pub struct OnlineDynaPix {
    system: System<OrbExtractor>,
    /// A copy of the system's feature extraction, run here to find the FAST corners beside
    /// the motion map.
    features: FeatureStage<OrbExtractor>,
    core: Core,
    /// Who watches the frames ([`OnlineDynaPix::set_observer`]).
    observer: Option<Arc<dyn RunObserver>>,
}

/// The online schedule apart from the SLAM system: everything the motion map of a frame
/// reads, so it can be computed while the system maps the previous keyframe.
struct Core {
    config: Config,
    cam: PinholeCamera,
    flow: DisFlow,
    rigidity_flow: DisFlow,
    /// The cues of P (`None` for ORB-SLAM2).
    cues: Option<Cues>,
    params: Option<MotionParams>,
    recon: ReconstructParams,
    pending: VecDeque<(usize, RgbdFrame)>,
    window: VecDeque<Past>,
    keyframes: VecDeque<Past>,
    /// `T_cw` of the two latest tracked frames (older first) for the motion model.
    last_tracked: VecDeque<(usize, Se3)>,
    next_index: usize,
    /// The rigidity cue of the next frame, computed beside the tracking of the frame before.
    ahead: Option<Ahead>,
}

/// The rigidity cue of a frame computed one push early ([`OnlineDynaPix::push_before`]). It
/// is used only for the same frame with the same neighbours, so it equals the cue computed
/// at the frame's own push.
struct Ahead {
    /// Push index of the frame.
    index: usize,
    /// The neighbour offsets it used.
    offsets: Vec<i64>,
    /// A copy of the frame when the caller showed it before pushing it (checked against the
    /// frame pushed); `None` when it was waiting in the lookahead.
    shown: Option<(f64, RgbImage, DepthImage)>,
    /// The cue.
    map: FloatImage,
}

/// A neighbour of the rigidity cue and where its images are.
enum RigidSource<'a> {
    /// A processed frame (window) or the frame in flight: grey image and images.
    Seen(Arc<GrayImage>, &'a RgbdImages),
    /// A frame waiting in the lookahead (its grey image is made when needed).
    Waiting(&'a RgbdFrame),
}

/// The frame being tracked while the next frame's rigidity cue is computed: not yet in the
/// window, but a past neighbour of the next frame.
#[derive(Clone, Copy)]
struct InFlight<'a> {
    index: usize,
    gray: &'a Arc<GrayImage>,
    images: &'a RgbdImages,
}

/// True when two frames have the same time and the same pixels (depth compared bit for bit).
fn same_frame(shown: &(f64, RgbImage, DepthImage), frame: &RgbdFrame) -> bool {
    shown.0.to_bits() == frame.t.to_bits()
        && shown.1 == frame.rgb
        && shown.2.dimensions() == frame.depth.dimensions()
        && shown
            .2
            .as_raw()
            .iter()
            .zip(frame.depth.as_raw())
            .all(|(a, b)| a.to_bits() == b.to_bits())
}

/// The rigidity cue's flow online, for images `width` pixels wide: `online.rigidity_flow`
/// (or `motion.rigidity`'s preset) at the online working width
/// (`online.rigidity_flow_working_width`).
fn online_rigidity_flow(config: &Config, width: u32) -> DisFlow {
    match &config.online.rigidity_flow {
        Some(p) => {
            let mut p = p.clone();
            p.finest_scale = dynapix_motion::rigidity::finest_scale_at_working_width(
                p.finest_scale,
                config.online.rigidity_flow_working_width,
                width,
            );
            DisFlow::new(p)
        }
        None => RigidityParams {
            flow_working_width: config.online.rigidity_flow_working_width,
            ..config.motion.rigidity.clone()
        }
        .flow_for_width(width),
    }
}

impl OnlineDynaPix {
    /// An online system for `camera` with `config` (method, mode, motion and SLAM parameters,
    /// the online schedule).
    pub fn new(camera: &Camera, config: &Config) -> Result<Self> {
        config.validate()?;
        if config.method.needs_masks() {
            tracing::debug!("dynapix+ online: masks come with the frames");
        }
        let cues = config.method.terms().map(|_| config.cues());
        let params = cues.filter(|c| c.paper).map(|_| {
            let mut p = config.motion_params();
            p.offsets = config.online.past_offsets.clone();
            p
        });
        let vocabulary = load_vocabulary(&config.slam.vocabulary)?;
        let extractor = OrbExtractor::new(camera.orb_params()?)?;
        // Online there is no end of the sequence to refine at: nothing is kept for it.
        let system_params = SystemParams {
            final_pose_refinement: false,
            final_global_ba: false,
            ..config.system_params()
        };
        let mut system = System::new(extractor, camera.rgbd(), system_params);
        if let Some(v) = vocabulary {
            system = system.with_vocabulary(v);
        }
        Ok(Self {
            features: system.feature_stage(),
            system,
            core: Core {
                config: config.clone(),
                cam: camera.pinhole(),
                flow: DisFlow::with_preset(config.motion.flow.preset()),
                rigidity_flow: online_rigidity_flow(config, camera.pinhole().width),
                cues,
                params,
                recon: config.motion.reconstruct.clone(),
                pending: VecDeque::new(),
                window: VecDeque::new(),
                keyframes: VecDeque::new(),
                last_tracked: VecDeque::new(),
                next_index: 0,
                ahead: None,
            },
            observer: None,
        })
    }

    /// Shows every processed frame to `observer` ([`RunObserver::frame`]; the caller reports
    /// the run's start and end, as [`crate::run_online`] does). The results
    /// are the same as without it.
    pub fn set_observer(&mut self, observer: Arc<dyn RunObserver>) {
        self.system.record_removed_points(true);
        self.observer = Some(observer);
    }

    /// The SLAM system (map, keyframes, full trajectory so far). Between pushes the newest
    /// keyframe may still wait for its local mapping and loop closing (they run during the
    /// next push); [`OnlineDynaPix::map_pending`] runs them now, [`OnlineDynaPix::finish`]
    /// runs them at the end.
    pub fn system(&self) -> &System<OrbExtractor> {
        &self.system
    }

    /// Runs the local mapping and loop closing of the newest keyframe now, if they are still
    /// pending (see [`OnlineDynaPix::system`]); the results of later frames are the same
    /// either way.
    pub fn map_pending(&mut self) -> Option<MappingOutcome> {
        self.system.map_pending()
    }

    /// The latency in frames: a frame's result comes when this many later frames arrived.
    pub fn lookahead(&self) -> usize {
        self.core.lookahead()
    }

    /// Pushes the next frame. Returns the result of the frame `lookahead` frames back (the
    /// newest frame itself without lookahead), or `None` while the first frames fill the
    /// lookahead.
    pub fn push(&mut self, frame: RgbdFrame) -> Result<Option<FrameResult>> {
        self.push_before(frame, None)
    }

    /// [`OnlineDynaPix::push`] when `next`, the frame that will be pushed after `frame`, has
    /// already arrived (a camera delivering faster than the system runs, or frames read from
    /// files). The part of `next`'s motion map that needs no pose, its rigidity cue (flows to
    /// its neighbours, rigid fits, residuals), is then computed beside the feature extraction
    /// and tracking of `frame`, and the push of `next` uses it instead of computing it again.
    /// The results are exactly those of [`OnlineDynaPix::push`]: the early cue is used only
    /// when the frame pushed next has the same time and pixels as `next` and the same
    /// neighbours are available, and is computed again otherwise. With a lookahead the frame
    /// after the processed one is already waiting and `push` does this by itself; `next` is
    /// used only when no frame is waiting. Off with `online.rigidity_ahead: false`.
    pub fn push_before(
        &mut self,
        frame: RgbdFrame,
        next: Option<&RgbdFrame>,
    ) -> Result<Option<FrameResult>> {
        let core = &mut self.core;
        let size = (core.cam.width, core.cam.height);
        for (what, got) in [
            ("colour image", frame.rgb.dimensions()),
            ("depth", frame.depth.dimensions()),
        ] {
            if got != size {
                return Err(Error::Input(format!(
                    "frame {} (t = {:.6}): {what} is {}×{}, the camera is {}×{}",
                    core.next_index, frame.t, got.0, got.1, size.0, size.1
                )));
            }
        }
        if let Some((_, last)) = core.pending.back()
            && frame.t <= last.t
        {
            return Err(Error::Input(format!(
                "frame {} (t = {:.6}) is not after the previous frame (t = {:.6})",
                core.next_index, frame.t, last.t
            )));
        }
        core.pending.push_back((core.next_index, frame));
        core.next_index += 1;
        if core.pending.len() <= core.lookahead() {
            return Ok(None);
        }
        self.process_oldest(next).map(Some)
    }

    /// Processes the frames still waiting for their lookahead (end of the stream) and the
    /// local mapping of the last keyframe, and returns the frames' results in order.
    pub fn finish(&mut self) -> Result<Vec<FrameResult>> {
        let mut out = Vec::with_capacity(self.core.pending.len());
        while !self.core.pending.is_empty() {
            out.push(self.process_oldest(None)?);
        }
        self.system.map_pending();
        Ok(out)
    }

    /// Processes the oldest waiting frame; `next` is the frame to be pushed after it when the
    /// caller has it already (see [`OnlineDynaPix::push_before`]).
    fn process_oldest(&mut self, next: Option<&RgbdFrame>) -> Result<FrameResult> {
        let Some((index, frame)) = self.core.pending.pop_front() else {
            return Err(Error::Input("no frame to process".into()));
        };
        let latency_frames = self.core.pending.len();
        let early_rigidity = self.core.take_ahead(index, &frame);
        let rigidity_ahead = early_rigidity.is_some();
        let t0 = Instant::now();
        let images = Arc::new(RgbdImages {
            rgb: frame.rgb,
            depth: frame.depth,
        });
        // The three jobs of a push side by side (see the type's documentation); the grey
        // image of the ORB front end is made with the corners.
        let (system, features, core) = (&mut self.system, &self.features, &self.core);
        let ((mapped, (orb_gray, mut corners)), motion) = rayon::join(
            || {
                rayon::join(
                    || system.map_pending(),
                    || {
                        let gray = rgb_to_gray_orbslam(&images.rgb);
                        let corners = features.fast_corners(&gray);
                        (gray, corners)
                    },
                )
            },
            || core.weights(index, &images, early_rigidity),
        );
        let motion = motion?;
        let motion_ms = t0.elapsed().as_secs_f64() * 1e3;
        // The frame's features and tracking, beside the rigidity cue of the next frame when it
        // has arrived (it needs no pose, only images).
        let (system, features, core) = (&mut self.system, &mut self.features, &self.core);
        let upcoming = match core.pending.front() {
            Some((j, f)) if *j == index + 1 => Some((f, false)),
            Some(_) => None,
            None => next.map(|f| (f, true)),
        };
        let in_flight = motion.gray.as_ref().map(|gray| InFlight {
            index,
            gray,
            images: &images,
        });
        let (tracked, ahead) = rayon::join(
            || {
                let t1 = Instant::now();
                let feats =
                    features.extract_cached(&orb_gray, motion.weights.as_ref(), &mut corners);
                let res = system.track_features(
                    FrameInput {
                        timestamp: frame.t,
                        gray: &orb_gray,
                        depth: &images.depth,
                        weights: motion.weights.as_ref(),
                        masks: frame.mask.as_ref(),
                    },
                    feats,
                );
                (res, t1.elapsed().as_secs_f64() * 1e3)
            },
            || {
                let t = Instant::now();
                let ahead = match (upcoming, in_flight) {
                    (Some((f, shown)), Some(fl)) => core.rigidity_ahead(index + 1, f, shown, fl),
                    _ => None,
                };
                (ahead, t.elapsed().as_secs_f64() * 1e3)
            },
        );
        let (res, slam_ms) = tracked;
        let res = res?;
        let (ahead, ahead_ms) = ahead;
        let next_rigidity_ms = if ahead.is_some() { ahead_ms } else { 0.0 };
        let status = frame_status(res.state);
        let tracked_cw = res.pose_cw.filter(|_| status == FrameStatus::Tracked);
        let core = &mut self.core;
        core.ahead = ahead;
        if let Some(cw) = tracked_cw {
            core.last_tracked.push_back((index, cw));
            while core.last_tracked.len() > 2 {
                core.last_tracked.pop_front();
            }
        }
        let pose_wc = tracked_cw.map(|cw| cw.inverse());
        if let Some(observer) = &self.observer {
            let times = StageTimes {
                motion_ms: Some(motion_ms),
                extract_ms: 0.0,
                track_ms: slam_ms,
                mapping_ms: mapped.as_ref().map_or(0.0, |m| m.mapping_seconds * 1e3),
                loop_ms: mapped
                    .as_ref()
                    .map_or(0.0, |m| m.loop_closing_seconds * 1e3),
            };
            // Decoded anyway: shown without asking `wants_images`.
            let mut view = FrameView::new(
                index,
                frame.t,
                &res,
                Some(&images.rgb),
                &images.depth,
                motion.weights.as_ref(),
                times,
                &self.system,
            );
            // Online a keyframe is mapped (and its loop closed) during the next push.
            view.loop_closed = mapped
                .as_ref()
                .and_then(|m| m.loop_closure.as_ref())
                .map(|l| (l.loop_timestamp, l.matched_points));
            observer.frame(&view);
        }
        core.remember(Past {
            index,
            images,
            gray: motion.gray,
            working: motion.working,
            background: motion.background,
            pose_wc: pose_wc.unwrap_or(motion.t_wc),
            keyframe: res.new_keyframe && pose_wc.is_some(),
        });
        Ok(FrameResult {
            index,
            t: frame.t,
            status,
            pose_wc,
            keyframe: res.new_keyframe,
            latency_frames,
            mean_probability: motion.mean_probability,
            motion_ms,
            background_ms: motion.background_ms,
            slam_ms,
            mapping_ms: mapped.map_or(0.0, |m| (m.mapping_seconds + m.loop_closing_seconds) * 1e3),
            rigidity_ahead,
            next_rigidity_ms,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::OnlineConfig;
    use dynapix_flow::dis::{DisParams, Preset};

    #[test]
    fn online_rigidity_flow_has_its_own_parameters() {
        let mut config = Config::default();
        let medium = DisParams::preset(Preset::Medium);
        // By default the online flow is the offline preset's.
        assert_eq!(config.online.rigidity_flow, None);
        assert_eq!(online_rigidity_flow(&config, 640).params, medium);
        // The cheaper flow, from Rust or from a file (keys left out take the medium values).
        config.online.rigidity_flow = Some(OnlineConfig::cheap_rigidity_flow());
        let cheap = online_rigidity_flow(&config, 640).params;
        assert_eq!(
            (
                cheap.patch_stride,
                cheap.grad_descent_iterations,
                cheap.variational.fixed_point_iterations
            ),
            (4, 16, 2)
        );
        assert_eq!((cheap.patch_size, cheap.finest_scale), (8, 1));
        assert_eq!(
            cheap.variational.sor_iterations,
            medium.variational.sor_iterations
        );
        let parsed = Config::from_yaml_str(
            "online: {rigidity_flow: {patch_stride: 4, grad_descent_iterations: 16, \
             variational: {fixed_point_iterations: 2}}}",
        )
        .unwrap();
        assert_eq!(online_rigidity_flow(&parsed, 640).params, cheap);
        // The online working width still sets the finest level.
        let coarse = Config::from_yaml_str(
            "online: {rigidity_flow: {patch_stride: 4}, rigidity_flow_working_width: 160}",
        )
        .unwrap();
        assert_eq!(online_rigidity_flow(&coarse, 640).params.finest_scale, 2);
        let bad = Config::from_yaml_str("online: {rigidity_flow: {patch_stride: 0}}")
            .and_then(|c| c.validate().map(|_| c));
        assert!(
            bad.unwrap_err()
                .to_string()
                .contains("online.rigidity_flow"),
            "a bad flow is refused naming the key"
        );
    }

    #[test]
    fn online_rigidity_flow_has_its_own_working_width() {
        let mut config = Config::default();
        assert_eq!(config.motion.rigidity.flow_working_width, 160);
        // Online keeps the medium preset's own finest level (320 px wide at 640×480)...
        assert_eq!(online_rigidity_flow(&config, 640).params.finest_scale, 1);
        assert_eq!(online_rigidity_flow(&config, 320).params.finest_scale, 1);
        // ...unless the online setting asks for the offline working width.
        config.online.rigidity_flow_working_width = 160;
        assert_eq!(online_rigidity_flow(&config, 640).params.finest_scale, 2);
        let parsed = Config::from_yaml_str("online: {rigidity_flow_working_width: 160}").unwrap();
        assert_eq!(parsed.online.rigidity_flow_working_width, 160);
    }
}
