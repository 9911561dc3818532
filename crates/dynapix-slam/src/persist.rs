//! Map save/load (ORB-SLAM2 has none upstream; issue 7 adds it for `--localize`): a versioned
//! binary map file, encoded and decoded in memory so the library stays free of I/O.
//!
//! Layout: a fixed little-endian header, then a [`postcard`] payload (serde; integers and
//! lengths as LEB128 varints, floats as little-endian IEEE bits, no field names):
//!
//! | bytes | content |
//! |---|---|
//! | 8 | magic `DPXMAP\0\0` |
//! | 4 | format version (u32 LE, [`FORMAT_VERSION`]) |
//! | 4 | reserved flags (u32 LE, 0) |
//! | 8 | payload length (u64 LE) |
//! | 4 | CRC-32 (IEEE, LE) of the payload |
//! | n | payload: [`SavedMap`] serialised with postcard |
//!
//! The payload holds the producer string, the camera (intrinsics, distortion, `bf`,
//! `th_depth`, fps, max depth), the depth factor, the identity of the vocabulary the BoW
//! vectors were computed with, and the [`MapSnapshot`]: pyramid, sequence counters, keyframes
//! (pose, keypoints raw and undistorted, descriptors, depth, uR, weights, dynamic flags,
//! matches, BoW and feature vectors, covisibility, spanning tree, loop edges, ids and
//! timestamp) and map points (position, normal, distances, descriptor, observations,
//! reference, counters, weight). Ids become dense indices; grids are rebuilt on load.
//! Culled-keyframe links and the replaced-point table are not saved: they only serve to
//! recompose the trajectory of the run that built the map. Version 1 was a hand-written
//! fixed-width encoding of the same fields; this build refuses it (`UnsupportedVersion`).
//!
//! Field order is the declaration order of the serde structs, so changing a payload struct
//! changes the format and needs a [`FORMAT_VERSION`] bump. Encoding is deterministic (no maps
//! with unstable order in the payload), so the same map always gives the same bytes.
//!
//! [`decode`] never panics: every byte string gives a validated [`SavedMap`] or a typed
//! [`PersistError`]. Memory stays bounded by the input: postcard reads each element from the
//! input before storing it, and serde preallocates at most 1 MiB for a sequence whatever
//! length it claims.

mod snapshot;

#[cfg(test)]
mod tests;

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::camera::RgbdCamera;

use crate::features::ScalePyramid;
use crate::map::{Map, MapParams};
use crate::vocab::Vocabulary;

pub use snapshot::{KeyFrameSnapshot, MapPointSnapshot, MapSnapshot};

/// Magic bytes opening every map file.
pub const MAGIC: [u8; 8] = *b"DPXMAP\0\0";
/// Format version this build writes and reads.
pub const FORMAT_VERSION: u32 = 2;
/// Size of the fixed header before the payload.
pub const HEADER_LEN: usize = 28;

/// Errors of map loading (and of the caller's file access, for one error type end to end).
#[derive(Debug, thiserror::Error)]
pub enum PersistError {
    /// The map could not be serialised (not expected for a valid map).
    #[error("cannot encode the map: {reason}")]
    Encode {
        /// The serialiser's message.
        reason: String,
    },
    /// Reading or writing the map file failed (the I/O error is the source).
    #[error("cannot access map file {path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The data does not start with the map magic bytes.
    #[error("not a dynapix map file (bad magic bytes)")]
    BadMagic,
    /// The file was written by a format version this build cannot read.
    #[error("unsupported map format version {found} (this build reads version {supported})")]
    UnsupportedVersion {
        /// Version in the file.
        found: u32,
        /// Version this build reads.
        supported: u32,
    },
    /// The data ends before the header or the payload says it should.
    #[error("map file truncated")]
    Truncated,
    /// The payload checksum does not match (file damaged).
    #[error("map file checksum mismatch (file damaged)")]
    Checksum,
    /// The payload is structurally invalid.
    #[error("corrupt map file: {what}")]
    Corrupt {
        /// What is wrong.
        what: String,
    },
    /// The map was built with a different camera than the one the caller uses.
    #[error("map camera differs from this run's: {what}")]
    CameraMismatch {
        /// Which parameter differs, with both values.
        what: String,
    },
    /// The map keypoints use another scale pyramid than the caller's feature extractor.
    #[error(
        "map was built with a {map_levels}-level pyramid of scale {map_scale}, this run extracts {levels} levels of scale {scale}"
    )]
    PyramidMismatch {
        /// Levels in the map.
        map_levels: u32,
        /// Scale factor in the map.
        map_scale: f32,
        /// Levels of the caller.
        levels: usize,
        /// Scale factor of the caller.
        scale: f32,
    },
    /// The map's BoW vectors come from another vocabulary than the caller's.
    #[error("map was built with vocabulary {expected}, got {got}")]
    VocabularyMismatch {
        /// Vocabulary of the map ("none" without one).
        expected: String,
        /// Vocabulary of the caller ("none" without one).
        got: String,
    },
}

impl PersistError {
    fn corrupt(what: impl Into<String>) -> Self {
        Self::Corrupt { what: what.into() }
    }
}

/// Identity of a vocabulary: its shape and the FNV-1a 64 checksum of its binary serialisation
/// (the one [`Vocabulary::to_bytes`] ends with), so equal trees give equal ids.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct VocabularyId {
    /// Checksum of the serialised vocabulary.
    pub hash: u64,
    /// Branching factor k.
    pub branching: u32,
    /// Depth L.
    pub levels: u32,
    /// Number of words.
    pub words: u32,
}

impl VocabularyId {
    /// The identity of `vocab`.
    pub fn of(vocab: &Vocabulary) -> Self {
        let bytes = vocab.to_bytes();
        let tail = bytes.len().saturating_sub(8);
        let mut h = [0u8; 8];
        if let Some(s) = bytes.get(tail..) {
            h.copy_from_slice(s);
        }
        Self {
            hash: u64::from_le_bytes(h),
            branching: u32::try_from(vocab.branching()).unwrap_or(u32::MAX),
            levels: u32::try_from(vocab.levels()).unwrap_or(u32::MAX),
            words: u32::try_from(vocab.word_count()).unwrap_or(u32::MAX),
        }
    }
}

impl std::fmt::Display for VocabularyId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:016x} (k={}, L={}, {} words)",
            self.hash, self.branching, self.levels, self.words
        )
    }
}

fn vocab_name(v: Option<VocabularyId>) -> String {
    v.map_or_else(|| "none".to_string(), |v| v.to_string())
}

/// Everything a map file holds (the payload, in field order).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SavedMap {
    /// Program and version that wrote the file.
    pub producer: String,
    /// Camera the map was built with.
    pub camera: RgbdCamera,
    /// Depth image factor (raw value per metre) of the sequence the map was built from.
    pub depth_factor: f64,
    /// Vocabulary of the BoW vectors (None: built without one).
    pub vocabulary: Option<VocabularyId>,
    /// The map.
    pub map: MapSnapshot,
}

/// The producer string of this build.
pub fn producer() -> String {
    format!("dynapix-slam {}", env!("CARGO_PKG_VERSION"))
}

impl SavedMap {
    /// Captures `map` with the context needed to use it again.
    pub fn from_map(
        map: &Map,
        camera: &RgbdCamera,
        depth_factor: f64,
        vocab: Option<&Vocabulary>,
    ) -> Self {
        Self {
            producer: producer(),
            camera: camera.clone(),
            depth_factor,
            vocabulary: vocab.map(VocabularyId::of),
            map: MapSnapshot::from_map(map),
        }
    }

    /// Serialises to the map file format (header + payload).
    pub fn to_bytes(&self) -> Result<Vec<u8>, PersistError> {
        // The payload is serialised in place behind a zeroed header, which is then filled in
        // (saves copying a multi-megabyte payload).
        let mut out = vec![0u8; HEADER_LEN];
        out.reserve(self.payload_size_hint());
        // Not expected to fail (every payload type is a plain struct, tuple, fixed array,
        // `Option` or `Vec` of known length, written into a growable vector), but a serialiser
        // error is reported, not turned into a panic.
        let mut out = postcard::to_extend(self, out).map_err(|e| PersistError::Encode {
            reason: e.to_string(),
        })?;
        let payload = out.get(HEADER_LEN..).unwrap_or_default();
        let len = (payload.len() as u64).to_le_bytes();
        let crc = crc32fast::hash(payload).to_le_bytes();
        let header = [
            &MAGIC[..],
            &FORMAT_VERSION.to_le_bytes(),
            &[0; 4],
            &len,
            &crc,
        ]
        .concat();
        out[..HEADER_LEN].copy_from_slice(&header);
        Ok(out)
    }

    /// Rough payload size (per-keypoint and per-point bytes of a typical map), so encoding
    /// grows its buffer at most once or twice.
    fn payload_size_hint(&self) -> usize {
        let keys: usize = self.map.keyframes.iter().map(|k| k.keys.len()).sum();
        keys * 110 + self.map.points.len() * 120
    }

    /// Number of keyframes in the map.
    pub fn num_keyframes(&self) -> usize {
        self.map.keyframes.len()
    }

    /// Number of map points.
    pub fn num_points(&self) -> usize {
        self.map.points.len()
    }

    /// Refuses a camera, depth factor, pyramid or vocabulary different from the map's: the
    /// keypoints, depths and BoW vectors stored in it would not be comparable with new frames.
    pub fn check_compatible(
        &self,
        camera: &RgbdCamera,
        depth_factor: f64,
        pyramid: &ScalePyramid,
        vocab: Option<&Vocabulary>,
    ) -> Result<(), PersistError> {
        check_camera(&self.camera, self.depth_factor, camera, depth_factor)?;
        if self.map.pyramid_levels as usize != pyramid.levels
            || self.map.scale_factor.to_bits() != pyramid.scale_factor.to_bits()
        {
            return Err(PersistError::PyramidMismatch {
                map_levels: self.map.pyramid_levels,
                map_scale: self.map.scale_factor,
                levels: pyramid.levels,
                scale: pyramid.scale_factor,
            });
        }
        let got = vocab.map(VocabularyId::of);
        if got != self.vocabulary {
            return Err(PersistError::VocabularyMismatch {
                expected: vocab_name(self.vocabulary),
                got: vocab_name(got),
            });
        }
        Ok(())
    }

    /// Rebuilds the live map (grids over the saved camera's image bounds).
    pub fn into_map(self, params: MapParams) -> Map {
        let bounds = self.camera.image_bounds();
        self.map.into_map(bounds, params)
    }
}

/// Relative closeness for camera parameters read from the same settings (they are normally
/// bit-identical; the tolerance only absorbs text round trips).
const CAMERA_RTOL: f64 = 1e-9;

fn check_camera(
    map: &RgbdCamera,
    map_depth_factor: f64,
    cam: &RgbdCamera,
    depth_factor: f64,
) -> Result<(), PersistError> {
    let close = |a: f64, b: f64| (a - b).abs() <= CAMERA_RTOL * a.abs().max(b.abs()).max(1.0);
    let (m, c) = (&map.pinhole, &cam.pinhole);
    if (m.width, m.height) != (c.width, c.height) {
        return Err(PersistError::CameraMismatch {
            what: format!(
                "image size {}x{} in the map, {}x{} here",
                m.width, m.height, c.width, c.height
            ),
        });
    }
    let mut pairs = vec![
        ("fx", m.fx, c.fx),
        ("fy", m.fy, c.fy),
        ("cx", m.cx, c.cx),
        ("cy", m.cy, c.cy),
    ];
    for (name, (a, b)) in ["k1", "k2", "p1", "p2", "k3"]
        .iter()
        .zip(m.dist.iter().zip(&c.dist))
    {
        pairs.push((name, *a, *b));
    }
    pairs.extend([
        ("bf", map.bf, cam.bf),
        ("ThDepth", map.th_depth, cam.th_depth),
        ("DepthMapFactor", map_depth_factor, depth_factor),
    ]);
    for (name, a, b) in pairs {
        if !close(a, b) {
            return Err(PersistError::CameraMismatch {
                what: format!("{name} is {a} in the map, {b} here"),
            });
        }
    }
    Ok(())
}

/// Encodes `map` with its camera, depth factor and vocabulary into a map file's bytes.
pub fn encode(
    map: &Map,
    camera: &RgbdCamera,
    depth_factor: f64,
    vocab: Option<&Vocabulary>,
) -> Result<Vec<u8>, PersistError> {
    SavedMap::from_map(map, camera, depth_factor, vocab).to_bytes()
}

/// Decodes and validates a map file's bytes.
pub fn decode(bytes: &[u8]) -> Result<SavedMap, PersistError> {
    let Some(magic) = bytes.get(..MAGIC.len()) else {
        // A short prefix of a real map file is a truncation, anything else is not a map.
        return Err(if MAGIC.starts_with(bytes) {
            PersistError::Truncated
        } else {
            PersistError::BadMagic
        });
    };
    if magic != MAGIC {
        return Err(PersistError::BadMagic);
    }
    let version = u32::from_le_bytes(header_field(bytes, 8)?);
    if version != FORMAT_VERSION {
        return Err(PersistError::UnsupportedVersion {
            found: version,
            supported: FORMAT_VERSION,
        });
    }
    let flags = u32::from_le_bytes(header_field(bytes, 12)?);
    let len = u64::from_le_bytes(header_field(bytes, 16)?);
    let crc = u32::from_le_bytes(header_field(bytes, 24)?);
    if flags != 0 {
        return Err(PersistError::corrupt(format!(
            "unknown header flags {flags:#x}"
        )));
    }
    let payload = bytes.get(HEADER_LEN..).ok_or(PersistError::Truncated)?;
    let have = payload.len() as u64;
    if have < len {
        return Err(PersistError::Truncated);
    }
    if have > len {
        return Err(PersistError::corrupt(format!(
            "{} bytes after the {len}-byte payload",
            have - len
        )));
    }
    if crc32fast::hash(payload) != crc {
        return Err(PersistError::Checksum);
    }
    decode_payload(payload)
}

/// The `N` header bytes at `at` (a header cut short is a truncation).
fn header_field<const N: usize>(bytes: &[u8], at: usize) -> Result<[u8; N], PersistError> {
    let s = bytes.get(at..at + N).ok_or(PersistError::Truncated)?;
    let mut a = [0u8; N];
    a.copy_from_slice(s);
    Ok(a)
}

/// Parses and validates a payload without the header checks (also the fuzzing entry point:
/// a payload that passes the checksum must still never panic).
fn decode_payload(payload: &[u8]) -> Result<SavedMap, PersistError> {
    let (saved, rest) = postcard::take_from_bytes::<SavedMap>(payload).map_err(|e| match e {
        postcard::Error::DeserializeUnexpectedEnd => PersistError::Truncated,
        e => PersistError::corrupt(format!("payload: {e}")),
    })?;
    if !rest.is_empty() {
        return Err(PersistError::corrupt(format!(
            "{} unread payload bytes",
            rest.len()
        )));
    }
    check_saved_camera(&saved)?;
    saved.map.validate()?;
    if let Some(v) = saved.vocabulary {
        for (i, k) in saved.map.keyframes.iter().enumerate() {
            if let Some(w) = k.bow.iter().find(|w| w.0 >= v.words) {
                return Err(PersistError::corrupt(format!(
                    "keyframe {i}: word {} of a {}-word vocabulary",
                    w.0, v.words
                )));
            }
        }
    }
    Ok(saved)
}

fn check_saved_camera(s: &SavedMap) -> Result<(), PersistError> {
    let c = &s.camera;
    let p = &c.pinhole;
    let nums = [p.fx, p.fy, p.cx, p.cy, c.bf, c.th_depth, c.fps, c.max_depth];
    if !nums.iter().chain(&p.dist).all(|v| v.is_finite())
        || p.fx <= 0.0
        || p.fy <= 0.0
        || p.width == 0
        || p.height == 0
    {
        return Err(PersistError::corrupt("camera parameters invalid"));
    }
    if !(s.depth_factor.is_finite() && s.depth_factor > 0.0) {
        return Err(PersistError::corrupt(format!(
            "depth factor {}",
            s.depth_factor
        )));
    }
    Ok(())
}
