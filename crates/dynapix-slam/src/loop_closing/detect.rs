//! Loop detection (ORB-SLAM2 `LoopClosing::DetectLoop` + `ComputeSim3`, spec §6.6) for RGB-D,
//! where the scale is observable and the relative transform is an SE3.
//!
//! Per new keyframe: skip while fewer than 10 keyframes followed the last loop; otherwise the
//! lowest bag-of-words score to a covisible keyframe is the bar loop candidates must clear in
//! the keyframe database (`database`), candidates must be covisibility-consistent over
//! consecutive keyframes, and each consistent candidate is verified geometrically:
//! bag-of-words matching of map points (ratio 0.75, ≥ 20), a seeded 3-point RANSAC with Horn
//! alignment (`solver`), two-way guided matching through the estimate (radius 7.5), a
//! refinement of the relative transform over both reprojection directions (χ² 10,
//! `refine`) with ≥ 20 inliers, then the map points of the loop keyframe and its covisibles
//! are projected with the corrected pose (radius 10) and the loop is accepted with ≥ 40
//! matches in total.
//!
//! Deterministic: candidates are visited in keyframe-id order and the RANSAC of each call is
//! seeded from [`DetectionParams::seed`] and the keyframe sequence number.

mod database;
mod refine;
mod search;
mod solver;

#[cfg(test)]
mod tests;

use std::collections::BTreeSet;

use dynapix_geometry::Se3;
use nalgebra::{Vector2, Vector3};

use crate::camera::RgbdCamera;

use crate::ids::{KeyFrameId, MapPointId};
use crate::map::Map;
use crate::matcher::MatcherParams;
use crate::pose::transform;
use crate::vocab::Vocabulary;

use super::LoopMatch;
use database::{CandidateSettings, ConsistentGroups, KeyFrameDatabase, bow_score};
use refine::{RefinePair, RefineSettings, refine_relative};
use solver::{PointPair, RansacSettings, RansacStep, Se3Ransac};

/// Parameters of loop detection; `Default` gives the ORB-SLAM2 values (spec §6.6).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct DetectionParams {
    /// Keyframes (by sequence number) that must follow the last loop, or the map origin,
    /// before detection runs (10).
    pub min_keyframes_since_loop: u64,
    /// A candidate needs more than this fraction of the best common-word count (0.8).
    pub common_words_ratio: f32,
    /// A candidate group is kept when its accumulated score exceeds this fraction of the
    /// best accumulated score (0.75).
    pub accumulated_score_ratio: f64,
    /// Best covisible keyframes over which candidate scores are accumulated (10).
    pub accumulation_covisibles: usize,
    /// A candidate is verified once its covisibility group (candidate + connected keyframes)
    /// was found, overlapping from one keyframe to the next, in this many consecutive
    /// keyframes (3, spec §6.6 "consistent over 3 consecutive KFs"). ORB-SLAM2's code counts
    /// continuations of a group (`mnCovisibilityConsistencyTh = 3` is met at the 4th
    /// keyframe); set 4 to reproduce that.
    pub consistency_threshold: usize,
    /// Ratio test of the bag-of-words keyframe matching (0.75).
    pub bow_ratio: f32,
    /// Minimum bag-of-words matches to try a candidate (20).
    pub min_bow_matches: usize,
    /// RANSAC success probability (0.99).
    pub ransac_probability: f64,
    /// RANSAC minimum inliers (20): a hypothesis with more is verified.
    pub ransac_min_inliers: usize,
    /// RANSAC maximum iterations per candidate (300).
    pub ransac_max_iterations: usize,
    /// RANSAC iterations per candidate per turn; candidates take turns (5).
    pub ransac_iterations_per_turn: usize,
    /// χ² (2 dof, 99 %) times σ² bounding the squared pixel error of a RANSAC inlier in both
    /// images (9.21, `Sim3Solver`).
    pub ransac_chi2: f64,
    /// Search radius (× level scale) of the two-way guided matching (7.5).
    pub se3_search_radius: f32,
    /// χ² threshold of the relative-transform refinement (10).
    pub refine_chi2: f64,
    /// χ² threshold of a refinement direction whose keypoint has depth (u, v, uR).
    pub refine_chi2_depth: f64,
    /// Use the keypoints' depth (virtual right coordinate) in the refinement.
    pub refine_with_depth: bool,
    /// Refinement iterations before dropping outliers (5).
    pub refine_first_iterations: usize,
    /// Refinement iterations after dropping outliers (10) …
    pub refine_iterations_after_drop: usize,
    /// … or when none was dropped (5).
    pub refine_iterations: usize,
    /// Pairs that must survive the first refinement round (10).
    pub refine_min_pairs: usize,
    /// Minimum inliers of the refined transform (20).
    pub min_refined_inliers: usize,
    /// Search radius (× level scale) of the loop-point projection (10).
    pub projection_radius: f32,
    /// Minimum matched loop points of the current keyframe to accept the loop (40).
    pub min_total_matches: usize,
    /// Seed of the RANSAC sampler (combined with the keyframe sequence number).
    pub seed: u64,
    /// Descriptor thresholds and the rotation histogram.
    pub matcher: MatcherParams,
}

impl Default for DetectionParams {
    fn default() -> Self {
        Self {
            min_keyframes_since_loop: 10,
            common_words_ratio: 0.8,
            accumulated_score_ratio: 0.75,
            accumulation_covisibles: 10,
            consistency_threshold: 3,
            bow_ratio: 0.75,
            min_bow_matches: 20,
            ransac_probability: 0.99,
            ransac_min_inliers: 20,
            ransac_max_iterations: 300,
            ransac_iterations_per_turn: 5,
            ransac_chi2: 9.21,
            se3_search_radius: 7.5,
            refine_chi2: 10.0,
            refine_chi2_depth: 12.8,
            refine_with_depth: true,
            refine_first_iterations: 5,
            refine_iterations_after_drop: 10,
            refine_iterations: 5,
            refine_min_pairs: 10,
            min_refined_inliers: 20,
            projection_radius: 10.0,
            min_total_matches: 40,
            seed: 0x100b_c105,
            matcher: MatcherParams::default(),
        }
    }
}

/// Where the last [`LoopDetector::detect`] call stopped.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DetectionOutcome {
    /// Not run yet.
    #[default]
    NotRun,
    /// No vocabulary, or the keyframe has no bag-of-words vector.
    NoVocabulary,
    /// The keyframe id is stale.
    UnknownKeyFrame,
    /// Too few keyframes since the last loop (or the map origin).
    TooSoon,
    /// The database returned no candidate.
    NoCandidates,
    /// Candidates, but none consistent over enough consecutive keyframes.
    NotConsistent,
    /// Every consistent candidate failed the geometric verification (BoW matches, RANSAC or
    /// refinement).
    GeometryRejected,
    /// A transform was found but too few loop points matched in total.
    TooFewTotalMatches,
    /// A loop was accepted.
    Accepted,
}

/// Figures of one consistent candidate's verification.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CandidateTrial {
    /// The candidate keyframe.
    pub keyframe: Option<KeyFrameId>,
    /// Its sequence number.
    pub seq: u64,
    /// Bag-of-words matches.
    pub bow_matches: usize,
    /// Inliers of the last RANSAC hypothesis that was verified (0 when none).
    pub ransac_inliers: usize,
    /// Matches after the two-way guided search of that hypothesis.
    pub guided_matches: usize,
    /// Inliers after the refinement (0 when it failed).
    pub refined_inliers: usize,
    /// RANSAC hypotheses that were verified.
    pub hypotheses: usize,
}

/// What the last [`LoopDetector::detect`] call saw (for logs and tests).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DetectionDiagnostics {
    /// The keyframe examined.
    pub keyframe: Option<KeyFrameId>,
    /// Its sequence number.
    pub seq: u64,
    /// Lowest bag-of-words score to a covisible keyframe (the candidates' bar).
    pub min_score: f64,
    /// Candidates returned by the database.
    pub candidates: Vec<KeyFrameId>,
    /// Their sequence numbers.
    pub candidate_seqs: Vec<u64>,
    /// Consistent groups carried to the next keyframe.
    pub consistent_groups: usize,
    /// Candidates consistent over enough consecutive keyframes.
    pub consistent_candidates: Vec<KeyFrameId>,
    /// Verification figures per consistent candidate.
    pub trials: Vec<CandidateTrial>,
    /// Matched loop points after the final projection (accepted or not).
    pub total_matches: usize,
    /// Where the call stopped.
    pub outcome: DetectionOutcome,
}

/// The loop detector: keyframe database, consistent groups and the gap since the last loop.
#[derive(Clone, Debug)]
pub struct LoopDetector {
    cam: RgbdCamera,
    params: DetectionParams,
    database: KeyFrameDatabase,
    groups: ConsistentGroups<KeyFrameId>,
    /// Sequence number of the last loop keyframe (None: count from the map origin).
    last_loop_seq: Option<u64>,
    diagnostics: DetectionDiagnostics,
}

/// A consistent candidate with its bag-of-words matches and RANSAC solver.
struct Trial {
    id: KeyFrameId,
    matches: Vec<Option<MapPointId>>,
    /// Keypoint of the current keyframe of each solver pair.
    pair_index: Vec<usize>,
    solver: Se3Ransac,
    diag: usize,
}

impl LoopDetector {
    /// A detector for keyframes of camera `cam`.
    pub fn new(cam: RgbdCamera, params: DetectionParams) -> Self {
        Self {
            cam,
            params,
            database: KeyFrameDatabase::default(),
            groups: ConsistentGroups::default(),
            last_loop_seq: None,
            diagnostics: DetectionDiagnostics::default(),
        }
    }

    /// The parameters.
    pub fn params(&self) -> &DetectionParams {
        &self.params
    }

    /// Forgets every keyframe and group (map reset).
    pub fn reset(&mut self) {
        self.database.clear();
        self.groups.clear();
        self.last_loop_seq = None;
        self.diagnostics = DetectionDiagnostics::default();
    }

    /// What the last [`LoopDetector::detect`] call saw.
    pub fn last_diagnostics(&self) -> &DetectionDiagnostics {
        &self.diagnostics
    }

    /// Tells the detector a loop was closed at `kf`: the next 10 keyframes (by sequence
    /// number) are not examined, and the consistency groups start afresh.
    pub fn loop_closed(&mut self, map: &Map, kf: KeyFrameId) {
        if let Some(k) = map.keyframe(kf) {
            self.last_loop_seq = Some(k.seq);
        }
        self.groups.clear();
    }

    /// Adds `kf` to the database and runs detection + SE3 estimation; Some on an accepted loop.
    pub fn detect(
        &mut self,
        map: &Map,
        kf: KeyFrameId,
        vocab: Option<&Vocabulary>,
    ) -> Option<LoopMatch> {
        self.diagnostics = DetectionDiagnostics {
            keyframe: Some(kf),
            ..DetectionDiagnostics::default()
        };
        let Some(k) = map.keyframe(kf) else {
            self.diagnostics.outcome = DetectionOutcome::UnknownKeyFrame;
            return None;
        };
        self.diagnostics.seq = k.seq;
        if vocab.is_none() || k.bow.is_empty() {
            self.diagnostics.outcome = DetectionOutcome::NoVocabulary;
            return None;
        }
        let base = self
            .last_loop_seq
            .or_else(|| map.origin.and_then(|o| map.keyframe(o)).map(|o| o.seq))
            .unwrap_or(0);
        if k.seq < base + self.params.min_keyframes_since_loop {
            self.database.add(kf, k);
            self.diagnostics.outcome = DetectionOutcome::TooSoon;
            return None;
        }
        // The candidates must look more like the keyframe than its least similar neighbour.
        let mut min_score = 1.0f64;
        for &(n, _) in &k.ordered {
            if let Some(nk) = map.keyframe(n) {
                min_score = min_score.min(bow_score(&k.bow, &nk.bow));
            }
        }
        self.diagnostics.min_score = min_score;
        let settings = CandidateSettings {
            common_words_ratio: self.params.common_words_ratio,
            accumulated_score_ratio: self.params.accumulated_score_ratio,
            covisibles: self.params.accumulation_covisibles,
        };
        let candidates = self
            .database
            .loop_candidates(map, kf, k, min_score, &settings);
        self.diagnostics.candidates = candidates.clone();
        self.diagnostics.candidate_seqs = candidates
            .iter()
            .filter_map(|&c| map.keyframe(c).map(|k| k.seq))
            .collect();
        if candidates.is_empty() {
            self.database.add(kf, k);
            self.groups.clear();
            self.diagnostics.outcome = DetectionOutcome::NoCandidates;
            return None;
        }
        let with_groups: Vec<(KeyFrameId, BTreeSet<KeyFrameId>)> = candidates
            .iter()
            .filter_map(|&c| {
                let ck = map.keyframe(c)?;
                let mut g: BTreeSet<KeyFrameId> = ck.connections.keys().copied().collect();
                g.insert(c);
                Some((c, g))
            })
            .collect();
        let consistent = self
            .groups
            .update(&with_groups, self.params.consistency_threshold);
        self.diagnostics.consistent_groups = self.groups.len();
        self.diagnostics.consistent_candidates = consistent.clone();
        self.database.add(kf, k);
        if consistent.is_empty() {
            self.diagnostics.outcome = DetectionOutcome::NotConsistent;
            return None;
        }
        let found = self.compute_se3(map, kf, &consistent);
        self.diagnostics.outcome = match &found {
            Some(_) => DetectionOutcome::Accepted,
            None if self.diagnostics.total_matches > 0 => DetectionOutcome::TooFewTotalMatches,
            None => DetectionOutcome::GeometryRejected,
        };
        found
    }

    /// Geometric verification of the consistent candidates (ORB-SLAM2 `ComputeSim3`).
    fn compute_se3(
        &mut self,
        map: &Map,
        cur_id: KeyFrameId,
        consistent: &[KeyFrameId],
    ) -> Option<LoopMatch> {
        let p = self.params.clone();
        let cur = map.keyframe(cur_id)?;
        let pyr = &map.pyramid;
        let seed = p.seed ^ cur.seq.wrapping_mul(0x9e37_79b9_7f4a_7c15);
        let ransac = RansacSettings {
            probability: p.ransac_probability,
            min_inliers: p.ransac_min_inliers,
            max_iterations: p.ransac_max_iterations,
        };
        let mut trials: Vec<Trial> = Vec::new();
        for (ci, &cand) in consistent.iter().enumerate() {
            let Some(ck) = map.keyframe(cand) else {
                continue;
            };
            let (matches, n) = search::search_by_bow(map, cur, ck, p.bow_ratio, &p.matcher);
            self.diagnostics.trials.push(CandidateTrial {
                keyframe: Some(cand),
                seq: ck.seq,
                bow_matches: n,
                ..CandidateTrial::default()
            });
            if n < p.min_bow_matches {
                continue;
            }
            let mut pairs = Vec::new();
            let mut pair_index = Vec::new();
            for m in matched_pairs(map, cur, cand, ck, &matches) {
                pairs.push(PointPair {
                    p1: m.p1,
                    p2: m.p2,
                    max_err1: p.ransac_chi2 * pyr.sigma2_of(m.kp1.octave as usize) as f64,
                    max_err2: p.ransac_chi2 * pyr.sigma2_of(m.kp2.octave as usize) as f64,
                });
                pair_index.push(m.i1);
            }
            let solver = Se3Ransac::new(
                pairs,
                &self.cam.pinhole,
                &ransac,
                seed ^ (ci as u64).wrapping_mul(0xbf58_476d_1ce4_e5b9),
            );
            trials.push(Trial {
                id: cand,
                matches,
                pair_index,
                solver,
                diag: self.diagnostics.trials.len() - 1,
            });
        }
        let refine = RefineSettings {
            chi2: p.refine_chi2,
            chi2_depth: p.refine_chi2_depth,
            first_iterations: p.refine_first_iterations,
            second_iterations_after_drop: p.refine_iterations_after_drop,
            second_iterations: p.refine_iterations,
            min_pairs: p.refine_min_pairs,
        };
        let mut active = vec![true; trials.len()];
        let mut found: Option<(KeyFrameId, Se3, Vec<Option<MapPointId>>)> = None;
        while found.is_none() && active.iter().any(|&a| a) {
            for (t, alive) in trials.iter_mut().zip(active.iter_mut()) {
                if !*alive {
                    continue;
                }
                let step = t.solver.iterate(p.ransac_iterations_per_turn);
                let (t12, inliers) = match step {
                    RansacStep::Exhausted => {
                        *alive = false;
                        continue;
                    }
                    RansacStep::Continue => continue,
                    RansacStep::Found(t12, inl) => (t12, inl),
                };
                let Some(ck) = map.keyframe(t.id) else {
                    *alive = false;
                    continue;
                };
                let mut matches: Vec<Option<MapPointId>> = vec![None; cur.keys_un.len()];
                for (j, &ok) in inliers.iter().enumerate() {
                    if ok
                        && let Some(&i1) = t.pair_index.get(j)
                        && let (Some(slot), Some(&m)) = (matches.get_mut(i1), t.matches.get(i1))
                    {
                        *slot = m;
                    }
                }
                let ransac_inliers = inliers.iter().filter(|&&b| b).count();
                search::search_by_se3(
                    map,
                    &self.cam,
                    cur,
                    (t.id, ck),
                    &mut matches,
                    &t12,
                    p.se3_search_radius,
                    &p.matcher,
                );
                let guided = matches.iter().flatten().count();
                let (pairs, idx) = refine_pairs(map, cur_id, t.id, &matches, p.refine_with_depth);
                let refined = refine_relative(&self.cam, &t12, &pairs, &refine);
                let mut n_in = 0;
                let mut t12r = t12;
                if let Some((tr, inl)) = refined {
                    t12r = tr;
                    let mut kept: Vec<Option<MapPointId>> = vec![None; matches.len()];
                    for (j, ok) in inl.iter().enumerate() {
                        if *ok
                            && let Some(&i1) = idx.get(j)
                            && let (Some(slot), Some(&m)) = (kept.get_mut(i1), matches.get(i1))
                        {
                            *slot = m;
                            n_in += 1;
                        }
                    }
                    matches = kept;
                }
                if let Some(d) = self.diagnostics.trials.get_mut(t.diag) {
                    d.ransac_inliers = ransac_inliers;
                    d.guided_matches = guided;
                    d.refined_inliers = n_in;
                    d.hypotheses += 1;
                }
                tracing::debug!(
                    current = cur.seq,
                    candidate = ck.seq,
                    ransac_inliers,
                    guided,
                    refined = n_in,
                    "loop hypothesis"
                );
                if n_in >= p.min_refined_inliers {
                    found = Some((t.id, t12r, matches));
                    break;
                }
            }
        }
        let (loop_id, t12, mut matched) = found?;
        let loop_kf = map.keyframe(loop_id)?;
        let corrected = crate::pose::normalized(&(t12 * loop_kf.pose));
        let loop_points = loop_points(map, loop_id);
        search::search_by_projection(
            map,
            &self.cam,
            cur,
            &corrected,
            &loop_points,
            &mut matched,
            p.projection_radius,
            &p.matcher,
        );
        let total = matched.iter().flatten().count();
        self.diagnostics.total_matches = total;
        tracing::debug!(
            current = cur.seq,
            loop_kf = loop_kf.seq,
            total,
            "loop projection matches"
        );
        if total < p.min_total_matches {
            return None;
        }
        Some(LoopMatch {
            current: cur_id,
            loop_kf: loop_id,
            corrected_pose: corrected,
            matched_points: matched,
            loop_points,
        })
    }
}

/// Refinement pairs for the matches of the current keyframe (keypoint i1 with its own map
/// point, matched to a loop-side point observed by `loop_id`), with the keypoint of each.
fn refine_pairs(
    map: &Map,
    cur_id: KeyFrameId,
    loop_id: KeyFrameId,
    matches: &[Option<MapPointId>],
    with_depth: bool,
) -> (Vec<RefinePair>, Vec<usize>) {
    let (Some(cur), Some(lk)) = (map.keyframe(cur_id), map.keyframe(loop_id)) else {
        return (Vec::new(), Vec::new());
    };
    let pyr = &map.pyramid;
    let mut pairs = Vec::new();
    let mut idx = Vec::new();
    for m in matched_pairs(map, cur, loop_id, lk, matches) {
        let (k1, k2) = (m.kp1, m.kp2);
        pairs.push(RefinePair {
            p1: m.p1,
            p2: m.p2,
            kp1: Vector2::new(k1.x as f64, k1.y as f64),
            kp2: Vector2::new(k2.x as f64, k2.y as f64),
            ur1: right(cur, m.i1, with_depth),
            ur2: right(lk, m.i2, with_depth),
            inv_sigma2_1: pyr.inv_sigma2_of(k1.octave as usize) as f64,
            inv_sigma2_2: pyr.inv_sigma2_of(k2.octave as usize) as f64,
        });
        idx.push(m.i1);
    }
    (pairs, idx)
}

/// A keypoint `i1` of the current keyframe with its own map point, matched to a point of the
/// other keyframe observed there at keypoint `i2`; both points in their camera's coordinates.
struct MatchedPair<'a> {
    i1: usize,
    i2: usize,
    p1: Vector3<f64>,
    p2: Vector3<f64>,
    kp1: &'a crate::features::KeyPoint,
    kp2: &'a crate::features::KeyPoint,
}

/// The usable pairs of `matches` (per keypoint of `cur`: a map point of `other_id`'s
/// neighbourhood), skipping keypoints without a map point and points `other_id` does not see.
fn matched_pairs<'a>(
    map: &'a Map,
    cur: &'a crate::map::KeyFrame,
    other_id: KeyFrameId,
    other: &'a crate::map::KeyFrame,
    matches: &'a [Option<MapPointId>],
) -> impl Iterator<Item = MatchedPair<'a>> + 'a {
    matches.iter().enumerate().filter_map(move |(i1, m)| {
        let pt1 = cur
            .map_points
            .get(i1)
            .copied()
            .flatten()
            .and_then(|id| map.point(id))?;
        let pt2 = map.point((*m)?)?;
        let &i2 = pt2.observations.get(&other_id)?;
        Some(MatchedPair {
            i1,
            i2,
            p1: transform(&cur.pose, &pt1.position),
            p2: transform(&other.pose, &pt2.position),
            kp1: cur.keys_un.get(i1)?,
            kp2: other.keys_un.get(i2)?,
        })
    })
}

/// Virtual right coordinate of keypoint `i` when it has depth and depth is used.
fn right(kf: &crate::map::KeyFrame, i: usize, with_depth: bool) -> Option<f64> {
    let ur = *kf.u_right.get(i)?;
    (with_depth && ur >= 0.0).then_some(ur as f64)
}

/// Map points of `loop_id` and its covisible keyframes (covisibles by decreasing weight,
/// then the loop keyframe, each in keypoint order), de-duplicated.
fn loop_points(map: &Map, loop_id: KeyFrameId) -> Vec<MapPointId> {
    let Some(lk) = map.keyframe(loop_id) else {
        return Vec::new();
    };
    let mut kfs: Vec<KeyFrameId> = lk.ordered.iter().map(|&(k, _)| k).collect();
    kfs.push(loop_id);
    let mut seen = std::collections::HashSet::new();
    let mut out = Vec::new();
    for k in kfs {
        let Some(kk) = map.keyframe(k) else { continue };
        for mp in kk.map_points.iter().flatten() {
            if map.point(*mp).is_some() && seen.insert(*mp) {
                out.push(*mp);
            }
        }
    }
    out
}
