//! ORB descriptor matching (ORB-SLAM2 `ORBmatcher`, spec §6.3/§6.5/§6.8): search by
//! projection frame → frame (motion model) and local map → frame, keyframe → frame matching
//! guided by bag-of-words nodes (brute force when no vocabulary is loaded), search for
//! triangulation with the epipolar constraint, fusion of map points into a keyframe, and the
//! rotation-consistency histogram.

use std::collections::HashSet;

use nalgebra::{Matrix3, Vector3};

use crate::camera::RgbdCamera;
use crate::features::ScalePyramid;
use crate::features::{Descriptor, KeyPoint, hamming};
use crate::frame::Frame;
use crate::ids::{KeyFrameId, MapPointId};
use crate::map::{KeyFrame, Map};
use crate::pose::transform;

/// Matching thresholds (ORB-SLAM2 constants).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct MatcherParams {
    /// Loose Hamming threshold (`TH_HIGH` = 100).
    pub th_high: u32,
    /// Strict Hamming threshold (`TH_LOW` = 50).
    pub th_low: u32,
    /// Bins of the rotation histogram (30).
    pub histo_len: usize,
    /// A bin is kept when it holds at least this fraction of the largest (0.1).
    pub histo_min_ratio: f32,
}

impl Default for MatcherParams {
    fn default() -> Self {
        Self {
            th_high: 100,
            th_low: 50,
            histo_len: 30,
            histo_min_ratio: 0.1,
        }
    }
}

/// Rotation-consistency histogram: keeps matches in the three most populated bins of the
/// keypoint angle difference.
pub struct RotationHistogram {
    bins: Vec<Vec<usize>>,
    min_ratio: f32,
}

impl RotationHistogram {
    /// Empty histogram.
    pub fn new(params: &MatcherParams) -> Self {
        Self {
            bins: vec![Vec::new(); params.histo_len.max(1)],
            min_ratio: params.histo_min_ratio,
        }
    }

    /// Records match `idx` with angle difference `a1 − a2` (degrees).
    pub fn add(&mut self, a1: f32, a2: f32, idx: usize) {
        let mut rot = a1 - a2;
        if !rot.is_finite() {
            rot = 0.0;
        }
        rot = rot.rem_euclid(360.0);
        let n = self.bins.len();
        let bin = ((rot * n as f32 / 360.0).round() as usize) % n;
        if let Some(b) = self.bins.get_mut(bin) {
            b.push(idx);
        }
    }

    /// Indices of matches outside the three largest bins (bins below `min_ratio`·largest are
    /// dropped too).
    pub fn rejected(&self) -> Vec<usize> {
        let mut order: Vec<usize> = (0..self.bins.len()).collect();
        order.sort_by(|&a, &b| self.bins[b].len().cmp(&self.bins[a].len()).then(a.cmp(&b)));
        let max1 = self.bins[order[0]].len() as f32;
        let mut keep = vec![false; self.bins.len()];
        for (rank, &b) in order.iter().take(3).enumerate() {
            let c = self.bins[b].len() as f32;
            if rank == 0 || c >= self.min_ratio * max1 {
                keep[b] = true;
            } else {
                break;
            }
        }
        let mut out = Vec::new();
        for (b, idxs) in self.bins.iter().enumerate() {
            if !keep[b] {
                out.extend_from_slice(idxs);
            }
        }
        out
    }
}

fn radius_by_viewing_cos(view_cos: f64) -> f32 {
    if view_cos > 0.998 { 2.5 } else { 4.0 }
}

/// A local map point predicted visible in the current frame (tracking's frustum test).
#[derive(Clone, Copy, Debug)]
pub struct ProjectionCandidate {
    /// The map point.
    pub point: MapPointId,
    /// Projected column.
    pub u: f64,
    /// Projected row.
    pub v: f64,
    /// Projected virtual right coordinate.
    pub u_right: f64,
    /// Predicted pyramid level.
    pub level: usize,
    /// Cosine between viewing ray and the point's mean normal.
    pub view_cos: f64,
}

/// Local-map search: matches the candidates into free keypoints of `frame` (search radius
/// 2.5/4.0 by viewing angle × `th` × level scale; ratio test between the best two when they
/// are on the same level; ORB-SLAM2 `SearchByProjection(Frame&, vector<MapPoint*>, th)`).
pub fn search_local_by_projection(
    frame: &mut Frame,
    map: &Map,
    candidates: &[ProjectionCandidate],
    th: f32,
    ratio: f32,
    params: &MatcherParams,
) -> usize {
    let pyr = &map.pyramid;
    let mut n = 0;
    for c in candidates {
        let Some(mp) = map.point(c.point) else {
            continue;
        };
        let mut r = radius_by_viewing_cos(c.view_cos);
        if th != 1.0 {
            r *= th;
        }
        let radius = r * pyr.scale_of(c.level);
        let idxs = frame.grid.features_in_area(
            c.u as f32,
            c.v as f32,
            radius,
            c.level as i32 - 1,
            c.level as i32,
        );
        let mut best = (u32::MAX, usize::MAX, -1i32);
        let mut second = (u32::MAX, -1i32);
        for idx in idxs {
            if let Some(Some(m)) = frame.map_points.get(idx)
                && map.point(*m).is_some_and(|p| p.num_obs > 0)
            {
                continue;
            }
            let ur = frame.u_right.get(idx).copied().unwrap_or(-1.0);
            if ur > 0.0 && (c.u_right as f32 - ur).abs() > radius {
                continue;
            }
            let Some(d) = frame.descriptors.get(idx) else {
                continue;
            };
            let dist = hamming(&mp.descriptor, d);
            let level = frame.keys_un.get(idx).map_or(0, |k| k.octave as i32);
            if dist < best.0 {
                second = (best.0, best.2);
                best = (dist, idx, level);
            } else if dist < second.0 {
                second = (dist, level);
            }
        }
        if best.0 <= params.th_high {
            if best.2 == second.1 && (best.0 as f32) > ratio * second.0 as f32 {
                continue;
            }
            if let Some(slot) = frame.map_points.get_mut(best.1) {
                *slot = Some(c.point);
                n += 1;
            }
        }
    }
    n
}

/// Motion-model search: projects the last frame's matched points into `cur` (pose already
/// predicted) and matches within `th`·scale; forward motion searches finer-or-equal
/// octaves, backward coarser-or-equal (ORB-SLAM2 `SearchByProjection(Frame&, const Frame&)`).
pub fn search_frame_by_projection(
    cur: &mut Frame,
    last: &Frame,
    map: &Map,
    cam: &RgbdCamera,
    th: f32,
    check_orientation: bool,
    params: &MatcherParams,
) -> usize {
    let (Some(tcw), Some(tlw)) = (cur.pose, last.pose) else {
        return 0;
    };
    let pyr = &map.pyramid;
    let twc = tcw.inverse().translation.vector;
    let tlc = transform(&tlw, &twc);
    let b = cam.baseline();
    let forward = tlc.z > b;
    let backward = -tlc.z > b;
    let mut hist = RotationHistogram::new(params);
    let mut n = 0;
    let bounds = cur.grid.bounds;
    for i in 0..last.len() {
        let Some(Some(mpid)) = last.map_points.get(i) else {
            continue;
        };
        if last.outlier.get(i).copied().unwrap_or(false) {
            continue;
        }
        let Some(mp) = map.point(*mpid) else { continue };
        let pc = transform(&tcw, &mp.position);
        let Some((u, v, ur_pred)) = cam.project(&pc) else {
            continue;
        };
        if !bounds.contains(u, v) {
            continue;
        }
        let last_oct = last.keys_un[i].octave as i32;
        let radius = th * pyr.scale_of(last_oct as usize);
        let idxs = if forward {
            cur.grid
                .features_in_area(u as f32, v as f32, radius, last_oct, -1)
        } else if backward {
            cur.grid
                .features_in_area(u as f32, v as f32, radius, 0, last_oct)
        } else {
            cur.grid
                .features_in_area(u as f32, v as f32, radius, last_oct - 1, last_oct + 1)
        };
        let mut best = (u32::MAX, usize::MAX);
        for idx in idxs {
            if let Some(Some(m)) = cur.map_points.get(idx)
                && map.point(*m).is_some_and(|p| p.num_obs > 0)
            {
                continue;
            }
            let ur = cur.u_right[idx];
            if ur > 0.0 && (ur_pred as f32 - ur).abs() > radius {
                continue;
            }
            let dist = hamming(&mp.descriptor, &cur.descriptors[idx]);
            if dist < best.0 {
                best = (dist, idx);
            }
        }
        if best.0 <= params.th_high {
            cur.map_points[best.1] = Some(*mpid);
            n += 1;
            if check_orientation {
                hist.add(last.keys_un[i].angle, cur.keys_un[best.1].angle, best.1);
            }
        }
    }
    let before = n;
    if check_orientation {
        for idx in hist.rejected() {
            if cur.map_points[idx].take().is_some() {
                n -= 1;
            }
        }
    }
    tracing::debug!(
        frame = cur.id,
        last_matched = last.map_points.iter().flatten().count(),
        before,
        after = n,
        "frame projection"
    );
    n
}

/// Pairs (keyframe keypoint, frame keypoint) to compare: same vocabulary node when both have
/// feature vectors, else every pair.
fn candidate_groups(
    kf_feat: &[(u32, Vec<u32>)],
    f_feat: &[(u32, Vec<u32>)],
    n_kf: usize,
    n_f: usize,
) -> Vec<(Vec<u32>, Vec<u32>)> {
    if kf_feat.is_empty() || f_feat.is_empty() {
        return vec![((0..n_kf as u32).collect(), (0..n_f as u32).collect())];
    }
    let mut out = Vec::new();
    let (mut a, mut b) = (0, 0);
    while a < kf_feat.len() && b < f_feat.len() {
        let (na, nb) = (kf_feat[a].0, f_feat[b].0);
        if na == nb {
            out.push((kf_feat[a].1.clone(), f_feat[b].1.clone()));
            a += 1;
            b += 1;
        } else if na < nb {
            a += 1;
        } else {
            b += 1;
        }
    }
    out
}

/// Keyframe → frame matching for reference-keyframe tracking and relocalisation: each
/// keyframe keypoint with a map point is matched to the closest free frame keypoint in the
/// same vocabulary node, with `TH_LOW`, the ratio test and optionally the rotation check
/// (ORB-SLAM2 `SearchByBoW(KeyFrame*, Frame&)`). Returns per frame keypoint the matched point.
pub fn search_keyframe_to_frame(
    kf: &KeyFrame,
    frame: &Frame,
    map: &Map,
    ratio: f32,
    check_orientation: bool,
    params: &MatcherParams,
) -> (Vec<Option<MapPointId>>, usize) {
    let mut matches: Vec<Option<MapPointId>> = vec![None; frame.len()];
    let mut hist = RotationHistogram::new(params);
    let mut n = 0;
    for (kf_idx, f_idx) in candidate_groups(&kf.feat, &frame.feat, kf.keys_un.len(), frame.len()) {
        for &i in &kf_idx {
            let i = i as usize;
            let Some(Some(mpid)) = kf.map_points.get(i) else {
                continue;
            };
            if map.point(*mpid).is_none() {
                continue;
            }
            let Some(d_kf) = kf.descriptors.get(i) else {
                continue;
            };
            let mut best = (u32::MAX, usize::MAX);
            let mut second = u32::MAX;
            for &j in &f_idx {
                let j = j as usize;
                if matches.get(j).is_some_and(|m| m.is_some()) {
                    continue;
                }
                let Some(d_f) = frame.descriptors.get(j) else {
                    continue;
                };
                let dist = hamming(d_kf, d_f);
                if dist < best.0 {
                    second = best.0;
                    best = (dist, j);
                } else if dist < second {
                    second = dist;
                }
            }
            if best.0 <= params.th_low && (best.0 as f32) < ratio * second as f32 {
                matches[best.1] = Some(*mpid);
                n += 1;
                if check_orientation {
                    hist.add(kf.keys_un[i].angle, frame.keys_un[best.1].angle, best.1);
                }
            }
        }
    }
    if check_orientation {
        for idx in hist.rejected() {
            if matches[idx].take().is_some() {
                n -= 1;
            }
        }
    }
    (matches, n)
}

/// Relocalisation's extra projection search: projects the map points of `kf` not yet in
/// `found` into `frame` (pose set) within `th`·scale and Hamming ≤ `orb_dist`, with the
/// rotation check (ORB-SLAM2 `SearchByProjection(Frame&, KeyFrame*, set, th, ORBdist)`).
#[allow(clippy::too_many_arguments)]
pub fn search_keyframe_by_projection(
    frame: &mut Frame,
    kf: &KeyFrame,
    map: &Map,
    cam: &RgbdCamera,
    found: &HashSet<MapPointId>,
    th: f32,
    orb_dist: u32,
    params: &MatcherParams,
) -> usize {
    let Some(tcw) = frame.pose else { return 0 };
    let center = tcw.inverse().translation.vector;
    let pyr = &map.pyramid;
    let mut hist = RotationHistogram::new(params);
    let mut n = 0;
    for (i, m) in kf.map_points.iter().enumerate() {
        let Some(mpid) = m else { continue };
        if found.contains(mpid) {
            continue;
        }
        let Some(mp) = map.point(*mpid) else { continue };
        let pc = transform(&tcw, &mp.position);
        let Some((u, v, _)) = cam.project(&pc) else {
            continue;
        };
        if !frame.grid.bounds.contains(u, v) {
            continue;
        }
        let dist3 = (mp.position - center).norm();
        if dist3 < 0.8 * mp.min_distance || dist3 > 1.2 * mp.max_distance {
            continue;
        }
        let level = mp.predict_scale(dist3, pyr) as i32;
        let radius = th * pyr.scale_of(level as usize);
        let idxs = frame
            .grid
            .features_in_area(u as f32, v as f32, radius, level - 1, level + 1);
        let mut best = (u32::MAX, usize::MAX);
        for idx in idxs {
            if frame.map_points[idx].is_some() {
                continue;
            }
            let d = hamming(&mp.descriptor, &frame.descriptors[idx]);
            if d < best.0 {
                best = (d, idx);
            }
        }
        if best.0 <= orb_dist {
            frame.map_points[best.1] = Some(*mpid);
            n += 1;
            hist.add(kf.keys_un[i].angle, frame.keys_un[best.1].angle, best.1);
        }
    }
    for idx in hist.rejected() {
        if frame.map_points[idx].take().is_some() {
            n -= 1;
        }
    }
    n
}

/// Fundamental matrix F12 with x1ᵀ·F12·x2 = 0 between two keyframes.
pub fn fundamental(kf1: &KeyFrame, kf2: &KeyFrame, cam: &RgbdCamera) -> Matrix3<f64> {
    let t12 = kf1.pose * kf2.pose.inverse();
    let r = t12.rotation.to_rotation_matrix().into_inner();
    let t = t12.translation.vector;
    let tx = dynapix_geometry::se3::hat(&t);
    let p = &cam.pinhole;
    let k = Matrix3::new(p.fx, 0.0, p.cx, 0.0, p.fy, p.cy, 0.0, 0.0, 1.0);
    let kinv = k.try_inverse().unwrap_or_else(Matrix3::identity);
    kinv.transpose() * tx * r * kinv
}

fn epipolar_ok(kp1: &KeyPoint, kp2: &KeyPoint, f12: &Matrix3<f64>, pyr: &ScalePyramid) -> bool {
    let x1 = Vector3::new(kp1.x as f64, kp1.y as f64, 1.0);
    let l = f12.transpose() * x1;
    let num = l.x * kp2.x as f64 + l.y * kp2.y as f64 + l.z;
    let den = l.x * l.x + l.y * l.y;
    if den == 0.0 {
        return false;
    }
    num * num / den < 3.84 * pyr.sigma2_of(kp2.octave as usize) as f64
}

/// Matches keypoints without map points between two keyframes for triangulation: Hamming
/// ≤ `TH_LOW`, epipolar distance test, epipole test for keypoints without depth in both, and
/// one-to-one by best distance (ORB-SLAM2 `SearchForTriangulation`, no rotation check).
pub fn search_for_triangulation(
    kf1: &KeyFrame,
    kf2: &KeyFrame,
    f12: &Matrix3<f64>,
    cam: &RgbdCamera,
    pyr: &ScalePyramid,
    params: &MatcherParams,
) -> Vec<(usize, usize)> {
    // Epipole of kf1's centre in kf2.
    let c1_in_2 = transform(&kf2.pose, &kf1.center());
    let (ex, ey) = cam
        .project(&c1_in_2)
        .map_or((f64::NAN, f64::NAN), |(u, v, _)| (u, v));
    let free1: Vec<u32> = (0..kf1.keys_un.len() as u32)
        .filter(|&i| kf1.map_points[i as usize].is_none())
        .collect();
    let free2: Vec<u32> = (0..kf2.keys_un.len() as u32)
        .filter(|&i| kf2.map_points[i as usize].is_none())
        .collect();
    let groups: Vec<(Vec<u32>, Vec<u32>)> = if kf1.feat.is_empty() || kf2.feat.is_empty() {
        vec![(free1, free2)]
    } else {
        candidate_groups(&kf1.feat, &kf2.feat, 0, 0)
    };
    let mut matched2 = vec![false; kf2.keys_un.len()];
    let mut pairs: Vec<(usize, usize)> = Vec::new();
    for (g1, g2) in groups {
        for &i1 in &g1 {
            let i1 = i1 as usize;
            if kf1.map_points[i1].is_some() {
                continue;
            }
            let stereo1 = kf1.u_right[i1] >= 0.0;
            let kp1 = &kf1.keys_un[i1];
            let d1: &Descriptor = &kf1.descriptors[i1];
            let mut best = (params.th_low + 1, usize::MAX);
            for &i2 in &g2 {
                let i2 = i2 as usize;
                if matched2[i2] || kf2.map_points[i2].is_some() {
                    continue;
                }
                let dist = hamming(d1, &kf2.descriptors[i2]);
                if dist > params.th_low || dist > best.0 {
                    continue;
                }
                let kp2 = &kf2.keys_un[i2];
                let stereo2 = kf2.u_right[i2] >= 0.0;
                if !stereo1 && !stereo2 {
                    let dx = ex - kp2.x as f64;
                    let dy = ey - kp2.y as f64;
                    if dx * dx + dy * dy < 100.0 * pyr.scale_of(kp2.octave as usize) as f64 {
                        continue;
                    }
                }
                if epipolar_ok(kp1, kp2, f12, pyr) {
                    best = (dist, i2);
                }
            }
            if best.1 != usize::MAX {
                matched2[best.1] = true;
                pairs.push((i1, best.1));
            }
        }
    }
    pairs
}

/// Projects `points` into keyframe `kf` and fuses each with the best keypoint: an existing
/// map point there is merged (the one with more observations survives), otherwise the
/// observation is added (ORB-SLAM2 `Fuse(KeyFrame*, vector<MapPoint*>, th)`).
pub fn fuse(
    map: &mut Map,
    kf_id: KeyFrameId,
    points: &[MapPointId],
    cam: &RgbdCamera,
    th: f32,
    params: &MatcherParams,
) -> usize {
    let mut fused = 0;
    for &mpid in points {
        let Some(kf) = map.keyframe(kf_id) else {
            return fused;
        };
        let Some(mp) = map.point(mpid) else { continue };
        if mp.observations.contains_key(&kf_id) {
            continue;
        }
        let tcw = kf.pose;
        let center = kf.center();
        let pc = transform(&tcw, &mp.position);
        let Some((u, v, ur)) = cam.project(&pc) else {
            continue;
        };
        if !kf.grid.bounds.contains(u, v) {
            continue;
        }
        let po = mp.position - center;
        let dist3 = po.norm();
        if dist3 < 0.8 * mp.min_distance || dist3 > 1.2 * mp.max_distance {
            continue;
        }
        if po.dot(&mp.normal) < 0.5 * dist3 {
            continue;
        }
        let pyr = &map.pyramid;
        let level = mp.predict_scale(dist3, pyr);
        let radius = th * pyr.scale_of(level);
        let idxs = kf.grid.features_in_area(u as f32, v as f32, radius, -1, -1);
        let mut best = (u32::MAX, usize::MAX);
        for idx in idxs {
            let kp = &kf.keys_un[idx];
            let kl = kp.octave as i32;
            if kl < level as i32 - 1 || kl > level as i32 {
                continue;
            }
            let ex = u - kp.x as f64;
            let ey = v - kp.y as f64;
            let inv_s2 = pyr.inv_sigma2_of(kl as usize) as f64;
            let kur = kf.u_right[idx];
            if kur >= 0.0 {
                let er = ur - kur as f64;
                if (ex * ex + ey * ey + er * er) * inv_s2 > 7.8 {
                    continue;
                }
            } else if (ex * ex + ey * ey) * inv_s2 > 5.99 {
                continue;
            }
            let d = hamming(&mp.descriptor, &kf.descriptors[idx]);
            if d < best.0 {
                best = (d, idx);
            }
        }
        if best.0 > params.th_low {
            continue;
        }
        let existing = kf.map_points[best.1];
        match existing.and_then(|e| map.point(e).map(|p| (e, p.num_obs))) {
            Some((e, e_obs)) => {
                let m_obs = map.point(mpid).map_or(0, |p| p.num_obs);
                if e_obs > m_obs {
                    map.replace_point(mpid, e);
                } else {
                    map.replace_point(e, mpid);
                }
            }
            None => {
                if !crate::weighting::may_birth_in_keyframe(
                    map,
                    kf_id,
                    best.1,
                    crate::weighting::BirthSource::Fusion,
                ) {
                    continue;
                }
                map.add_observation(mpid, kf_id, best.1);
                map.set_keyframe_match(kf_id, best.1, Some(mpid));
            }
        }
        fused += 1;
    }
    fused
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_histogram_keeps_consistent_matches() {
        let p = MatcherParams::default();
        let mut h = RotationHistogram::new(&p);
        for i in 0..20 {
            h.add(10.0, 0.0, i);
        }
        for i in 20..30 {
            h.add(370.0, 0.0, i); // same as 10°
        }
        h.add(180.0, 0.0, 30);
        h.add(100.0, 0.0, 31);
        h.add(250.0, 0.0, 32);
        let rej = h.rejected();
        // Top bin 30 entries; the three singletons: 2nd and 3rd bins hold 1 < 0.1·30 → dropped.
        let mut rej = rej;
        rej.sort();
        assert_eq!(rej, vec![30, 31, 32]);
    }
}
