//! Vocabulary training: hierarchical k-medians over binary descriptors as DBoW2's
//! `HKmeansStep` (k-means++ seeding, assignment by Hamming distance, bitwise-majority centres,
//! iterate until assignments stop changing), then IDF weights from the training images.
//!
//! Determinism: every node's random generator is seeded from the training seed and the node's
//! path in the tree, so results do not depend on rayon's scheduling.

use super::{VocabError, Vocabulary};
use crate::keypoint::{Descriptor, hamming};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Training parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainParams {
    /// Branching factor k (DBoW2 / ORBvoc: 10).
    pub k: usize,
    /// Depth L of the tree (ORBvoc: 6; choose for the amount of data, ~k^L ≈ descriptors/10).
    pub levels: usize,
    /// Seed of the k-means++ initialisation.
    pub seed: u64,
    /// Upper bound on k-medians iterations per node (DBoW2 iterates until convergence).
    pub max_iterations: usize,
}

impl Default for TrainParams {
    /// k = 10, L = 4, seed 0, at most 30 iterations.
    fn default() -> Self {
        Self {
            k: 10,
            levels: 4,
            seed: 0,
            max_iterations: 30,
        }
    }
}

/// A node of the tree under construction.
struct Built {
    centre: Descriptor,
    children: Vec<Built>,
}

/// Subsets at least this large are split on the rayon pool.
const PARALLEL_MIN: usize = 4096;

fn mix(a: u64, b: u64) -> u64 {
    // SplitMix64 finaliser over the combined value: a cheap, well-spread path hash.
    let mut z = a ^ b
        .wrapping_add(0x9E37_79B9_7F4A_7C15)
        .wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Bitwise majority of a set of descriptors; a bit is set when at least half of them (rounded
/// up) have it, as DBoW2's `FORB::meanValue`.
fn majority(all: &[Descriptor], idx: &[u32]) -> Descriptor {
    let mut counts = [0u32; 256];
    for &i in idx {
        let d = &all[i as usize];
        for (byte, &v) in d.iter().enumerate() {
            for bit in 0..8 {
                counts[byte * 8 + bit] += ((v >> bit) & 1) as u32;
            }
        }
    }
    let half = (idx.len() as u32).div_ceil(2);
    let mut out = [0u8; 32];
    for (b, c) in counts.iter().enumerate() {
        if *c >= half && !idx.is_empty() {
            out[b / 8] |= 1 << (b % 8);
        }
    }
    out
}

/// k-means++ seeding: first centre uniform, then each next centre drawn with probability
/// proportional to the squared distance to the nearest chosen centre.
fn seed_centres(
    all: &[Descriptor],
    idx: &[u32],
    k: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<Descriptor> {
    let mut centres = Vec::with_capacity(k);
    let first = idx[rng.random_range(0..idx.len())];
    centres.push(all[first as usize]);
    let mut dmin: Vec<u32> = idx
        .iter()
        .map(|&i| hamming(&all[i as usize], &centres[0]))
        .collect();
    while centres.len() < k {
        let total: f64 = dmin.iter().map(|&d| (d as f64) * (d as f64)).sum();
        if total <= 0.0 {
            break; // All remaining descriptors coincide with a centre.
        }
        let mut cut = rng.random::<f64>() * total;
        let mut pick = idx.len() - 1;
        for (j, &d) in dmin.iter().enumerate() {
            cut -= (d as f64) * (d as f64);
            if cut <= 0.0 && d > 0 {
                pick = j;
                break;
            }
        }
        let c = all[idx[pick] as usize];
        for (j, &i) in idx.iter().enumerate() {
            dmin[j] = dmin[j].min(hamming(&all[i as usize], &c));
        }
        centres.push(c);
    }
    centres
}

/// Index of the nearest centre (first on ties).
fn nearest(d: &Descriptor, centres: &[Descriptor]) -> usize {
    let mut best = 0;
    let mut best_d = u32::MAX;
    for (c, centre) in centres.iter().enumerate() {
        let dist = hamming(d, centre);
        if dist < best_d {
            best_d = dist;
            best = c;
        }
    }
    best
}

/// Splits `idx` into at most k clusters and recurses until depth `levels`.
fn build(all: &[Descriptor], idx: Vec<u32>, depth: usize, key: u64, p: &TrainParams) -> Vec<Built> {
    if depth >= p.levels || idx.len() <= 1 {
        return Vec::new();
    }
    // Trivial case of DBoW2: few descriptors become one child each.
    if idx.len() <= p.k {
        return idx
            .iter()
            .map(|&i| Built {
                centre: all[i as usize],
                children: Vec::new(),
            })
            .collect();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(key);
    let mut centres = seed_centres(all, &idx, p.k, &mut rng);
    let mut assign: Vec<usize> = vec![usize::MAX; idx.len()];
    for _ in 0..p.max_iterations.max(1) {
        let new: Vec<usize> = if idx.len() >= PARALLEL_MIN {
            idx.par_iter()
                .map(|&i| nearest(&all[i as usize], &centres))
                .collect()
        } else {
            idx.iter()
                .map(|&i| nearest(&all[i as usize], &centres))
                .collect()
        };
        if new == assign {
            break;
        }
        assign = new;
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); centres.len()];
        for (j, &c) in assign.iter().enumerate() {
            members[c].push(idx[j]);
        }
        for (c, m) in members.iter().enumerate() {
            if !m.is_empty() {
                centres[c] = majority(all, m);
            }
        }
    }
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); centres.len()];
    for (j, &c) in assign.iter().enumerate() {
        if c < members.len() {
            members[c].push(idx[j]);
        }
    }
    // Empty clusters are dropped; the others recurse (in parallel for large subsets).
    let jobs: Vec<(usize, Descriptor, Vec<u32>)> = members
        .into_iter()
        .enumerate()
        .filter(|(_, m)| !m.is_empty())
        .map(|(c, m)| (c, centres[c], m))
        .collect();
    let recurse = |(c, centre, m): (usize, Descriptor, Vec<u32>)| Built {
        centre,
        children: build(all, m, depth + 1, mix(key, c as u64 + 1), p),
    };
    if idx.len() >= PARALLEL_MIN {
        jobs.into_par_iter().map(recurse).collect()
    } else {
        jobs.into_iter().map(recurse).collect()
    }
}

/// Flattens in DBoW2 node order: a node's children get consecutive ids, then each child's
/// subtree follows depth first.
fn flatten(
    children: Vec<Built>,
    parent_id: u32,
    parent: &mut Vec<u32>,
    desc: &mut Vec<Descriptor>,
) {
    let first = parent.len() as u32;
    let mut subtrees = Vec::with_capacity(children.len());
    for c in children {
        parent.push(parent_id);
        desc.push(c.centre);
        subtrees.push(c.children);
    }
    for (j, sub) in subtrees.into_iter().enumerate() {
        flatten(sub, first + j as u32, parent, desc);
    }
}

impl Vocabulary {
    /// Trains a vocabulary on the descriptors of a set of images (one slice per image; the
    /// image grouping is what the IDF weights count).
    pub fn train(images: &[Vec<Descriptor>], params: &TrainParams) -> Result<Self, VocabError> {
        if params.k < 2 || params.k > 255 {
            return Err(VocabError::Train(format!(
                "k must be in 2..=255, got {}",
                params.k
            )));
        }
        if params.levels == 0 || params.levels > 16 {
            return Err(VocabError::Train(format!(
                "levels must be in 1..=16, got {}",
                params.levels
            )));
        }
        let all: Vec<Descriptor> = images.iter().flatten().copied().collect();
        if all.len() < 2 {
            return Err(VocabError::Train(format!(
                "need at least 2 descriptors, got {}",
                all.len()
            )));
        }
        if all.len() > u32::MAX as usize {
            return Err(VocabError::Train("too many descriptors".into()));
        }
        let idx: Vec<u32> = (0..all.len() as u32).collect();
        let tree = build(&all, idx, 0, mix(params.seed, 0), params);
        let mut parent = vec![0u32];
        let mut desc = vec![[0u8; 32]];
        flatten(tree, 0, &mut parent, &mut desc);
        let n = parent.len();
        let mut voc = Self::from_nodes(
            params.k as u32,
            params.levels as u32,
            parent,
            desc,
            vec![0.0; n],
        )?;
        // IDF: ln(N / Nᵢ) with Nᵢ the number of training images in which word i occurs.
        let words_per_image: Vec<Vec<u32>> = images
            .par_iter()
            .map(|img| {
                let mut w: Vec<u32> = img.iter().map(|d| voc.word_of(d).0).collect();
                w.sort_unstable();
                w.dedup();
                w
            })
            .collect();
        let mut ni = vec![0u32; voc.word_count()];
        for ws in &words_per_image {
            for &w in ws {
                if let Some(c) = ni.get_mut(w as usize) {
                    *c += 1;
                }
            }
        }
        let n_images = images.len() as f64;
        for (word, &count) in ni.iter().enumerate() {
            let node = voc.node_of_word[word] as usize;
            voc.weight[node] = if count > 0 {
                (n_images / count as f64).ln() as f32
            } else {
                0.0
            };
        }
        Ok(voc)
    }
}
