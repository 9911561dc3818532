//! Keyframe ↔ keyframe matching for loop verification (ORB-SLAM2 `ORBmatcher`, spec §6.6):
//! bag-of-words guided matching between the map points of two keyframes
//! (`SearchByBoW(KeyFrame*, KeyFrame*)`), the two-way guided search through a relative
//! transform (`SearchBySim3` with scale 1) and the projection of the loop neighbourhood's map
//! points with the corrected pose (`SearchByProjection(KeyFrame*, Sim3, …)`).

use dynapix_geometry::Se3;
use nalgebra::Vector3;

use crate::camera::RgbdCamera;
use crate::features::hamming;
use crate::ids::{KeyFrameId, MapPointId};
use crate::map::{KeyFrame, Map, MapPoint};
use crate::matcher::{MatcherParams, RotationHistogram};
use crate::pose::transform;

/// Matches the map points of `kf1` to those of `kf2` among keypoints sharing a vocabulary
/// node: Hamming distance below `TH_LOW`, the ratio test against the second best, one-to-one
/// on the `kf2` side, and the rotation-consistency check. Returns per keypoint of `kf1` the
/// matched map point of `kf2` and the number of matches. Keyframes without feature vectors
/// (no vocabulary) give no matches.
pub(crate) fn search_by_bow(
    map: &Map,
    kf1: &KeyFrame,
    kf2: &KeyFrame,
    ratio: f32,
    params: &MatcherParams,
) -> (Vec<Option<MapPointId>>, usize) {
    let mut matches: Vec<Option<MapPointId>> = vec![None; kf1.keys_un.len()];
    let mut matched2 = vec![false; kf2.keys_un.len()];
    let mut hist = RotationHistogram::new(params);
    let mut n = 0;
    let (f1, f2) = (&kf1.feat, &kf2.feat);
    let (mut a, mut b) = (0, 0);
    while a < f1.len() && b < f2.len() {
        let (na, nb) = (f1[a].0, f2[b].0);
        if na < nb {
            a += 1;
            continue;
        }
        if nb < na {
            b += 1;
            continue;
        }
        for &i1 in &f1[a].1 {
            let i1 = i1 as usize;
            let Some(Some(mp1)) = kf1.map_points.get(i1) else {
                continue;
            };
            if map.point(*mp1).is_none() {
                continue;
            }
            let Some(d1) = kf1.descriptors.get(i1) else {
                continue;
            };
            let mut best = (u32::MAX, usize::MAX);
            let mut second = u32::MAX;
            for &i2 in &f2[b].1 {
                let i2 = i2 as usize;
                if matched2.get(i2).copied().unwrap_or(true) {
                    continue;
                }
                let Some(Some(mp2)) = kf2.map_points.get(i2) else {
                    continue;
                };
                if map.point(*mp2).is_none() {
                    continue;
                }
                let Some(d2) = kf2.descriptors.get(i2) else {
                    continue;
                };
                let d = hamming(d1, d2);
                if d < best.0 {
                    second = best.0;
                    best = (d, i2);
                } else if d < second {
                    second = d;
                }
            }
            if best.0 < params.th_low && (best.0 as f32) < ratio * second as f32 {
                let (Some(mp2), Some(k1), Some(k2), Some(slot)) = (
                    kf2.map_points.get(best.1).copied().flatten(),
                    kf1.keys_un.get(i1),
                    kf2.keys_un.get(best.1),
                    matches.get_mut(i1),
                ) else {
                    continue;
                };
                *slot = Some(mp2);
                if let Some(m) = matched2.get_mut(best.1) {
                    *m = true;
                }
                hist.add(k1.angle, k2.angle, i1);
                n += 1;
            }
        }
        a += 1;
        b += 1;
    }
    for i in hist.rejected() {
        if matches.get_mut(i).and_then(|m| m.take()).is_some() {
            n -= 1;
        }
    }
    (matches, n)
}

/// Best free keypoint of `kf` for map point `mp` projected at camera-frame position `pc`:
/// inside the image, within the point's scale-invariance distance (`dist` from the camera
/// centre), searched in a square of `th`·scale around the projection among keypoints of the
/// predicted level or one finer. Returns (keypoint, Hamming distance).
#[allow(clippy::too_many_arguments)]
fn best_in_area(
    map: &Map,
    kf: &KeyFrame,
    cam: &RgbdCamera,
    mp: &MapPoint,
    pc: &Vector3<f64>,
    dist: f64,
    th: f32,
    taken: &dyn Fn(usize) -> bool,
) -> Option<(usize, u32)> {
    let (u, v, _) = cam.project(pc)?;
    if !kf.grid.bounds.contains(u, v) {
        return None;
    }
    if dist < 0.8 * mp.min_distance || dist > 1.2 * mp.max_distance {
        return None;
    }
    let pyr = &map.pyramid;
    let level = mp.predict_scale(dist, pyr) as i32;
    let radius = th * pyr.scale_of(level as usize);
    let mut best: Option<(usize, u32)> = None;
    for idx in kf.grid.features_in_area(u as f32, v as f32, radius, -1, -1) {
        let Some(kp) = kf.keys_un.get(idx) else {
            continue;
        };
        let lv = kp.octave as i32;
        if lv < level - 1 || lv > level || taken(idx) {
            continue;
        }
        let Some(d) = kf.descriptors.get(idx) else {
            continue;
        };
        let dist = hamming(&mp.descriptor, d);
        if best.is_none_or(|(_, bd)| dist < bd) {
            best = Some((idx, dist));
        }
    }
    best
}

/// Two-way guided matching through `t12` (camera 2 → camera 1): the unmatched map points of
/// `kf1` are projected into `kf2` and those of `kf2` into `kf1` within `th`·scale (Hamming ≤
/// `TH_HIGH`); a pair is added to `matches` (per keypoint of `kf1`) only when both searches
/// agree. Returns the number of new matches.
#[allow(clippy::too_many_arguments)]
pub(crate) fn search_by_se3(
    map: &Map,
    cam: &RgbdCamera,
    kf1: &KeyFrame,
    (id2, kf2): (KeyFrameId, &KeyFrame),
    matches: &mut [Option<MapPointId>],
    t12: &Se3,
    th: f32,
    params: &MatcherParams,
) -> usize {
    let t21 = t12.inverse();
    let mut already2 = vec![false; kf2.keys_un.len()];
    for mp in matches.iter().flatten() {
        if let Some(&i2) = map.point(*mp).and_then(|p| p.observations.get(&id2))
            && let Some(a) = already2.get_mut(i2)
        {
            *a = true;
        }
    }
    // kf1 → kf2.
    let mut match1: Vec<Option<usize>> = vec![None; kf1.keys_un.len()];
    for (i1, slot) in kf1.map_points.iter().enumerate() {
        if matches.get(i1).is_none_or(|m| m.is_some()) {
            continue;
        }
        let Some(mp) = slot.and_then(|id| map.point(id)) else {
            continue;
        };
        let pc1 = transform(&kf1.pose, &mp.position);
        let pc2 = transform(&t21, &pc1);
        // Distance to the centre of kf2 as seen through the loop transform.
        let dist = pc2.norm();
        if let Some((idx, d)) = best_in_area(map, kf2, cam, mp, &pc2, dist, th, &|_| false)
            && d <= params.th_high
        {
            match1[i1] = Some(idx);
        }
    }
    // kf2 → kf1.
    let mut match2: Vec<Option<usize>> = vec![None; kf2.keys_un.len()];
    for (i2, slot) in kf2.map_points.iter().enumerate() {
        if already2.get(i2).copied().unwrap_or(true) {
            continue;
        }
        let Some(mp) = slot.and_then(|id| map.point(id)) else {
            continue;
        };
        let pc2 = transform(&kf2.pose, &mp.position);
        let pc1 = transform(t12, &pc2);
        let dist = pc1.norm();
        if let Some((idx, d)) = best_in_area(map, kf1, cam, mp, &pc1, dist, th, &|_| false)
            && d <= params.th_high
        {
            match2[i2] = Some(idx);
        }
    }
    let mut found = 0;
    for (i1, m) in match1.iter().enumerate() {
        let Some(i2) = *m else { continue };
        if match2.get(i2).copied().flatten() == Some(i1)
            && let Some(mp2) = kf2.map_points.get(i2).copied().flatten()
            && let Some(slot) = matches.get_mut(i1)
        {
            *slot = Some(mp2);
            found += 1;
        }
    }
    found
}

/// Projects `points` into `kf` with pose `tcw` (the corrected pose of the loop) and matches
/// each to the best keypoint not yet in `matched` within `th`·scale, with the viewing-angle
/// (< 60°) and distance checks and Hamming ≤ `TH_LOW`. Returns the number of new matches.
#[allow(clippy::too_many_arguments)]
pub(crate) fn search_by_projection(
    map: &Map,
    cam: &RgbdCamera,
    kf: &KeyFrame,
    tcw: &Se3,
    points: &[MapPointId],
    matched: &mut [Option<MapPointId>],
    th: f32,
    params: &MatcherParams,
) -> usize {
    let center = tcw.inverse().translation.vector;
    let already: std::collections::HashSet<MapPointId> =
        matched.iter().flatten().copied().collect();
    let mut n = 0;
    for &id in points {
        if already.contains(&id) {
            continue;
        }
        let Some(mp) = map.point(id) else { continue };
        let pc = transform(tcw, &mp.position);
        let po = mp.position - center;
        let dist = po.norm();
        if po.dot(&mp.normal) < 0.5 * dist {
            continue;
        }
        let taken = |idx: usize| matched.get(idx).is_none_or(|m| m.is_some());
        if let Some((idx, d)) = best_in_area(map, kf, cam, mp, &pc, dist, th, &taken)
            && d <= params.th_low
            && let Some(slot) = matched.get_mut(idx)
        {
            *slot = Some(id);
            n += 1;
        }
    }
    n
}
