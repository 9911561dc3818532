//! Tracking parameters with ORB-SLAM2's RGB-D defaults.

use dynapix_optim::PoseOnlyParams;

use super::relocalization::RelocParams;
use crate::matcher::MatcherParams;

/// Tracking parameters (ORB-SLAM2 RGB-D defaults).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct TrackingParams {
    /// Initialisation needs more keypoints than this (500).
    pub init_min_features: usize,
    /// Motion-model search radius factor (15 for RGB-D).
    pub motion_th: f32,
    /// Minimum motion-model matches (20; retried with twice the radius).
    pub motion_min_matches: usize,
    /// Minimum inlier map points after motion-model or reference tracking (10).
    pub min_inliers_frame: usize,
    /// Ratio of the keyframe → frame matching for reference tracking (0.7).
    pub ref_ratio: f32,
    /// Minimum keyframe → frame matches (15).
    pub ref_min_matches: usize,
    /// Ratio of the local-map search (0.8).
    pub local_ratio: f32,
    /// Local-map search radius factor (3 for RGB-D).
    pub local_th: f32,
    /// Local-map search radius factor just after relocalisation (5).
    pub local_th_reloc: f32,
    /// Minimum local-map inliers (30).
    pub local_min_inliers: usize,
    /// Minimum local-map inliers within `fps` frames of a relocalisation (50).
    pub local_min_inliers_reloc: usize,
    /// Frustum test: minimum cosine between viewing ray and point normal (0.5).
    pub view_cos_min: f64,
    /// Upper bound on the local keyframe list while adding neighbours (80).
    pub max_local_keyframes: usize,
    /// Keyframe decision: fraction of the reference's tracked points (0.75).
    pub kf_ref_ratio: f32,
    /// Same with fewer than 2 keyframes (0.4).
    pub kf_ref_ratio_few: f32,
    /// Keyframe decision c1c fraction (0.25).
    pub kf_c1c_ratio: f32,
    /// Keyframe decision: minimum inliers (15).
    pub kf_min_inliers: usize,
    /// needClose: tracked close points below this (100) …
    pub kf_close_tracked: usize,
    /// … and untracked close points above this (70).
    pub kf_close_untracked: usize,
    /// Frames since the last keyframe before inserting (mMinFrames = 0).
    pub min_frames: u64,
    /// Close points a new keyframe creates at least (100).
    pub kf_new_points: usize,
    /// Vocabulary tree depth at which features are grouped for BoW matching (2).
    pub bow_group_depth: usize,
    /// Reset the map when lost with at most this many keyframes (5).
    pub reset_max_keyframes: usize,
    /// Pose-only optimisation.
    pub pose: PoseOnlyParams,
    /// Matcher thresholds.
    pub matcher: MatcherParams,
    /// Relocalisation.
    pub reloc: RelocParams,
    /// Predicted local-map tracking: when the motion model, the reference keyframe (and, once
    /// lost, relocalisation) fail, the frame is tracked against the last local map from the
    /// constant-velocity prediction, for at most this many frames after the last tracked one
    /// (0 = off, as ORB-SLAM2). Among movers the few static matches of the last frame can be
    /// too few for the motion model while the local map still holds enough static points.
    pub predicted_frames: u64,
    /// Relocalisation against the local map: while lost, when the bag-of-words
    /// relocalisation (and predicted tracking) fail, the frame is matched by projection
    /// against the last local map from the last tracked pose, held and extrapolated, within
    /// `local_reloc_th`; it is then accepted as after any relocalisation (≥
    /// `local_min_inliers_reloc` local-map inliers). Off in ORB-SLAM2 (false).
    pub local_relocalisation: bool,
    /// Consistency check of a pose found with few matches: a predicted frame is refused, and
    /// the final pose refinement keeps the tracked pose, when the optimised pose moves the
    /// median projection of the local map (the reference keyframe's points for the
    /// refinement) by more than the widest window of the local-map search that found the
    /// matches (4 · `local_th_reloc` px). Off in ORB-SLAM2 (false).
    pub pose_consistency: bool,
    /// Search radius factor of the local-map relocalisation (15, the motion model's).
    pub local_reloc_th: f32,
}

impl Default for TrackingParams {
    fn default() -> Self {
        Self {
            init_min_features: 500,
            motion_th: 15.0,
            motion_min_matches: 20,
            min_inliers_frame: 10,
            ref_ratio: 0.7,
            ref_min_matches: 15,
            local_ratio: 0.8,
            local_th: 3.0,
            local_th_reloc: 5.0,
            local_min_inliers: 30,
            local_min_inliers_reloc: 50,
            view_cos_min: 0.5,
            max_local_keyframes: 80,
            kf_ref_ratio: 0.75,
            kf_ref_ratio_few: 0.4,
            kf_c1c_ratio: 0.25,
            kf_min_inliers: 15,
            kf_close_tracked: 100,
            kf_close_untracked: 70,
            min_frames: 0,
            kf_new_points: 100,
            reset_max_keyframes: 5,
            bow_group_depth: 2,
            pose: PoseOnlyParams::default(),
            matcher: MatcherParams::default(),
            reloc: RelocParams::default(),
            predicted_frames: 0,
            local_relocalisation: false,
            pose_consistency: false,
            local_reloc_th: 15.0,
        }
    }
}
