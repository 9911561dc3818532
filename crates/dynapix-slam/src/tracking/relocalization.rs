//! Relocalisation (ORB-SLAM2 `Tracking::Relocalization`, spec §6.8): candidate keyframes
//! (bag-of-words when a vocabulary is loaded, else the most recent keyframes), keyframe →
//! frame matching (ratio 0.75), a seeded RANSAC pose hypothesis, pose optimisation and the
//! two extra projection searches before accepting with ≥ 50 inliers.
//!
//! The minimal solver is a 3-point rigid alignment of the frame's depth-backprojected
//! keypoints to the map points (RGB-D gives 3-D on both sides); hypotheses are scored by
//! reprojection χ² (5.991·σ²), as ORB-SLAM2 scores its EPnP hypotheses.

use std::collections::{BTreeMap, HashSet};

use dynapix_geometry::Se3;
use nalgebra::{Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::Tracker;
use crate::frame::{Frame, transform};
use crate::map::{KeyFrameId, Map, MapPointId};
use crate::matcher;

/// Relocalisation parameters (ORB-SLAM2 defaults).
#[derive(Clone, Debug, PartialEq)]
pub struct RelocParams {
    /// Keyframe → frame matching ratio (0.75).
    pub ratio: f32,
    /// Minimum matches with a candidate (15).
    pub min_matches: usize,
    /// RANSAC success probability (0.99).
    pub probability: f64,
    /// Minimum RANSAC inliers (10).
    pub min_inliers: usize,
    /// Maximum RANSAC iterations (300).
    pub max_iterations: usize,
    /// Reprojection χ² threshold per σ² (5.991).
    pub chi2: f64,
    /// Candidates examined without a vocabulary (most recent keyframes first).
    pub max_candidates_without_vocabulary: usize,
    /// Fraction of the best common-word count a candidate needs (0.8).
    pub min_common_words_ratio: f32,
    /// Fraction of the best accumulated score a candidate needs (0.75).
    pub min_score_ratio: f64,
    /// Seed of the RANSAC sampler (combined with the frame id).
    pub seed: u64,
}

impl Default for RelocParams {
    fn default() -> Self {
        Self {
            ratio: 0.75,
            min_matches: 15,
            probability: 0.99,
            min_inliers: 10,
            max_iterations: 300,
            chi2: 5.991,
            max_candidates_without_vocabulary: 40,
            min_common_words_ratio: 0.8,
            min_score_ratio: 0.75,
            seed: 0x5eed,
        }
    }
}

/// L1 score between two L1-normalised BoW vectors sorted by word (DBoW2 `L1Scoring`).
pub fn bow_score(a: &[(u32, f64)], b: &[(u32, f64)]) -> f64 {
    let (mut i, mut j) = (0, 0);
    let mut s = 0.0;
    while i < a.len() && j < b.len() {
        match a[i].0.cmp(&b[j].0) {
            std::cmp::Ordering::Equal => {
                let (x, y) = (a[i].1, b[j].1);
                s += (x - y).abs() - x.abs() - y.abs();
                i += 1;
                j += 1;
            }
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
        }
    }
    -s / 2.0
}

/// Candidate keyframes for relocalising `frame` (ORB-SLAM2 `DetectRelocalizationCandidates`).
pub fn candidates(map: &Map, frame: &Frame, p: &RelocParams) -> Vec<KeyFrameId> {
    let kfs = map.keyframes_sorted();
    if frame.bow.is_empty() || kfs.iter().all(|(_, k)| k.bow.is_empty()) {
        return kfs
            .iter()
            .rev()
            .take(p.max_candidates_without_vocabulary)
            .map(|(id, _)| *id)
            .collect();
    }
    let words: HashSet<u32> = frame.bow.iter().map(|w| w.0).collect();
    let mut common: BTreeMap<KeyFrameId, usize> = BTreeMap::new();
    for (id, k) in &kfs {
        let c = k.bow.iter().filter(|w| words.contains(&w.0)).count();
        if c > 0 {
            common.insert(*id, c);
        }
    }
    let Some(&max_common) = common.values().max() else {
        return Vec::new();
    };
    let min_common = (max_common as f32 * p.min_common_words_ratio) as usize;
    let mut scores: BTreeMap<KeyFrameId, f64> = BTreeMap::new();
    for (&id, &c) in &common {
        if c > min_common
            && let Some(k) = map.keyframe(id)
        {
            scores.insert(id, bow_score(&frame.bow, &k.bow));
        }
    }
    let mut acc: Vec<(KeyFrameId, f64, KeyFrameId)> = Vec::new();
    let mut best_acc = 0.0f64;
    for (&id, &s) in &scores {
        let Some(k) = map.keyframe(id) else { continue };
        let (mut total, mut best, mut best_id) = (s, s, id);
        for n in k.best_covisibles(10) {
            if let Some(&sn) = scores.get(&n) {
                total += sn;
                if sn > best {
                    best = sn;
                    best_id = n;
                }
            }
        }
        best_acc = best_acc.max(total);
        acc.push((id, total, best_id));
    }
    let min_score = p.min_score_ratio * best_acc;
    let mut out = Vec::new();
    let mut seen = HashSet::new();
    for (_, total, best_id) in acc {
        if total > min_score && seen.insert(best_id) {
            out.push(best_id);
        }
    }
    out
}

/// Rigid transform `T` minimising Σ|T·a − b|² (Kabsch/Horn, no scale).
fn rigid_fit(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> Option<Se3> {
    if a.len() < 3 || a.len() != b.len() {
        return None;
    }
    let n = a.len() as f64;
    let ca = a.iter().sum::<Vector3<f64>>() / n;
    let cb = b.iter().sum::<Vector3<f64>>() / n;
    let mut h = Matrix3::zeros();
    for (x, y) in a.iter().zip(b) {
        h += (x - ca) * (y - cb).transpose();
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (vt.transpose() * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = vt.transpose() * d * u.transpose();
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let t = cb - rot * ca;
    Some(Se3::from_parts(Translation3::from(t), rot))
}

/// RANSAC pose `T_cw` from matches (keypoint index, world point); returns the pose and the
/// inlier keypoint indices.
fn ransac_pose(
    tracker: &Tracker,
    map: &Map,
    frame: &Frame,
    matches: &[(usize, Vector3<f64>)],
    rng: &mut ChaCha8Rng,
) -> Option<(Se3, Vec<usize>)> {
    let p = &tracker.params.reloc;
    let cam = &tracker.cam;
    // Camera-frame points from depth (only keypoints with depth can seed a hypothesis).
    let seeds: Vec<(usize, Vector3<f64>, Vector3<f64>)> = matches
        .iter()
        .filter_map(|&(i, xw)| {
            let z = *frame.depth.get(i)? as f64;
            if z <= 0.0 {
                return None;
            }
            let kp = frame.keys_un.get(i)?;
            let xc = Vector3::new(
                (kp.x as f64 - cam.pinhole.cx) * z / cam.pinhole.fx,
                (kp.y as f64 - cam.pinhole.cy) * z / cam.pinhole.fy,
                z,
            );
            Some((i, xw, xc))
        })
        .collect();
    if seeds.len() < p.min_inliers.max(3) {
        return None;
    }
    let inliers_of = |t: &Se3| -> Vec<usize> {
        matches
            .iter()
            .filter(|(i, xw)| {
                let pc = transform(t, xw);
                let Some((u, v, _)) = cam.project(&pc) else {
                    return false;
                };
                let kp = &frame.keys_un[*i];
                let (eu, ev) = (u - kp.x as f64, v - kp.y as f64);
                let s2 = map.pyramid.sigma2_of(kp.octave as usize) as f64;
                eu * eu + ev * ev < p.chi2 * s2
            })
            .map(|(i, _)| *i)
            .collect()
    };
    let mut best: Option<(Se3, Vec<usize>)> = None;
    let mut iterations = p.max_iterations;
    let mut it = 0;
    let n = seeds.len();
    while it < iterations {
        it += 1;
        let mut pick = [0usize; 3];
        pick[0] = rng.random_range(0..n);
        pick[1] = rng.random_range(0..n);
        pick[2] = rng.random_range(0..n);
        if pick[0] == pick[1] || pick[1] == pick[2] || pick[0] == pick[2] {
            continue;
        }
        let a: Vec<Vector3<f64>> = pick.iter().map(|&k| seeds[k].1).collect();
        let b: Vec<Vector3<f64>> = pick.iter().map(|&k| seeds[k].2).collect();
        let Some(t) = rigid_fit(&a, &b) else { continue };
        let inl = inliers_of(&t);
        if best.as_ref().is_none_or(|(_, bi)| inl.len() > bi.len()) {
            let ratio = inl.len() as f64 / matches.len() as f64;
            if ratio > 0.0 && ratio < 1.0 {
                let k = ((1.0 - p.probability).ln() / (1.0 - ratio.powi(3)).ln()).ceil();
                if k.is_finite() && k > 0.0 {
                    iterations = iterations.min(k as usize);
                }
            } else if ratio >= 1.0 {
                iterations = it;
            }
            best = Some((t, inl));
        }
    }
    let (t, inl) = best?;
    if inl.len() < p.min_inliers {
        return None;
    }
    // Refine on all depth inliers.
    let set: HashSet<usize> = inl.iter().copied().collect();
    let (a, b): (Vec<_>, Vec<_>) = seeds
        .iter()
        .filter(|s| set.contains(&s.0))
        .map(|s| (s.1, s.2))
        .unzip();
    let t2 = rigid_fit(&a, &b).unwrap_or(t);
    let inl2 = inliers_of(&t2);
    if inl2.len() >= inl.len() {
        Some((t2, inl2))
    } else {
        Some((t, inl))
    }
}

fn drop_outliers(frame: &mut Frame) {
    for i in 0..frame.len() {
        if frame.outlier[i] {
            frame.map_points[i] = None;
            frame.outlier[i] = false;
        }
    }
}

/// Tries to relocalise `frame`; on success its pose and matches are set.
pub(super) fn relocalize(tracker: &mut Tracker, map: &mut Map, frame: &mut Frame) -> bool {
    let p = tracker.params.reloc.clone();
    let cands = candidates(map, frame, &p);
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed ^ frame.id.wrapping_mul(0x9e37_79b9_7f4a_7c15));
    for kf_id in cands {
        let Some(kf) = map.keyframe(kf_id) else {
            continue;
        };
        let (matches, n) = matcher::search_keyframe_to_frame(
            kf,
            frame,
            map,
            p.ratio,
            true,
            &tracker.params.matcher,
        );
        if n < p.min_matches {
            continue;
        }
        let pairs: Vec<(usize, Vector3<f64>)> = matches
            .iter()
            .enumerate()
            .filter_map(|(i, m)| Some((i, map.point((*m)?)?.position)))
            .collect();
        let Some((pose, inliers)) = ransac_pose(tracker, map, frame, &pairs, &mut rng) else {
            continue;
        };
        frame.pose = Some(pose);
        frame.map_points.iter_mut().for_each(|m| *m = None);
        for &i in &inliers {
            frame.map_points[i] = matches[i];
        }
        let mut good = tracker.optimize_pose(map, frame);
        if good < 10 {
            continue;
        }
        drop_outliers(frame);
        if good < 50 {
            let found: HashSet<MapPointId> = frame.map_points.iter().flatten().copied().collect();
            let Some(kf) = map.keyframe(kf_id) else {
                continue;
            };
            let add = matcher::search_keyframe_by_projection(
                frame,
                kf,
                map,
                &tracker.cam,
                &found,
                10.0,
                100,
                &tracker.params.matcher,
            );
            if add + good >= 50 {
                good = tracker.optimize_pose(map, frame);
                if good > 30 && good < 50 {
                    let found: HashSet<MapPointId> = frame
                        .map_points
                        .iter()
                        .zip(&frame.outlier)
                        .filter(|(_, o)| !**o)
                        .filter_map(|(m, _)| *m)
                        .collect();
                    let add = matcher::search_keyframe_by_projection(
                        frame,
                        kf,
                        map,
                        &tracker.cam,
                        &found,
                        3.0,
                        64,
                        &tracker.params.matcher,
                    );
                    if good + add >= 50 {
                        good = tracker.optimize_pose(map, frame);
                    }
                }
                drop_outliers(frame);
            }
        }
        if good >= 50 {
            tracker.reference_kf = Some(kf_id);
            return true;
        }
    }
    frame.pose = None;
    frame.map_points.iter_mut().for_each(|m| *m = None);
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rigid_fit_recovers_a_transform() {
        let t = Se3::from_parts(
            Translation3::new(0.3, -0.1, 0.5),
            UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
        );
        let a: Vec<Vector3<f64>> = (0..6)
            .map(|i| Vector3::new(i as f64, (i * i) as f64 * 0.1, 1.0 + (i % 3) as f64))
            .collect();
        let b: Vec<Vector3<f64>> = a.iter().map(|x| transform(&t, x)).collect();
        let r = rigid_fit(&a, &b).unwrap();
        assert!((r.translation.vector - t.translation.vector).norm() < 1e-9);
        assert!(r.rotation.angle_to(&t.rotation) < 1e-9);
    }

    #[test]
    fn bow_score_is_one_for_identical_vectors() {
        let a = vec![(1, 0.5), (4, 0.25), (9, 0.25)];
        assert!((bow_score(&a, &a) - 1.0).abs() < 1e-12);
        let b = vec![(2, 1.0)];
        assert!(bow_score(&a, &b).abs() < 1e-12);
    }
}
