//! Loop closing (ORB-SLAM2 `LoopClosing`, spec §6.6), run synchronously after local mapping on
//! each new keyframe so the default mode stays deterministic: bag-of-words loop detection with
//! covisibility-consistent candidate groups ([`detect`]), a relative SE3 estimate (scale fixed to
//! 1 for RGB-D) verified by guided matching, then loop correction ([`correct`]): pose
//! propagation to the current keyframe's neighbourhood, loop fusion, essential-graph
//! optimisation and a weighted global bundle adjustment.

use dynapix_geometry::Se3;

use crate::ids::{KeyFrameId, MapPointId};

pub mod correct;
pub mod detect;

/// An accepted loop: what detection hands to correction (ORB-SLAM2 `mpMatchedKF`, `mg2oScw`,
/// `mvpCurrentMatchedPoints`, `mvpLoopMapPoints`).
#[derive(Clone, Debug, PartialEq)]
pub struct LoopMatch {
    /// The keyframe that closed the loop (the newest keyframe).
    pub current: KeyFrameId,
    /// The matched old keyframe.
    pub loop_kf: KeyFrameId,
    /// Corrected pose `T_cw` of the current keyframe, i.e. `T_cm · T_mw` with `T_cm` the
    /// estimated current-from-loop-keyframe transform and `T_mw` the loop keyframe's pose.
    pub corrected_pose: Se3,
    /// Per keypoint of the current keyframe: the matched map point from the loop keyframe's
    /// neighbourhood (`None` when unmatched). Same length as the keyframe's keypoints.
    pub matched_points: Vec<Option<MapPointId>>,
    /// Map points of the loop keyframe and its covisible keyframes, de-duplicated, in a
    /// deterministic order (fused into the corrected neighbourhood of the current keyframe).
    pub loop_points: Vec<MapPointId>,
}

use crate::camera::RgbdCamera;
use crate::map::Map;
use crate::vocab::Vocabulary;
use correct::{CorrectionParams, CorrectionStats, correct_loop};
use detect::{DetectionParams, LoopDetector};

/// Parameters of loop closing.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct LoopClosingParams {
    /// Run loop closing at all (`--no-loop-closing` turns it off).
    pub enabled: bool,
    /// Detection and SE3 estimation.
    pub detection: DetectionParams,
    /// Correction, essential graph and global BA.
    pub correction: CorrectionParams,
}

impl Default for LoopClosingParams {
    fn default() -> Self {
        Self {
            enabled: true,
            detection: DetectionParams::default(),
            correction: CorrectionParams::default(),
        }
    }
}

/// One closed loop, for logs and reports.
#[derive(Clone, Debug)]
pub struct LoopEvent {
    /// Keyframe that closed the loop.
    pub current: KeyFrameId,
    /// Its timestamp.
    pub current_timestamp: f64,
    /// The matched old keyframe.
    pub loop_kf: KeyFrameId,
    /// Its timestamp.
    pub loop_timestamp: f64,
    /// Keypoints of the current keyframe matched to loop-side map points.
    pub matched_points: usize,
    /// What the correction did and how long it took.
    pub correction: CorrectionStats,
}

/// The loop-closing stage (ORB-SLAM2 `LoopClosing`), stepped once per new keyframe after local
/// mapping.
pub struct LoopCloser {
    /// Parameters.
    pub params: LoopClosingParams,
    cam: RgbdCamera,
    detector: LoopDetector,
    events: Vec<LoopEvent>,
}

impl LoopCloser {
    /// A loop closer for `cam`.
    pub fn new(cam: RgbdCamera, params: LoopClosingParams) -> Self {
        Self {
            detector: LoopDetector::new(cam.clone(), params.detection.clone()),
            cam,
            params,
            events: Vec::new(),
        }
    }

    /// Forgets the keyframe database and the candidate groups (map reset); closed loops stay
    /// in the log.
    pub fn reset(&mut self) {
        self.detector.reset();
    }

    /// Looks for a loop at keyframe `kf` and closes it. Returns the event when one was closed.
    pub fn step(
        &mut self,
        map: &mut Map,
        kf: KeyFrameId,
        vocab: Option<&Vocabulary>,
    ) -> Option<LoopEvent> {
        if !self.params.enabled {
            return None;
        }
        let m = self.detector.detect(map, kf, vocab)?;
        let current_timestamp = map.keyframe(m.current)?.timestamp;
        let loop_timestamp = map.keyframe(m.loop_kf)?.timestamp;
        let correction = correct_loop(map, &self.cam, &m, &self.params.correction);
        self.detector.loop_closed(map, m.current);
        let event = LoopEvent {
            current: m.current,
            current_timestamp,
            loop_kf: m.loop_kf,
            loop_timestamp,
            matched_points: m.matched_points.iter().flatten().count(),
            correction,
        };
        tracing::info!(
            "loop closed: keyframe at {:.3} s ↔ {:.3} s, {} matches",
            event.current_timestamp,
            event.loop_timestamp,
            event.matched_points
        );
        self.events.push(event.clone());
        Some(event)
    }

    /// The parameters.
    pub fn params(&self) -> &LoopClosingParams {
        &self.params
    }

    /// Loops closed so far, in order.
    pub fn events(&self) -> &[LoopEvent] {
        &self.events
    }
}
