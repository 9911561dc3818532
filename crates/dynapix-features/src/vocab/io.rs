//! Vocabulary serialisation: the dynapix binary format, the ORB-SLAM2 `ORBvoc.txt` text format
//! (spec §6.9), and file helpers (atomic writes).
//!
//! Binary format, version 1, all integers little endian:
//!
//! | bytes | content |
//! |---|---|
//! | 8 | magic `DPXVOCAB` |
//! | 4 | format version (1) |
//! | 4 | branching factor k |
//! | 4 | depth L |
//! | 4 | scoring (0 = L1, as DBoW2) |
//! | 4 | weighting (0 = TF-IDF, as DBoW2) |
//! | 4 | node count n, root included |
//! | 40 · (n − 1) | per non-root node in id order: parent u32, descriptor 32 bytes, weight f32 |
//! | 8 | FNV-1a 64 checksum of all preceding bytes |
//!
//! Leaves are the nodes without children, word ids count them in node order (as DBoW2).

use super::{VocabError, Vocabulary};
use crate::keypoint::Descriptor;
use std::io::BufRead;
use std::path::Path;

const MAGIC: &[u8; 8] = b"DPXVOCAB";
const VERSION: u32 = 1;
const HEADER: usize = 8 + 6 * 4;
const RECORD: usize = 4 + 32 + 4;
/// DBoW2 scoring and weighting codes this implementation supports (L1-norm, TF-IDF).
const SCORING_L1: u32 = 0;
const WEIGHTING_TF_IDF: u32 = 0;

fn fnv1a64(data: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in data {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    let mut a = [0u8; 4];
    a.copy_from_slice(&b[at..at + 4]);
    u32::from_le_bytes(a)
}

impl Vocabulary {
    /// Serialises to the dynapix binary format (see the module docs).
    pub fn to_bytes(&self) -> Vec<u8> {
        let n = self.parent.len();
        let mut out = Vec::with_capacity(HEADER + RECORD * n + 8);
        out.extend_from_slice(MAGIC);
        for v in [
            VERSION,
            self.k,
            self.levels,
            SCORING_L1,
            WEIGHTING_TF_IDF,
            n as u32,
        ] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for id in 1..n {
            out.extend_from_slice(&self.parent[id].to_le_bytes());
            out.extend_from_slice(&self.descriptor[id]);
            out.extend_from_slice(&self.weight[id].to_le_bytes());
        }
        let sum = fnv1a64(&out);
        out.extend_from_slice(&sum.to_le_bytes());
        out
    }

    /// Parses the dynapix binary format, checking magic, version, length, checksum and tree
    /// consistency.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, VocabError> {
        if bytes.len() < 8 || &bytes[..8] != MAGIC {
            return Err(VocabError::BadMagic);
        }
        if bytes.len() < HEADER + 8 {
            return Err(VocabError::BadLength {
                expected: HEADER + 8,
                got: bytes.len(),
            });
        }
        let version = u32_at(bytes, 8);
        if version != VERSION {
            return Err(VocabError::UnsupportedVersion {
                got: version,
                expected: VERSION,
            });
        }
        let (k, levels, scoring, weighting) = (
            u32_at(bytes, 12),
            u32_at(bytes, 16),
            u32_at(bytes, 20),
            u32_at(bytes, 24),
        );
        let n = u32_at(bytes, 28) as usize;
        let expected = n
            .checked_sub(1)
            .and_then(|m| m.checked_mul(RECORD))
            .and_then(|m| m.checked_add(HEADER + 8));
        let Some(expected) = expected else {
            return Err(VocabError::BadNode {
                node: 0,
                reason: format!("node count {n}"),
            });
        };
        if bytes.len() != expected {
            return Err(VocabError::BadLength {
                expected,
                got: bytes.len(),
            });
        }
        let body = &bytes[..expected - 8];
        let mut sum = [0u8; 8];
        sum.copy_from_slice(&bytes[expected - 8..]);
        if fnv1a64(body) != u64::from_le_bytes(sum) {
            return Err(VocabError::Checksum);
        }
        check_codes(scoring, weighting)?;
        let mut parent = vec![0u32; n];
        let mut descriptor = vec![[0u8; 32]; n];
        let mut weight = vec![0f32; n];
        for id in 1..n {
            let at = HEADER + (id - 1) * RECORD;
            parent[id] = u32_at(bytes, at);
            descriptor[id].copy_from_slice(&bytes[at + 4..at + 36]);
            weight[id] = f32::from_bits(u32_at(bytes, at + 36));
        }
        Self::from_nodes(k, levels, parent, descriptor, weight)
    }

    /// Parses an ORB-SLAM2 / DBoW2 text vocabulary (`ORBvoc.txt`): a header line
    /// `k L scoring weighting`, then one line per non-root node `parent is_leaf b0 … b31 weight`
    /// in node order. Empty lines are skipped (upstream turns a trailing one into a bogus node).
    pub fn from_orbvoc_text<R: BufRead>(reader: R) -> Result<Self, VocabError> {
        let mut lines = reader.lines().enumerate();
        let text_err = |line: usize, reason: String| VocabError::Text { line, reason };
        let (k, levels) = loop {
            let Some((i, line)) = lines.next() else {
                return Err(text_err(1, "missing header line".into()));
            };
            let line = line.map_err(|e| text_err(i + 1, e.to_string()))?;
            if line.trim().is_empty() {
                continue;
            }
            let f: Vec<&str> = line.split_whitespace().collect();
            if f.len() != 4 {
                return Err(text_err(
                    i + 1,
                    format!("header needs `k L scoring weighting`, got {line:?}"),
                ));
            }
            let mut v = [0u32; 4];
            for (slot, s) in v.iter_mut().zip(&f) {
                *slot = s
                    .parse()
                    .map_err(|_| text_err(i + 1, format!("header field {s:?} is not a number")))?;
            }
            check_codes(v[2], v[3])?;
            break (v[0], v[1]);
        };
        let mut parent = vec![0u32];
        let mut descriptor: Vec<Descriptor> = vec![[0u8; 32]];
        let mut weight = vec![0f32];
        let mut leaf_flag = vec![false];
        for (i, line) in lines {
            let line = line.map_err(|e| text_err(i + 1, e.to_string()))?;
            if line.trim().is_empty() {
                continue;
            }
            let f: Vec<&str> = line.split_whitespace().collect();
            if f.len() != 35 {
                return Err(text_err(
                    i + 1,
                    format!(
                        "expected 35 fields (parent, leaf, 32 bytes, weight), got {}",
                        f.len()
                    ),
                ));
            }
            let p: u32 = f[0]
                .parse()
                .map_err(|_| text_err(i + 1, format!("parent {:?} is not a node id", f[0])))?;
            if p as usize >= parent.len() {
                return Err(text_err(
                    i + 1,
                    format!("parent {p} is not an earlier node"),
                ));
            }
            let leaf = match f[1] {
                "0" => false,
                "1" => true,
                other => return Err(text_err(i + 1, format!("leaf flag {other:?} is not 0/1"))),
            };
            let mut d = [0u8; 32];
            for (b, s) in d.iter_mut().zip(&f[2..34]) {
                *b = s.parse().map_err(|_| {
                    text_err(i + 1, format!("descriptor byte {s:?} not in 0..=255"))
                })?;
            }
            let w: f32 = f[34]
                .parse()
                .map_err(|_| text_err(i + 1, format!("weight {:?} is not a number", f[34])))?;
            if !w.is_finite() {
                return Err(text_err(i + 1, format!("weight {w} is not finite")));
            }
            parent.push(p);
            descriptor.push(d);
            weight.push(w);
            leaf_flag.push(leaf);
        }
        if parent.len() < 2 {
            return Err(text_err(1, "no nodes after the header".into()));
        }
        let voc = Self::from_nodes(k, levels, parent, descriptor, weight)?;
        // The leaf flags must agree with the tree shape, or word ids would not match upstream's.
        for (id, &flag) in leaf_flag.iter().enumerate().skip(1) {
            let has_children = !voc.children(id).is_empty();
            if flag == has_children {
                return Err(VocabError::BadNode {
                    node: id as u64,
                    reason: format!(
                        "leaf flag {} but the node has {} children",
                        flag as u8,
                        voc.children(id).len()
                    ),
                });
            }
        }
        Ok(voc)
    }

    /// Loads a vocabulary file, dynapix binary or ORB-SLAM2 text (detected by the magic bytes).
    pub fn load(path: &Path) -> Result<Self, VocabError> {
        let io_err = |source| VocabError::Io {
            path: path.to_path_buf(),
            source,
        };
        let bytes = std::fs::read(path).map_err(io_err)?;
        if bytes.starts_with(MAGIC) {
            Self::from_bytes(&bytes)
        } else if bytes.starts_with(&[0x1f, 0x8b]) {
            // ORB-SLAM2 ships `ORBvoc.txt.tar.gz`; decompression is left to the user.
            Err(VocabError::Unsupported(format!(
                "{} is gzip-compressed; extract it first (tar -xzf ORBvoc.txt.tar.gz)",
                path.display()
            )))
        } else {
            Self::from_orbvoc_text(std::io::Cursor::new(bytes))
        }
    }

    /// Writes the binary format atomically ([`dynapix_io::write_atomic`]).
    pub fn save(&self, path: &Path) -> Result<(), VocabError> {
        dynapix_io::write_atomic(path, &self.to_bytes())?;
        Ok(())
    }
}

fn check_codes(scoring: u32, weighting: u32) -> Result<(), VocabError> {
    if scoring != SCORING_L1 {
        return Err(VocabError::Unsupported(format!(
            "scoring type {scoring} (only 0 = L1-norm is implemented)"
        )));
    }
    if weighting != WEIGHTING_TF_IDF {
        return Err(VocabError::Unsupported(format!(
            "weighting type {weighting} (only 0 = TF-IDF is implemented)"
        )));
    }
    Ok(())
}
