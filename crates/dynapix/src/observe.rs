//! Watching a run: the [`RunObserver`] that the offline passes ([`crate::OfflineRunner`],
//! [`crate::slam::run_pass_observed`]) and the online mode ([`crate::OnlineDynaPix`],
//! [`crate::run_online`]) call at the start and end of a pass and after every frame, with
//! what a viewer shows (pose, images, P, keypoints with their weights, map points, removed
//! points, keyframes, loops, timings).
//!
//! The trait has no viewer dependency (the `dynapix-rerun` crate implements it with Rerun).
//! Without an observer nothing here runs: no image is kept or copied, no point recorded.
//! With one, everything a [`FrameView`] offers is borrowed from the run (keypoints and map
//! points are read lazily, only when the observer asks), so an observer pays only for what
//! it logs. Observers must not change results: they only see shared references.

use dynapix_geometry::{PinholeCamera, Se3};
use dynapix_io::{DepthImage, FrameStatus, StaticWeights, Trajectory};
use dynapix_slam::System;
use dynapix_slam::orb::OrbExtractor;
use dynapix_slam::tracking::TrackingState;
use image::RgbImage;
use nalgebra::Vector3;

use crate::pass::PassOutput;

/// Something that watches a run (a viewer, a recorder). Every method has a no-op default;
/// calls come from the thread that runs the SLAM system, in frame order.
pub trait RunObserver: Send + Sync {
    /// Whether the colour images of `pass`'s frames are wanted ([`FrameView::rgb`]): an
    /// offline pass keeps each frame's colour image until it is tracked only when this is
    /// true (asked once, before [`RunObserver::pass_begins`]). Online the image is decoded
    /// anyway and always shown.
    fn wants_images(&self, _pass: &PassInfo<'_>) -> bool {
        true
    }

    /// A pass (offline) or an online run begins.
    fn pass_begins(&self, _pass: &PassInfo<'_>) {}

    /// A frame was tracked (or found lost).
    fn frame(&self, _frame: &FrameView<'_>) {}

    /// A pass ends, with what it produced (offline; the online run ends with
    /// [`RunObserver::online_ends`]).
    fn pass_ends(&self, _pass: &PassInfo<'_>, _output: &PassOutput) {}

    /// An online run ends, with the system's final estimate of every tracked frame.
    fn online_ends(&self, _pass: &PassInfo<'_>, _refined: &Trajectory) {}
}

/// What is known about a pass when it begins.
#[derive(Clone, Copy, Debug)]
pub struct PassInfo<'a> {
    /// The pass's number in the run, from 1 (the first pass of a DynaPix run is 1, its
    /// weighted passes follow).
    pub number: usize,
    /// Its label (`first pass (rigidity)`, `dynapix pass 2`, `dynapix online`).
    pub label: &'a str,
    /// Frames in the sequence.
    pub frames: usize,
    /// The camera (intrinsics and image size).
    pub camera: &'a PinholeCamera,
    /// The sequence's ground truth, when it has one (never used by the run itself).
    pub ground_truth: Option<&'a Trajectory>,
    /// The pass is weighted by motion probabilities (DynaPix) rather than plain ORB-SLAM2.
    pub weighted: bool,
    /// The pass is planned as the run's last one, whose trajectory is the result (the final
    /// weighted pass of an offline DynaPix run, an ORB-SLAM2 run's pass, `slam`, an online
    /// run); the passes before it only make the motion maps of the next.
    pub last: bool,
}

/// How tracking may use a keypoint, from its static weight w = 1 − P and the method's
/// thresholds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KeypointUse {
    /// Full weight: may create map points (P ≤ γ_add).
    Used,
    /// Down-weighted: tracked with weight w, creates no map point (γ_add < P < γ_del).
    DownWeighted,
    /// Refused: a map point matched to it is removed as moving (P ≥ γ_del).
    Refused,
}

/// One keypoint of a tracked frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KeypointView {
    /// Column (level-0 pixels).
    pub x: f32,
    /// Row (level-0 pixels).
    pub y: f32,
    /// Static weight w = 1 − P sampled at the keypoint (1 for ORB-SLAM2).
    pub weight: f32,
    /// How tracking may use it.
    pub usage: KeypointUse,
    /// Matched to a map point as an inlier of the pose.
    pub matched: bool,
}

/// One map point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapPointView {
    /// World position (m).
    pub position: Vector3<f64>,
    /// Static weight 1 − its motion probability.
    pub weight: f32,
    /// Keyframes observing it.
    pub observations: usize,
}

/// Milliseconds of each stage of a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// Motion probability map (online only; offline maps are made before the pass).
    pub motion_ms: Option<f64>,
    /// Feature extraction (offline; online it is part of `track_ms`).
    pub extract_ms: f64,
    /// Tracking.
    pub track_ms: f64,
    /// Local mapping.
    pub mapping_ms: f64,
    /// Loop closing.
    pub loop_ms: f64,
}

/// What a run shows of one frame, borrowed from it for the duration of
/// [`RunObserver::frame`].
pub struct FrameView<'a> {
    /// Index of the frame (in the sequence offline, in push order online).
    pub index: usize,
    /// Its time (s).
    pub t: f64,
    /// Tracked, lost or not initialised.
    pub status: FrameStatus,
    /// Camera-to-world pose at tracking time (`None` unless tracked).
    pub pose_wc: Option<Se3>,
    /// The colour image (when [`RunObserver::wants_images`]).
    pub rgb: Option<&'a RgbImage>,
    /// The depth image.
    pub depth: &'a DepthImage,
    /// The static weights w = 1 − P the frame was tracked with (`None`: unweighted).
    pub weights: Option<&'a StaticWeights>,
    /// Map points matched as inliers.
    pub tracked_points: usize,
    /// A keyframe was made from this frame.
    pub keyframe: bool,
    /// The loop closed at this frame's keyframe: `(time of the matched old keyframe, points
    /// matched)`.
    pub loop_closed: Option<(f64, usize)>,
    /// Stage timings.
    pub times: StageTimes,
    system: &'a System<OrbExtractor>,
}

impl<'a> FrameView<'a> {
    /// A view of the frame `index` just processed by `system`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        index: usize,
        t: f64,
        result: &dynapix_slam::FrameResult,
        rgb: Option<&'a RgbImage>,
        depth: &'a DepthImage,
        weights: Option<&'a StaticWeights>,
        times: StageTimes,
        system: &'a System<OrbExtractor>,
    ) -> Self {
        // As `slam::frame_status` (not called: that module calls this one).
        let status = match result.state {
            TrackingState::Ok => FrameStatus::Tracked,
            TrackingState::Lost => FrameStatus::Lost,
            TrackingState::NotInitialized => FrameStatus::NotInitialized,
        };
        let pose_wc = result
            .pose_cw
            .filter(|_| status == FrameStatus::Tracked)
            .map(|cw| cw.inverse());
        Self {
            index,
            t,
            status,
            pose_wc,
            rgb,
            depth,
            weights,
            tracked_points: result.inliers,
            keyframe: result.new_keyframe,
            loop_closed: result
                .loop_closure
                .as_ref()
                .map(|l| (l.loop_timestamp, l.matched_points)),
            times,
            system,
        }
    }

    /// The frame's keypoints with their weights (empty when tracking kept no frame of this
    /// time, e.g. before initialisation).
    pub fn keypoints(&self) -> impl Iterator<Item = KeypointView> + '_ {
        let d = &self.system.map().params.dynapix;
        let (used_above, refused_at) = (1.0 - d.gamma_add, 1.0 - d.gamma_del);
        let frame = self
            .system
            .last_frame()
            .filter(|f| f.timestamp.to_bits() == self.t.to_bits());
        frame.into_iter().flat_map(move |f| {
            f.keys.iter().enumerate().map(move |(i, k)| {
                let weight = f.weights.get(i).copied().unwrap_or(1.0);
                let usage = if weight >= used_above {
                    KeypointUse::Used
                } else if weight <= refused_at {
                    KeypointUse::Refused
                } else {
                    KeypointUse::DownWeighted
                };
                let matched = f.map_points.get(i).is_some_and(Option::is_some)
                    && !f.outlier.get(i).copied().unwrap_or(true);
                KeypointView {
                    x: k.x,
                    y: k.y,
                    weight,
                    usage,
                    matched,
                }
            })
        })
    }

    /// Every map point of the map as it is after this frame.
    pub fn map_points(&self) -> impl Iterator<Item = MapPointView> + '_ {
        let map = self.system.map();
        map.point_ids()
            .into_iter()
            .filter_map(move |id| map.point(id))
            .map(|p| MapPointView {
                position: p.position,
                weight: p.weight,
                observations: p.observations.len(),
            })
    }

    /// Map points in the map.
    pub fn num_map_points(&self) -> usize {
        self.system.map().num_points()
    }

    /// Keyframes in the map.
    pub fn num_keyframes(&self) -> usize {
        self.system.map().num_keyframes()
    }

    /// `(time, camera-to-world pose)` of every keyframe of the map, in order.
    pub fn keyframe_poses(&self) -> Vec<(f64, Se3)> {
        self.system.keyframe_trajectory()
    }

    /// World positions of the map points removed as moving while tracking this frame.
    pub fn removed_points(&self) -> &[Vector3<f64>] {
        self.system.removed_points()
    }
}
