//! Relocalisation (ORB-SLAM2 `Tracking::Relocalization`, spec §6.8): candidate keyframes
//! (bag-of-words when a vocabulary is loaded, else the most recent keyframes), keyframe →
//! frame matching (ratio 0.75), a seeded RANSAC pose hypothesis, pose optimisation and the
//! two extra projection searches before accepting with ≥ 50 inliers.
//!
//! Pose hypotheses come from the seeded EPnP RANSAC of `dynapix_geometry::pnp` (seed from
//! the frame and candidate, so runs are reproducible).

use std::collections::{BTreeMap, HashSet};

use dynapix_geometry::Se3;
use dynapix_geometry::pnp::{PnpRansac, PnpRansacParams};
use nalgebra::{Vector2, Vector3};

use super::Tracker;
use crate::frame::Frame;
use crate::ids::{KeyFrameId, MapPointId};
use crate::map::Map;
use crate::matcher;

/// Relocalisation parameters (ORB-SLAM2 defaults).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
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

/// Seeded EPnP RANSAC on the matches `(keypoint index, world point)`; returns `T_cw` and
/// the inlier keypoint indices.
fn pnp_pose(
    tracker: &Tracker,
    map: &Map,
    frame: &Frame,
    matches: &[(usize, Vector3<f64>)],
    seed: u64,
) -> Option<(Se3, Vec<usize>)> {
    let p = &tracker.params.reloc;
    let points: Vec<Vector3<f64>> = matches.iter().map(|m| m.1).collect();
    let pixels: Vec<Vector2<f64>> = matches
        .iter()
        .map(|&(i, _)| {
            let k = &frame.keys_un[i];
            Vector2::new(k.x as f64, k.y as f64)
        })
        .collect();
    let sigma2: Vec<f64> = matches
        .iter()
        .map(|&(i, _)| map.pyramid.sigma2_of(frame.keys_un[i].octave as usize) as f64)
        .collect();
    let params = PnpRansacParams {
        probability: p.probability,
        min_inliers: p.min_inliers,
        max_iterations: p.max_iterations,
        th2: p.chi2,
        seed,
        ..PnpRansacParams::default()
    };
    let mut ransac =
        PnpRansac::new(&points, &pixels, &sigma2, &tracker.cam.pinhole, &params).ok()?;
    let (pose, inl) = ransac.solve()?;
    let idx = matches
        .iter()
        .zip(&inl)
        .filter(|(_, ok)| **ok)
        .map(|(m, _)| m.0)
        .collect();
    Some((pose, idx))
}

fn kf_id_seed(map: &Map, kf: KeyFrameId) -> u64 {
    map.keyframe(kf)
        .map_or(0, |k| k.seq.wrapping_mul(0xbf58_476d_1ce4_e5b9))
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
        let seed = p.seed ^ frame.id.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ kf_id_seed(map, kf_id);
        let Some((pose, inliers)) = pnp_pose(tracker, map, frame, &pairs, seed) else {
            continue;
        };
        frame.pose = Some(crate::pose::normalized(&pose));
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
    fn bow_score_is_one_for_identical_vectors() {
        let a = vec![(1, 0.5), (4, 0.25), (9, 0.25)];
        assert!((bow_score(&a, &a) - 1.0).abs() < 1e-12);
        let b = vec![(2, 1.0)];
        assert!(bow_score(&a, &b).abs() < 1e-12);
    }
}
