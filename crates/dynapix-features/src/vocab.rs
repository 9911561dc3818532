//! DBoW2-style bag-of-words vocabulary over 256-bit ORB descriptors (spec §6.9; the place
//! recognition and BoW-guided matching backbone of ORB-SLAM2).
//!
//! A vocabulary is a tree with branching factor k and depth L built by hierarchical k-medians
//! (k-means++ seeding with a fixed seed, bitwise-majority centres). Leaves are words with an IDF
//! weight ln(N/Nᵢ) (N training images, Nᵢ images containing the word). An image becomes a
//! [`BowVector`] (TF-IDF, L1-normalised) and a [`FeatureVector`] (feature indices grouped by
//! the node `levels_up` levels above the leaves), and two images are compared with the L1 score
//! s = 1 − ½·Σ|v/|v|₁ − w/|w|₁|.
//!
//! Node numbering follows DBoW2: the root is node 0, children of a node are created together
//! and the tree is grown depth first, so the node order is the line order of `ORBvoc.txt` and
//! word ids number the leaves in node order.
//!
//! Why not `kornia-bow` 0.2 (design.md §4 asked to evaluate it first): its k-means++ draws from
//! an unseeded thread RNG (training is not reproducible), its IDF counts features instead of
//! images, and its direct index groups by depth from the root; DBoW2 semantics are needed here.
//!
//! Files: our own compact binary format (see [`Vocabulary::to_bytes`]) and an importer of the
//! ORB-SLAM2 text format [`Vocabulary::from_orbvoc_text`].

mod io;
mod train;

pub use train::TrainParams;

use crate::keypoint::{Descriptor, hamming};

/// Index of a leaf of the vocabulary (a visual word), counting leaves in node order.
pub type WordId = u32;
/// Index of a vocabulary node; 0 is the root.
pub type NodeId = u32;

/// Errors of vocabulary training, loading and saving.
#[derive(Debug, thiserror::Error)]
pub enum VocabError {
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// Writing the vocabulary file failed.
    #[error(transparent)]
    Write(#[from] dynapix_io::IoError),
    /// The binary data does not start with the vocabulary magic bytes.
    #[error("not a dynapix vocabulary (bad magic bytes)")]
    BadMagic,
    /// The binary format version is not supported.
    #[error("unsupported vocabulary format version {got} (this build reads {expected})")]
    UnsupportedVersion {
        /// Version in the file.
        got: u32,
        /// Version this build reads.
        expected: u32,
    },
    /// The binary data is shorter or longer than its header says.
    #[error("vocabulary data has {got} bytes, header implies {expected}")]
    BadLength {
        /// Implied size.
        expected: usize,
        /// Actual size.
        got: usize,
    },
    /// The checksum at the end of the binary data does not match.
    #[error("vocabulary checksum mismatch (file corrupt)")]
    Checksum,
    /// A node of the tree is inconsistent.
    #[error("vocabulary node {node}: {reason}")]
    BadNode {
        /// Node id.
        node: u64,
        /// What is wrong.
        reason: String,
    },
    /// A line of an `ORBvoc.txt` text vocabulary could not be parsed.
    #[error("ORBvoc text line {line}: {reason}")]
    Text {
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// A feature of the vocabulary this implementation does not support.
    #[error("unsupported vocabulary: {0}")]
    Unsupported(String),
    /// Training parameters or data are unusable.
    #[error("cannot train vocabulary: {0}")]
    Train(String),
}

/// Bag-of-words vector: (word, weight) pairs sorted by word id, L1-normalised (weights sum to
/// 1) unless empty. Word ids are what an inverted index (keyframe database) is built from.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BowVector(Vec<(WordId, f64)>);

impl BowVector {
    /// Builds a vector from (word, weight) pairs: sums duplicates, sorts by word, L1-normalises.
    pub fn from_weights(mut pairs: Vec<(WordId, f64)>) -> Self {
        pairs.sort_by_key(|p| p.0);
        let mut out: Vec<(WordId, f64)> = Vec::with_capacity(pairs.len());
        for (w, v) in pairs {
            match out.last_mut() {
                Some(last) if last.0 == w => last.1 += v,
                _ => out.push((w, v)),
            }
        }
        let norm: f64 = out.iter().map(|p| p.1.abs()).sum();
        if norm > 0.0 {
            for p in &mut out {
                p.1 /= norm;
            }
        }
        Self(out)
    }
    /// The (word, weight) pairs, sorted by word id.
    pub fn as_slice(&self) -> &[(WordId, f64)] {
        &self.0
    }
    /// Iterates over (word, weight) pairs in word order.
    pub fn iter(&self) -> impl Iterator<Item = &(WordId, f64)> {
        self.0.iter()
    }
    /// Iterates over the word ids present.
    pub fn words(&self) -> impl Iterator<Item = WordId> + '_ {
        self.0.iter().map(|p| p.0)
    }
    /// Weight of `word`, if present.
    pub fn get(&self, word: WordId) -> Option<f64> {
        self.0
            .binary_search_by_key(&word, |p| p.0)
            .ok()
            .map(|i| self.0[i].1)
    }
    /// Number of distinct words.
    pub fn len(&self) -> usize {
        self.0.len()
    }
    /// True when no word is present.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
    /// L1 similarity s = 1 − ½·Σ|v/|v|₁ − w/|w|₁| in [0, 1] (DBoW2 `L1Scoring`); 0 when either
    /// vector is empty.
    pub fn l1_score(&self, other: &BowVector) -> f64 {
        let na: f64 = self.0.iter().map(|p| p.1.abs()).sum();
        let nb: f64 = other.0.iter().map(|p| p.1.abs()).sum();
        if na <= 0.0 || nb <= 0.0 {
            return 0.0;
        }
        // Only common words contribute: |a−b| − |a| − |b| is 0 elsewhere.
        let (a, b) = (&self.0, &other.0);
        let (mut i, mut j) = (0, 0);
        let mut s = 0.0;
        while i < a.len() && j < b.len() {
            match a[i].0.cmp(&b[j].0) {
                std::cmp::Ordering::Less => i += 1,
                std::cmp::Ordering::Greater => j += 1,
                std::cmp::Ordering::Equal => {
                    let (x, y) = (a[i].1 / na, b[j].1 / nb);
                    s += (x - y).abs() - x.abs() - y.abs();
                    i += 1;
                    j += 1;
                }
            }
        }
        (-0.5 * s).clamp(0.0, 1.0)
    }
}

/// Direct index of one image: (node, feature indices) sorted by node id, indices ascending.
/// Features are grouped by their ancestor node a fixed number of levels above the leaves; ORB-
/// SLAM2's BoW matching only compares features that share such a node.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FeatureVector(Vec<(NodeId, Vec<usize>)>);

impl FeatureVector {
    /// The (node, features) groups sorted by node id.
    pub fn as_slice(&self) -> &[(NodeId, Vec<usize>)] {
        &self.0
    }
    /// Iterates over the groups in node order.
    pub fn iter(&self) -> impl Iterator<Item = &(NodeId, Vec<usize>)> {
        self.0.iter()
    }
    /// Features under `node`, if any.
    pub fn get(&self, node: NodeId) -> Option<&[usize]> {
        self.0
            .binary_search_by_key(&node, |p| p.0)
            .ok()
            .map(|i| &self.0[i].1[..])
    }
    /// Number of groups.
    pub fn len(&self) -> usize {
        self.0.len()
    }
    /// True when there are no groups.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

/// The default vocabulary shipped with the repository (`assets/vocab/`, provenance in
/// `assets/vocab/PROVENANCE.md`): k = 10, L = 4, trained with `dynapix vocab train` on the 300
/// RGB frames of TUM RGB-D fr1/xyz (CC BY 4.0).
static EMBEDDED_DEFAULT: &[u8] = include_bytes!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../assets/vocab/fr1_xyz_k10_l4.dpxvoc"
));

/// Levels above the leaves at which ORB-SLAM2 groups features (`levelsup = 4`).
pub const DEFAULT_LEVELS_UP: usize = 4;

/// A hierarchical vocabulary tree (DBoW2 `TemplatedVocabulary` with ORB descriptors, L1
/// scoring and TF-IDF weighting).
#[derive(Clone, Debug, PartialEq)]
pub struct Vocabulary {
    k: u32,
    levels: u32,
    /// Parent of each node (root: itself).
    parent: Vec<NodeId>,
    /// Centre descriptor of each node (root: zeros).
    descriptor: Vec<Descriptor>,
    /// IDF weight of each node (meaningful for leaves).
    weight: Vec<f32>,
    /// Children of node n are `child_ids[child_off[n]..child_off[n+1]]`, ascending.
    child_off: Vec<u32>,
    child_ids: Vec<NodeId>,
    /// Depth of each node (root 0).
    depth: Vec<u8>,
    /// Word id of each leaf node (`u32::MAX` for inner nodes).
    word_of_node: Vec<WordId>,
    /// Node id of each word.
    node_of_word: Vec<NodeId>,
}

impl Vocabulary {
    /// Assembles a vocabulary from per-node parents (node 0 is the root, every other node's
    /// parent has a smaller id), descriptors and weights; leaves are nodes without children.
    pub(crate) fn from_nodes(
        k: u32,
        levels: u32,
        parent: Vec<NodeId>,
        descriptor: Vec<Descriptor>,
        weight: Vec<f32>,
    ) -> Result<Self, VocabError> {
        let n = parent.len();
        if n == 0 || descriptor.len() != n || weight.len() != n {
            return Err(VocabError::BadNode {
                node: 0,
                reason: "empty tree or mismatched node arrays".into(),
            });
        }
        if n > u32::MAX as usize / 2 {
            return Err(VocabError::Unsupported(format!("{n} nodes")));
        }
        let mut depth = vec![0u8; n];
        let mut count = vec![0u32; n + 1];
        for id in 1..n {
            let p = parent[id] as usize;
            if p >= id {
                return Err(VocabError::BadNode {
                    node: id as u64,
                    reason: format!("parent {p} is not an earlier node"),
                });
            }
            let d = depth[p].checked_add(1).ok_or_else(|| VocabError::BadNode {
                node: id as u64,
                reason: "tree deeper than 255 levels".into(),
            })?;
            depth[id] = d;
            count[p + 1] += 1;
            if !weight[id].is_finite() {
                return Err(VocabError::BadNode {
                    node: id as u64,
                    reason: format!("weight {} is not finite", weight[id]),
                });
            }
        }
        let mut child_off = vec![0u32; n + 1];
        for i in 0..n {
            child_off[i + 1] = child_off[i] + count[i + 1];
        }
        let mut fill = child_off.clone();
        let mut child_ids = vec![0u32; n.saturating_sub(1)];
        for (id, &p) in parent.iter().enumerate().skip(1) {
            let p = p as usize;
            child_ids[fill[p] as usize] = id as u32;
            fill[p] += 1;
        }
        let mut word_of_node = vec![u32::MAX; n];
        let mut node_of_word = Vec::new();
        for id in 1..n {
            if child_off[id] == child_off[id + 1] {
                word_of_node[id] = node_of_word.len() as u32;
                node_of_word.push(id as u32);
            }
        }
        let mut parent = parent;
        parent[0] = 0;
        Ok(Self {
            k,
            levels,
            parent,
            descriptor,
            weight,
            child_off,
            child_ids,
            depth,
            word_of_node,
            node_of_word,
        })
    }

    /// The default vocabulary compiled into the binary (see `assets/vocab/PROVENANCE.md`).
    /// Parsing takes a few milliseconds; the only possible error is a corrupt build.
    pub fn embedded_default() -> Result<Self, VocabError> {
        Self::from_bytes(EMBEDDED_DEFAULT)
    }

    /// Branching factor k the vocabulary was built with.
    pub fn branching(&self) -> usize {
        self.k as usize
    }
    /// Depth L the vocabulary was built with.
    pub fn levels(&self) -> usize {
        self.levels as usize
    }
    /// Number of nodes including the root.
    pub fn node_count(&self) -> usize {
        self.parent.len()
    }
    /// Number of words (leaves).
    pub fn word_count(&self) -> usize {
        self.node_of_word.len()
    }
    /// IDF weight of a word (0 for unknown ids).
    pub fn word_weight(&self, word: WordId) -> f64 {
        self.node_of_word
            .get(word as usize)
            .map(|&n| self.weight[n as usize] as f64)
            .unwrap_or(0.0)
    }
    /// Parent of a node (the root is its own parent).
    pub fn parent(&self, node: NodeId) -> Option<NodeId> {
        self.parent.get(node as usize).copied()
    }
    /// Depth of a node below the root.
    pub fn node_depth(&self, node: NodeId) -> Option<usize> {
        self.depth.get(node as usize).map(|&d| d as usize)
    }

    fn children(&self, node: usize) -> &[NodeId] {
        &self.child_ids[self.child_off[node] as usize..self.child_off[node + 1] as usize]
    }

    /// Descends from the root by minimum Hamming distance (first child on ties) and returns the
    /// leaf node and the node on the path at depth `group_depth` (the leaf if shallower).
    fn descend(&self, d: &Descriptor, group_depth: usize) -> (usize, usize) {
        let mut node = 0usize;
        let mut group = 0usize;
        loop {
            let ch = self.children(node);
            if ch.is_empty() {
                break;
            }
            let mut best = ch[0] as usize;
            let mut best_d = u32::MAX;
            for &c in ch {
                let dist = hamming(d, &self.descriptor[c as usize]);
                if dist < best_d {
                    best_d = dist;
                    best = c as usize;
                }
            }
            node = best;
            if self.depth[node] as usize <= group_depth {
                group = node;
            }
        }
        if (self.depth[node] as usize) < group_depth {
            group = node;
        }
        (node, group)
    }

    /// Word id of one descriptor and its IDF weight.
    pub fn word_of(&self, d: &Descriptor) -> (WordId, f64) {
        let (leaf, _) = self.descend(d, 0);
        (self.word_of_node[leaf], self.weight[leaf] as f64)
    }

    /// Depth of the grouping node for `levels_up` levels above the leaves: L − levels_up,
    /// clamped to ≥ 1 so that shallow trees still group by the root's children.
    pub fn group_depth(&self, levels_up: usize) -> usize {
        (self.levels as usize).saturating_sub(levels_up).max(1)
    }

    /// BoW and feature vectors of an image's descriptors with ORB-SLAM2's `levels_up = 4`.
    pub fn transform(&self, descs: &[Descriptor]) -> (BowVector, FeatureVector) {
        self.transform_with_levels_up(descs, DEFAULT_LEVELS_UP)
    }

    /// BoW vector (TF-IDF, L1-normalised) and feature vector grouped `levels_up` levels above the
    /// leaves (see [`Vocabulary::group_depth`]). As DBoW2, features whose word has zero weight
    /// are left out of both.
    pub fn transform_with_levels_up(
        &self,
        descs: &[Descriptor],
        levels_up: usize,
    ) -> (BowVector, FeatureVector) {
        let gd = self.group_depth(levels_up);
        let mut pairs = Vec::with_capacity(descs.len());
        let mut groups: Vec<(NodeId, usize)> = Vec::with_capacity(descs.len());
        for (i, d) in descs.iter().enumerate() {
            let (leaf, group) = self.descend(d, gd);
            let w = self.weight[leaf] as f64;
            if w > 0.0 {
                pairs.push((self.word_of_node[leaf], w));
                groups.push((group as NodeId, i));
            }
        }
        groups.sort_unstable();
        let mut fv: Vec<(NodeId, Vec<usize>)> = Vec::new();
        for (node, i) in groups {
            match fv.last_mut() {
                Some(last) if last.0 == node => last.1.push(i),
                _ => fv.push((node, vec![i])),
            }
        }
        (BowVector::from_weights(pairs), FeatureVector(fv))
    }

    /// L1 score of two BoW vectors (see [`BowVector::l1_score`]).
    pub fn score(&self, a: &BowVector, b: &BowVector) -> f64 {
        a.l1_score(b)
    }
}

#[cfg(test)]
mod tests;
