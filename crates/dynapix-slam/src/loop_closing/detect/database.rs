//! The keyframe database and the covisibility-consistency filter of loop detection
//! (ORB-SLAM2 `KeyFrameDatabase::DetectLoopCandidates` and the consistent groups of
//! `LoopClosing::DetectLoop`, spec §6.6).
//!
//! The database is an inverted index word → keyframes. Culled keyframes are not removed
//! eagerly (the map does not notify the detector); their ids go stale in the map and are
//! pruned from the index the next time a query visits their words.

use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};

use crate::map::{KeyFrame, Map};

use crate::ids::KeyFrameId;

/// Inverted index of keyframe words.
#[derive(Clone, Debug, Default)]
pub(crate) struct KeyFrameDatabase {
    index: HashMap<u32, Vec<KeyFrameId>>,
}

/// Candidate-selection thresholds (ORB-SLAM2: 0.8, 0.75, 10).
#[derive(Clone, Copy, Debug)]
pub(crate) struct CandidateSettings {
    /// A candidate needs more than this fraction of the best common-word count.
    pub common_words_ratio: f32,
    /// A group is kept when its accumulated score exceeds this fraction of the best.
    pub accumulated_score_ratio: f64,
    /// Covisible keyframes whose scores are accumulated.
    pub covisibles: usize,
}

/// L1 score of two L1-normalised bag-of-words vectors sorted by word (DBoW2 `L1Scoring`).
pub(crate) fn bow_score(a: &[(u32, f64)], b: &[(u32, f64)]) -> f64 {
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
    (-s / 2.0).clamp(0.0, 1.0)
}

impl KeyFrameDatabase {
    /// Empties the index (map reset).
    pub fn clear(&mut self) {
        self.index.clear();
    }

    /// Indexes `id` under its words (once per keyframe).
    pub fn add(&mut self, id: KeyFrameId, kf: &KeyFrame) {
        for &(w, _) in &kf.bow {
            let list = self.index.entry(w).or_default();
            if list.last() != Some(&id) {
                list.push(id);
            }
        }
    }

    /// Number of index entries, stale ones included (for tests).
    #[cfg(test)]
    pub fn entries(&self) -> usize {
        self.index.values().map(Vec::len).sum()
    }

    /// Loop candidates of keyframe `id`: keyframes not connected to it that share enough
    /// words, score at least `min_score`, and whose covisibility group accumulates a high
    /// enough score; each group is represented by its best-scoring member. Deterministic
    /// order (by keyframe id).
    pub fn loop_candidates(
        &mut self,
        map: &Map,
        id: KeyFrameId,
        kf: &KeyFrame,
        min_score: f64,
        s: &CandidateSettings,
    ) -> Vec<KeyFrameId> {
        let connected: HashSet<KeyFrameId> = kf.connections.keys().copied().collect();
        let mut common: BTreeMap<KeyFrameId, usize> = BTreeMap::new();
        for &(w, _) in &kf.bow {
            let Some(list) = self.index.get_mut(&w) else {
                continue;
            };
            list.retain(|k| map.keyframe(*k).is_some());
            for &k in list.iter() {
                if k != id && !connected.contains(&k) {
                    *common.entry(k).or_insert(0) += 1;
                }
            }
        }
        let Some(&max_common) = common.values().max() else {
            return Vec::new();
        };
        let min_common = (max_common as f32 * s.common_words_ratio) as usize;
        // Scores of every keyframe with enough common words (used for accumulation), and
        // the ones above `min_score` (the candidates proper).
        let mut scores: BTreeMap<KeyFrameId, f64> = BTreeMap::new();
        let mut passing: Vec<(KeyFrameId, f64)> = Vec::new();
        for (&k, &c) in &common {
            if c <= min_common {
                continue;
            }
            let Some(other) = map.keyframe(k) else {
                continue;
            };
            let sc = bow_score(&kf.bow, &other.bow);
            scores.insert(k, sc);
            if sc >= min_score {
                passing.push((k, sc));
            }
        }
        let mut accumulated: Vec<(f64, KeyFrameId)> = Vec::new();
        let mut best_acc = 0.0f64;
        for &(k, sc) in &passing {
            let Some(other) = map.keyframe(k) else {
                continue;
            };
            let (mut acc, mut best, mut best_id) = (sc, sc, k);
            for n in other.best_covisibles(s.covisibles) {
                if let Some(&sn) = scores.get(&n) {
                    acc += sn;
                    if sn > best {
                        best = sn;
                        best_id = n;
                    }
                }
            }
            best_acc = best_acc.max(acc);
            accumulated.push((acc, best_id));
        }
        let keep = s.accumulated_score_ratio * best_acc;
        let mut seen = BTreeSet::new();
        accumulated
            .into_iter()
            .filter(|&(acc, k)| acc > keep && seen.insert(k))
            .map(|(_, k)| k)
            .collect()
    }
}

/// Covisibility groups of the previous keyframes' candidates with their consistency count.
#[derive(Clone, Debug)]
pub(crate) struct ConsistentGroups<T> {
    groups: Vec<(BTreeSet<T>, usize)>,
}

impl<T> Default for ConsistentGroups<T> {
    fn default() -> Self {
        Self { groups: Vec::new() }
    }
}

impl<T: Ord + Copy> ConsistentGroups<T> {
    /// Forgets every group (no candidates for a keyframe, or a map reset).
    pub fn clear(&mut self) {
        self.groups.clear();
    }

    /// Number of groups carried to the next keyframe.
    pub fn len(&self) -> usize {
        self.groups.len()
    }

    /// Feeds the candidates of one keyframe, each with its covisibility group (the candidate
    /// and its connected keyframes). A group sharing a keyframe with a previous group
    /// continues it with count + 1 (each previous group is continued once), others start a
    /// count of one. Returns the candidates whose count reached `threshold`, i.e. whose
    /// groups were found in `threshold` consecutive keyframes (this one included).
    pub fn update(&mut self, candidates: &[(T, BTreeSet<T>)], threshold: usize) -> Vec<T> {
        let mut next: Vec<(BTreeSet<T>, usize)> = Vec::new();
        let mut continued = vec![false; self.groups.len()];
        let mut enough = Vec::new();
        for (cand, group) in candidates {
            let mut accepted = false;
            let mut consistent_somewhere = false;
            for (g, (prev, count)) in self.groups.iter().enumerate() {
                if !group.iter().any(|k| prev.contains(k)) {
                    continue;
                }
                consistent_somewhere = true;
                let c = count + 1;
                if !continued[g] {
                    next.push((group.clone(), c));
                    continued[g] = true;
                }
                if c >= threshold && !accepted {
                    enough.push(*cand);
                    accepted = true;
                }
            }
            if !consistent_somewhere {
                next.push((group.clone(), 1));
                if threshold <= 1 {
                    enough.push(*cand);
                }
            }
        }
        self.groups = next;
        enough
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn group(ids: &[u32]) -> BTreeSet<u32> {
        ids.iter().copied().collect()
    }

    #[test]
    fn a_candidate_seen_in_three_consecutive_keyframes_is_accepted() {
        let mut g = ConsistentGroups::default();
        let th = 3;
        // Keyframe 1: candidate 10 (group 9,10,11) starts a group.
        assert!(g.update(&[(10, group(&[9, 10, 11]))], th).is_empty());
        // Keyframe 2: a group overlapping the previous one: seen twice, not enough.
        assert!(g.update(&[(11, group(&[10, 11, 12]))], th).is_empty());
        // Keyframe 3: seen in 3 consecutive keyframes.
        assert_eq!(g.update(&[(12, group(&[11, 12, 13]))], th), vec![12]);
        // And it stays accepted while the chain goes on.
        assert_eq!(g.update(&[(12, group(&[12, 13]))], th), vec![12]);
    }

    #[test]
    fn an_interrupted_or_inconsistent_sequence_is_not_accepted() {
        let th = 3;
        let mut g = ConsistentGroups::default();
        assert!(g.update(&[(10, group(&[10, 11]))], th).is_empty());
        assert!(g.update(&[(11, group(&[10, 11]))], th).is_empty());
        // A keyframe without candidates breaks the chain: twice more is not enough…
        g.clear();
        assert!(g.update(&[(11, group(&[10, 11]))], th).is_empty());
        assert!(g.update(&[(11, group(&[10, 11]))], th).is_empty());
        // … the third consecutive sighting is.
        assert_eq!(g.update(&[(11, group(&[10, 11]))], th), vec![11]);
        // A group disjoint from every previous one starts over and is not accepted, even
        // when another candidate of the same keyframe is.
        let mut g = ConsistentGroups::default();
        for _ in 0..2 {
            assert!(g.update(&[(1, group(&[1, 2]))], th).is_empty());
        }
        let acc = g.update(&[(1, group(&[1, 2])), (50, group(&[50, 51]))], th);
        assert_eq!(acc, vec![1]);
        assert_eq!(g.len(), 2);
        // Jumping between disjoint places never accumulates.
        let mut g = ConsistentGroups::default();
        for k in 0..6u32 {
            assert!(
                g.update(&[(k * 10, group(&[k * 10, k * 10 + 1]))], th)
                    .is_empty()
            );
        }
    }

    #[test]
    fn bow_score_is_one_for_identical_and_zero_for_disjoint_vectors() {
        let a = vec![(1, 0.5), (4, 0.25), (9, 0.25)];
        assert!((bow_score(&a, &a) - 1.0).abs() < 1e-12);
        assert!(bow_score(&a, &[(2, 1.0)]).abs() < 1e-12);
    }
}
