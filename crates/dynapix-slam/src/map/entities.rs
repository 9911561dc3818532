//! The map's entities: keyframes, map points, and the link a culled keyframe leaves behind
//! (ORB-SLAM2 `KeyFrame`, `MapPoint`).

use std::collections::{BTreeMap, BTreeSet};

use dynapix_geometry::Se3;
use nalgebra::Vector3;

use crate::camera::RgbdCamera;
use crate::features::{Descriptor, KeyPoint, ScalePyramid};
use crate::frame::{FeatureGrid, Frame};
use crate::ids::{KeyFrameId, MapPointId};
use crate::pose::transform;

/// A keyframe: a frame kept in the map, with its covisibility links and spanning-tree links.
#[derive(Clone, Debug)]
pub struct KeyFrame {
    /// Keyframe sequence number (0 for the first keyframe of the map), ORB-SLAM2 `mnId`.
    pub seq: u64,
    /// Id of the frame it was created from.
    pub frame_id: u64,
    /// Timestamp in seconds.
    pub timestamp: f64,
    /// Pose `T_cw` (world → camera).
    pub pose: Se3,
    /// Keypoints at their image (distorted) position.
    pub keys: Vec<KeyPoint>,
    /// Undistorted keypoints.
    pub keys_un: Vec<KeyPoint>,
    /// Descriptors.
    pub descriptors: Vec<Descriptor>,
    /// Depth per keypoint in metres, negative when missing.
    pub depth: Vec<f32>,
    /// Virtual right coordinate per keypoint, negative when missing.
    pub u_right: Vec<f32>,
    /// DynaPix weight w = 1 − P per keypoint.
    pub weights: Vec<f32>,
    /// Keypoint on a semantically dynamic class (DynaPix+, gates map-point birth).
    pub dynamic_class: Vec<bool>,
    /// Map point matched to each keypoint.
    pub map_points: Vec<Option<MapPointId>>,
    /// Feature grid over the undistorted keypoints.
    pub grid: FeatureGrid,
    /// Bag-of-words words of the keypoints, `(word, weight)`, sorted by word.
    pub bow: Vec<(u32, f64)>,
    /// Feature vector: node id → keypoint indices, sorted by node.
    pub feat: Vec<(u32, Vec<u32>)>,
    /// Covisibility weights to other keyframes (shared map points), only edges kept.
    pub connections: BTreeMap<KeyFrameId, usize>,
    /// Covisible keyframes sorted by decreasing weight (ties by id).
    pub ordered: Vec<(KeyFrameId, usize)>,
    /// Spanning-tree parent (None for the root).
    pub parent: Option<KeyFrameId>,
    /// Spanning-tree children.
    pub children: BTreeSet<KeyFrameId>,
    /// Loop edges (filled by loop closing, a later stage).
    pub loop_edges: BTreeSet<KeyFrameId>,
}

impl KeyFrame {
    /// Builds a keyframe from a frame with a pose. `seq` is the keyframe sequence number.
    pub fn from_frame(frame: &Frame, seq: u64, pose: Se3) -> Self {
        Self {
            seq,
            frame_id: frame.id,
            timestamp: frame.timestamp,
            pose,
            keys: frame.keys.clone(),
            keys_un: frame.keys_un.clone(),
            descriptors: frame.descriptors.clone(),
            depth: frame.depth.clone(),
            u_right: frame.u_right.clone(),
            weights: frame.weights.clone(),
            dynamic_class: frame.dynamic_class.clone(),
            map_points: frame.map_points.clone(),
            grid: frame.grid.clone(),
            bow: frame.bow.clone(),
            feat: frame.feat.clone(),
            connections: BTreeMap::new(),
            ordered: Vec::new(),
            parent: None,
            children: BTreeSet::new(),
            loop_edges: BTreeSet::new(),
        }
    }

    /// Camera centre in world coordinates.
    pub fn center(&self) -> Vector3<f64> {
        self.pose.inverse().translation.vector
    }

    /// Up to `n` best covisible keyframes.
    pub fn best_covisibles(&self, n: usize) -> Vec<KeyFrameId> {
        self.ordered.iter().take(n).map(|&(k, _)| k).collect()
    }

    /// Covisibility weight to `other` (0 when not connected).
    pub fn weight(&self, other: KeyFrameId) -> usize {
        self.connections.get(&other).copied().unwrap_or(0)
    }

    /// Back-projects keypoint `i` with its depth into world coordinates.
    pub fn unproject(&self, i: usize, cam: &RgbdCamera) -> Option<Vector3<f64>> {
        let z = *self.depth.get(i)? as f64;
        if z <= 0.0 {
            return None;
        }
        let kp = self.keys_un.get(i)?;
        let xc = Vector3::new(
            (kp.x as f64 - cam.pinhole.cx) * z / cam.pinhole.fx,
            (kp.y as f64 - cam.pinhole.cy) * z / cam.pinhole.fy,
            z,
        );
        Some(transform(&self.pose.inverse(), &xc))
    }
}

/// A 3-D landmark with its observations and the statistics tracking and culling need.
#[derive(Clone, Debug)]
pub struct MapPoint {
    /// Creation order (deterministic tie-breaks).
    pub seq: u64,
    /// Position in world coordinates.
    pub position: Vector3<f64>,
    /// Mean viewing direction (unit).
    pub normal: Vector3<f64>,
    /// Minimum distance of scale invariance.
    pub min_distance: f64,
    /// Maximum distance of scale invariance.
    pub max_distance: f64,
    /// Representative descriptor (minimum median distance to the others).
    pub descriptor: Descriptor,
    /// Observing keyframes and the keypoint index in each.
    pub observations: BTreeMap<KeyFrameId, usize>,
    /// Observation count, depth-valid observations count 2 (ORB-SLAM2 `nObs`).
    pub num_obs: usize,
    /// Reference keyframe (first observer still present).
    pub reference: KeyFrameId,
    /// Keyframe sequence number of its creation keyframe (`mnFirstKFid`).
    pub first_kf_seq: u64,
    /// Times predicted visible in a tracked frame.
    pub visible: u32,
    /// Times matched in a tracked frame.
    pub found: u32,
    /// 1 − the point's DynaPix motion probability, initialised from the creating keypoint
    /// and updated from matched keypoints by [`crate::weighting::update_matched_points`].
    pub weight: f32,
    /// The observations `descriptor` was last chosen from, in order, and the choice: when
    /// both still hold, [`Map::compute_distinctive_descriptor`] would choose the same again.
    pub(crate) descriptor_basis: (Vec<(KeyFrameId, usize)>, Descriptor),
}

impl MapPoint {
    /// Found / visible ratio.
    pub fn found_ratio(&self) -> f32 {
        if self.visible == 0 {
            0.0
        } else {
            self.found as f32 / self.visible as f32
        }
    }

    /// Predicted pyramid level at distance `dist` (ORB-SLAM2 `PredictScale`).
    pub fn predict_scale(&self, dist: f64, pyr: &ScalePyramid) -> usize {
        let ratio = self.max_distance / dist.max(1e-12);
        let level = (ratio.ln() / (pyr.scale_factor as f64).ln()).ceil();
        if level.is_nan() || level < 0.0 {
            0
        } else {
            (level as usize).min(pyr.levels.saturating_sub(1))
        }
    }
}

/// Link of a culled keyframe to its spanning-tree parent, kept so frame poses stored relative
/// to it can be recomposed.
#[derive(Clone, Copy, Debug)]
pub struct CulledLink {
    /// Parent at culling time.
    pub parent: KeyFrameId,
    /// `T_cp`: pose of the culled keyframe relative to its parent.
    pub t_cp: Se3,
}
