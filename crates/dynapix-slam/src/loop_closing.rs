//! Loop closing (ORB-SLAM2 `LoopClosing`, spec §6.6), run synchronously after local mapping on
//! each new keyframe so the default mode stays deterministic: bag-of-words loop detection with
//! covisibility-consistent candidate groups ([`detect`]), a relative SE3 estimate (scale fixed to
//! 1 for RGB-D) verified by guided matching, then loop correction ([`correct`]): pose
//! propagation to the current keyframe's neighbourhood, loop fusion, essential-graph
//! optimisation and a weighted global bundle adjustment.

use dynapix_geometry::Se3;

use crate::map::{KeyFrameId, MapPointId};

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
