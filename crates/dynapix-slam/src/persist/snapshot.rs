//! A dense, id-free copy of the [`Map`]: keyframes sorted by sequence number and map points
//! sorted by creation order, every cross-reference a dense index into those lists (ORB-SLAM2
//! keeps raw pointers and has no such layer; map save/load needs one so ids of culled entities
//! and arena generations do not leak into files). References to culled keyframes or points are
//! dropped on the way in; the feature grid is rebuilt from the undistorted keypoints on the
//! way out.

use std::collections::{BTreeMap, BTreeSet, HashMap};

use dynapix_geometry::Se3;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::PersistError;
use crate::camera::ImageBounds;
use crate::features::ScalePyramid;
use crate::features::{Descriptor, KeyPoint};
use crate::frame::FeatureGrid;
use crate::ids::{KeyFrameId, MapPointId};
use crate::map::{KeyFrame, Map, MapParams, MapPoint};

/// One keyframe with dense indices.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KeyFrameSnapshot {
    /// Keyframe sequence number.
    pub seq: u64,
    /// Id of the frame it was created from.
    pub frame_id: u64,
    /// Timestamp in seconds.
    pub timestamp: f64,
    /// Pose `T_cw`.
    pub pose: Se3,
    /// Keypoints at their image position.
    pub keys: Vec<KeyPoint>,
    /// Undistorted keypoints.
    pub keys_un: Vec<KeyPoint>,
    /// Descriptors.
    pub descriptors: Vec<Descriptor>,
    /// Depth per keypoint (negative when missing).
    pub depth: Vec<f32>,
    /// Virtual right coordinate per keypoint (negative when missing).
    pub u_right: Vec<f32>,
    /// DynaPix weight per keypoint.
    pub weights: Vec<f32>,
    /// Keypoint on a semantically dynamic class.
    pub dynamic_class: Vec<bool>,
    /// Matched map point (index into [`MapSnapshot::points`]) per keypoint.
    pub map_points: Vec<Option<u32>>,
    /// Bag-of-words vector.
    pub bow: Vec<(u32, f64)>,
    /// Feature vector.
    pub feat: Vec<(u32, Vec<u32>)>,
    /// Covisible keyframes with their weights, in the keyframe's own order (decreasing weight).
    pub covisibility: Vec<(u32, u64)>,
    /// Spanning-tree parent.
    pub parent: Option<u32>,
    /// Spanning-tree children, ascending.
    pub children: Vec<u32>,
    /// Loop edges, ascending.
    pub loop_edges: Vec<u32>,
}

/// One map point with dense indices.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapPointSnapshot {
    /// Creation order.
    pub seq: u64,
    /// World position.
    pub position: Vector3<f64>,
    /// Mean viewing direction.
    pub normal: Vector3<f64>,
    /// Minimum distance of scale invariance.
    pub min_distance: f64,
    /// Maximum distance of scale invariance.
    pub max_distance: f64,
    /// Representative descriptor.
    pub descriptor: Descriptor,
    /// `(keyframe index, keypoint index)`, ascending by keyframe.
    pub observations: Vec<(u32, u32)>,
    /// Observation count (depth-valid observations count 2).
    pub num_obs: u64,
    /// Reference keyframe (None when it was culled and nothing replaced it).
    pub reference: Option<u32>,
    /// Sequence number of the creating keyframe.
    pub first_kf_seq: u64,
    /// Times predicted visible.
    pub visible: u32,
    /// Times matched.
    pub found: u32,
    /// DynaPix point weight.
    pub weight: f32,
}

/// The whole map with dense indices.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapSnapshot {
    /// Pyramid levels of the keypoints.
    pub pyramid_levels: u32,
    /// Pyramid scale factor.
    pub scale_factor: f32,
    /// Next keyframe sequence number.
    pub next_kf_seq: u64,
    /// Next map point sequence number.
    pub next_mp_seq: u64,
    /// The origin keyframe.
    pub origin: Option<u32>,
    /// Keyframes sorted by sequence number.
    pub keyframes: Vec<KeyFrameSnapshot>,
    /// Map points sorted by creation order.
    pub points: Vec<MapPointSnapshot>,
}

fn sorted_indices<'a>(
    ids: impl Iterator<Item = &'a KeyFrameId>,
    index: &HashMap<KeyFrameId, u32>,
) -> Vec<u32> {
    let mut v: Vec<u32> = ids.filter_map(|id| index.get(id).copied()).collect();
    v.sort_unstable();
    v.dedup();
    v
}

impl MapSnapshot {
    /// The dense copy of `map`.
    pub fn from_map(map: &Map) -> Self {
        let kfs = map.keyframes_sorted();
        let kf_index: HashMap<KeyFrameId, u32> = kfs
            .iter()
            .enumerate()
            .map(|(i, (id, _))| (*id, i as u32))
            .collect();
        let mut pts: Vec<(MapPointId, &MapPoint)> = map
            .point_ids()
            .into_iter()
            .filter_map(|id| Some((id, map.point(id)?)))
            .collect();
        pts.sort_by(|a, b| a.1.seq.cmp(&b.1.seq).then(a.0.cmp(&b.0)));
        let mp_index: HashMap<MapPointId, u32> = pts
            .iter()
            .enumerate()
            .map(|(i, (id, _))| (*id, i as u32))
            .collect();
        let keyframes = kfs
            .iter()
            .map(|(_, k)| KeyFrameSnapshot {
                seq: k.seq,
                frame_id: k.frame_id,
                timestamp: k.timestamp,
                pose: k.pose,
                keys: k.keys.clone(),
                keys_un: k.keys_un.clone(),
                descriptors: k.descriptors.clone(),
                depth: k.depth.clone(),
                u_right: k.u_right.clone(),
                weights: k.weights.clone(),
                dynamic_class: k.dynamic_class.clone(),
                map_points: k
                    .map_points
                    .iter()
                    .map(|m| m.and_then(|id| mp_index.get(&id).copied()))
                    .collect(),
                bow: k.bow.clone(),
                feat: k.feat.clone(),
                covisibility: k
                    .ordered
                    .iter()
                    .filter_map(|(id, w)| Some((*kf_index.get(id)?, *w as u64)))
                    .collect(),
                parent: k.parent.and_then(|p| kf_index.get(&p).copied()),
                children: sorted_indices(k.children.iter(), &kf_index),
                loop_edges: sorted_indices(k.loop_edges.iter(), &kf_index),
            })
            .collect();
        let points = pts
            .iter()
            .map(|(_, p)| {
                let mut observations: Vec<(u32, u32)> = p
                    .observations
                    .iter()
                    .filter_map(|(k, &i)| Some((*kf_index.get(k)?, u32::try_from(i).ok()?)))
                    .collect();
                observations.sort_unstable();
                let first_observer = observations.first().map(|o| o.0);
                MapPointSnapshot {
                    seq: p.seq,
                    position: p.position,
                    normal: p.normal,
                    min_distance: p.min_distance,
                    max_distance: p.max_distance,
                    descriptor: p.descriptor,
                    observations,
                    num_obs: p.num_obs as u64,
                    // A stale reference falls back to the first observer, as
                    // `Map::erase_observation` does, so a reload re-encodes identically.
                    reference: kf_index.get(&p.reference).copied().or(first_observer),
                    first_kf_seq: p.first_kf_seq,
                    visible: p.visible,
                    found: p.found,
                    weight: p.weight,
                }
            })
            .collect();
        Self {
            pyramid_levels: u32::try_from(map.pyramid.levels).unwrap_or(u32::MAX),
            scale_factor: map.pyramid.scale_factor,
            next_kf_seq: map.next_keyframe_seq(),
            next_mp_seq: map.next_point_seq(),
            origin: map.origin.and_then(|o| kf_index.get(&o).copied()),
            keyframes,
            points,
        }
    }

    /// The pyramid the keypoint octaves refer to.
    pub fn pyramid(&self) -> ScalePyramid {
        ScalePyramid::new(self.pyramid_levels as usize, self.scale_factor)
    }

    /// Rebuilds a live map; feature grids span `bounds` (the camera's undistorted image
    /// bounds). Never fails: on an unvalidated snapshot an out-of-range index becomes a stale
    /// id, which every map accessor treats as absent.
    pub fn into_map(self, bounds: ImageBounds, params: MapParams) -> Map {
        let pyramid = self.pyramid();
        let kf = KeyFrameId::dense;
        let keyframes: Vec<KeyFrame> = self
            .keyframes
            .into_iter()
            .map(|k| {
                let grid = FeatureGrid::new(bounds, &k.keys_un);
                KeyFrame {
                    seq: k.seq,
                    frame_id: k.frame_id,
                    timestamp: k.timestamp,
                    pose: k.pose,
                    keys: k.keys,
                    keys_un: k.keys_un,
                    descriptors: k.descriptors,
                    depth: k.depth,
                    u_right: k.u_right,
                    weights: k.weights,
                    dynamic_class: k.dynamic_class,
                    map_points: k
                        .map_points
                        .iter()
                        .map(|m| m.map(MapPointId::dense))
                        .collect(),
                    grid,
                    bow: k.bow,
                    feat: k.feat,
                    connections: k
                        .covisibility
                        .iter()
                        .map(|&(o, w)| (kf(o), w as usize))
                        .collect::<BTreeMap<_, _>>(),
                    ordered: k
                        .covisibility
                        .iter()
                        .map(|&(o, w)| (kf(o), w as usize))
                        .collect(),
                    parent: k.parent.map(kf),
                    children: k.children.iter().map(|&c| kf(c)).collect::<BTreeSet<_>>(),
                    loop_edges: k.loop_edges.iter().map(|&c| kf(c)).collect::<BTreeSet<_>>(),
                }
            })
            .collect();
        let points: Vec<MapPoint> = self
            .points
            .into_iter()
            .map(|p| {
                let observations: BTreeMap<KeyFrameId, usize> = p
                    .observations
                    .iter()
                    .map(|&(k, i)| (kf(k), i as usize))
                    .collect();
                // A point whose reference was culled falls back to its first observer, as
                // `Map::erase_observation` does; with no observer it keeps a stale id.
                let reference = p
                    .reference
                    .map(kf)
                    .or_else(|| observations.keys().next().copied())
                    .unwrap_or(kf(u32::MAX));
                MapPoint {
                    seq: p.seq,
                    position: p.position,
                    normal: p.normal,
                    min_distance: p.min_distance,
                    max_distance: p.max_distance,
                    descriptor: p.descriptor,
                    observations,
                    num_obs: usize::try_from(p.num_obs).unwrap_or(usize::MAX),
                    reference,
                    first_kf_seq: p.first_kf_seq,
                    visible: p.visible,
                    found: p.found,
                    weight: p.weight,
                    descriptor_basis: (Vec::new(), p.descriptor),
                }
            })
            .collect();
        Map::from_dense(
            pyramid,
            params,
            keyframes,
            points,
            self.origin.map(kf),
            self.next_kf_seq,
            self.next_mp_seq,
        )
    }

    /// Checks every index, length and number (what [`super::decode`] guarantees).
    pub fn validate(&self) -> Result<(), PersistError> {
        let bad = |what: String| Err(PersistError::corrupt(what));
        if !(1..=64).contains(&self.pyramid_levels) {
            return bad(format!("{} pyramid levels", self.pyramid_levels));
        }
        if !(self.scale_factor.is_finite() && self.scale_factor >= 1.0) {
            return bad(format!("pyramid scale factor {}", self.scale_factor));
        }
        let nk = self.keyframes.len();
        let np = self.points.len();
        let kf_ok = |i: u32| (i as usize) < nk;
        if let Some(o) = self.origin
            && !kf_ok(o)
        {
            return bad(format!("origin keyframe {o} of {nk}"));
        }
        let mut prev_seq: Option<u64> = None;
        for (ki, k) in self.keyframes.iter().enumerate() {
            let ctx = |s: String| PersistError::corrupt(format!("keyframe {ki}: {s}"));
            if prev_seq.is_some_and(|p| k.seq <= p) || k.seq >= self.next_kf_seq {
                return Err(ctx(format!("sequence number {} out of order", k.seq)));
            }
            prev_seq = Some(k.seq);
            if !k.timestamp.is_finite() {
                return Err(ctx("timestamp not finite".into()));
            }
            check_pose(&k.pose).map_err(ctx)?;
            let n = k.keys.len();
            let lens = [
                ("undistorted keypoints", k.keys_un.len()),
                ("descriptors", k.descriptors.len()),
                ("depths", k.depth.len()),
                ("right coordinates", k.u_right.len()),
                ("weights", k.weights.len()),
                ("dynamic flags", k.dynamic_class.len()),
                ("map point matches", k.map_points.len()),
            ];
            for (what, len) in lens {
                if len != n {
                    return Err(ctx(format!("{len} {what} for {n} keypoints")));
                }
            }
            for (i, kp) in k.keys.iter().chain(&k.keys_un).enumerate() {
                let finite = [kp.x, kp.y, kp.angle, kp.response, kp.size]
                    .iter()
                    .all(|v| v.is_finite());
                if !finite || u32::from(kp.octave) >= self.pyramid_levels {
                    return Err(ctx(format!("keypoint {} invalid", i % n.max(1))));
                }
            }
            let floats = k.depth.iter().chain(&k.u_right).chain(&k.weights);
            if floats.into_iter().any(|v| !v.is_finite()) {
                return Err(ctx("depth, right coordinate or weight not finite".into()));
            }
            if let Some(m) = k.map_points.iter().flatten().find(|&&m| m as usize >= np) {
                return Err(ctx(format!("map point {m} of {np}")));
            }
            if k.bow.iter().any(|w| !w.1.is_finite()) {
                return Err(ctx("bag-of-words weight not finite".into()));
            }
            if k.bow.windows(2).any(|w| w[0].0 >= w[1].0) {
                return Err(ctx("bag-of-words words not ascending".into()));
            }
            if k.feat.windows(2).any(|w| w[0].0 >= w[1].0) {
                return Err(ctx("feature-vector nodes not ascending".into()));
            }
            if let Some(i) = k.feat.iter().flat_map(|f| &f.1).find(|&&i| i as usize >= n) {
                return Err(ctx(format!("feature-vector keypoint {i} of {n}")));
            }
            let mut seen = BTreeSet::new();
            for &(o, _) in &k.covisibility {
                if !kf_ok(o) || o as usize == ki || !seen.insert(o) {
                    return Err(ctx(format!("covisibility edge to keyframe {o}")));
                }
            }
            let links = k.parent.iter().chain(&k.children).chain(&k.loop_edges);
            if let Some(o) = links.into_iter().find(|&&o| !kf_ok(o) || o as usize == ki) {
                return Err(ctx(format!("tree or loop link to keyframe {o} of {nk}")));
            }
            if k.children.windows(2).any(|w| w[0] >= w[1])
                || k.loop_edges.windows(2).any(|w| w[0] >= w[1])
            {
                return Err(ctx("children or loop edges not ascending".into()));
            }
        }
        // The spanning tree must be a forest: every parent chain ends within nk steps.
        for ki in 0..nk {
            let mut cur = ki;
            let mut steps = 0;
            while let Some(p) = self.keyframes.get(cur).and_then(|k| k.parent) {
                cur = p as usize;
                steps += 1;
                if steps > nk {
                    return bad(format!("spanning-tree cycle through keyframe {ki}"));
                }
            }
        }
        let mut prev_seq: Option<u64> = None;
        for (pi, p) in self.points.iter().enumerate() {
            let ctx = |s: String| PersistError::corrupt(format!("map point {pi}: {s}"));
            if prev_seq.is_some_and(|s| p.seq <= s) || p.seq >= self.next_mp_seq {
                return Err(ctx(format!("sequence number {} out of order", p.seq)));
            }
            prev_seq = Some(p.seq);
            let finite = p
                .position
                .iter()
                .chain(p.normal.iter())
                .all(|v| v.is_finite())
                && p.min_distance.is_finite()
                && p.max_distance.is_finite()
                && p.weight.is_finite();
            if !finite {
                return Err(ctx("non-finite geometry or weight".into()));
            }
            if let Some(r) = p.reference
                && !kf_ok(r)
            {
                return Err(ctx(format!("reference keyframe {r} of {nk}")));
            }
            if p.observations.windows(2).any(|w| w[0].0 >= w[1].0) {
                return Err(ctx("observations not ascending by keyframe".into()));
            }
            for &(k, i) in &p.observations {
                let Some(kf) = self.keyframes.get(k as usize) else {
                    return Err(ctx(format!("observed by keyframe {k} of {nk}")));
                };
                if i as usize >= kf.keys.len() {
                    return Err(ctx(format!("keypoint {i} of keyframe {k} out of range")));
                }
            }
        }
        Ok(())
    }
}

/// A pose is usable when all its numbers are finite and its quaternion is unit within float
/// noise (it is stored bit-exact, so anything else is corruption).
fn check_pose(pose: &Se3) -> Result<(), String> {
    let q = pose.rotation.quaternion().coords;
    let t = pose.translation.vector;
    if !q.iter().chain(t.iter()).all(|v| v.is_finite()) {
        return Err("pose not finite".into());
    }
    if (q.norm() - 1.0).abs() > 1e-6 {
        return Err(format!("pose quaternion norm {}", q.norm()));
    }
    Ok(())
}
