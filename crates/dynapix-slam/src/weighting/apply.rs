//! The DynaPix rules applied to frames and the map (they sit above both): birth gates for a
//! keypoint of a frame or keyframe, semantic class masks (DynaPix+), and the per-map-point
//! probability update with removal at γ_del after tracking.

use crate::frame::Frame;
use crate::ids::{KeyFrameId, MapPointId};
use crate::map::Map;
use crate::weighting::params::{
    BirthSource, DynaPixParams, Weighting, may_birth, prob_of_weight, should_delete,
    update_point_probability,
};

/// [`may_birth`] for keypoint `i` of a frame (false for an index out of range).
pub fn may_birth_in_frame(p: &DynaPixParams, frame: &Frame, i: usize, source: BirthSource) -> bool {
    let w = frame.weights.get(i).copied().unwrap_or(1.0);
    let dynamic = frame.dynamic_class.get(i).copied().unwrap_or(false);
    may_birth(p, w, dynamic, source)
}

/// [`may_birth`] for keypoint `i` of keyframe `kf` of `map` (false when either is missing).
pub fn may_birth_in_keyframe(map: &Map, kf: KeyFrameId, i: usize, source: BirthSource) -> bool {
    let p = &map.params.dynapix;
    let Some(k) = map.keyframe(kf) else {
        return false;
    };
    let Some(&w) = k.weights.get(i) else {
        return false;
    };
    let dynamic = k.dynamic_class.get(i).copied().unwrap_or(false);
    may_birth(p, w, dynamic, source)
}

/// Marks the keypoints of `frame` that lie on a non-zero pixel of the semantic `mask`
/// (DynaPix+: 8-bit masks, non-zero = a dynamic class), sampled at the image position like the
/// weights; keypoints outside the mask image are not marked.
pub fn apply_class_mask(frame: &mut Frame, mask: &image::GrayImage) {
    for (k, flag) in frame.keys.iter().zip(frame.dynamic_class.iter_mut()) {
        if !(k.x >= 0.0 && k.y >= 0.0) {
            continue;
        }
        let (x, y) = (k.x as u32, k.y as u32);
        if x < mask.width() && y < mask.height() {
            *flag = mask.get_pixel(x, y).0[0] != 0;
        }
    }
}

/// Counters of one [`update_matched_points`] call.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UpdateStats {
    /// Map points whose probability was updated.
    pub updated: usize,
    /// Map points removed because their probability reached γ_del.
    pub deleted: usize,
}

/// Updates the motion probability of every map point matched (as an inlier) in the tracked
/// `frame` from the keypoint's P, and removes the points that reach γ_del from the map and the
/// frame at once (spec §7.14: an atomic "bad" instead of the reference's lagging flag).
/// The reference only tests observations with depth (spec §2.3).
pub fn update_matched_points(map: &mut Map, frame: &mut Frame) -> UpdateStats {
    update_matched_points_logged(map, frame, None)
}

/// [`update_matched_points`] that also appends the world position of every removed point to
/// `removed` when given (for a viewer; nothing is allocated without it).
pub fn update_matched_points_logged(
    map: &mut Map,
    frame: &mut Frame,
    mut removed: Option<&mut Vec<nalgebra::Vector3<f64>>>,
) -> UpdateStats {
    let p = map.params.dynapix.clone();
    let mut stats = UpdateStats::default();
    if !p.enabled() {
        return stats;
    }
    let mut doomed: Vec<(usize, MapPointId)> = Vec::new();
    for i in 0..frame.len() {
        let Some(id) = frame.map_points.get(i).copied().flatten() else {
            continue;
        };
        if frame.outlier.get(i).copied().unwrap_or(true) {
            continue;
        }
        if p.weighting == Weighting::Reference && frame.depth.get(i).is_none_or(|&d| d <= 0.0) {
            continue;
        }
        let obs = prob_of_weight(frame.weights.get(i).copied().unwrap_or(1.0));
        let Some(mp) = map.point_mut(id) else {
            continue;
        };
        let new_p = update_point_probability(p.update, prob_of_weight(mp.weight), obs);
        mp.weight = 1.0 - new_p;
        stats.updated += 1;
        if should_delete(&p, new_p) {
            doomed.push((i, id));
        }
    }
    for (i, id) in doomed {
        if let Some(mp) = map.point(id) {
            if let Some(out) = removed.as_deref_mut() {
                out.push(mp.position);
            }
            map.cull_point(id);
            stats.deleted += 1;
        }
        if let Some(slot) = frame.map_points.get_mut(i) {
            *slot = None;
        }
    }
    stats
}
