//! Map save/load (ORB-SLAM2 has none upstream; issue 7 adds it for `--localize`): a versioned
//! binary map file, encoded and decoded in memory so the library stays free of I/O.
//!
//! Layout (all integers and floats little-endian):
//!
//! | bytes | content |
//! |---|---|
//! | 8 | magic `DPXMAP\0\0` |
//! | 4 | format version (u32, [`FORMAT_VERSION`]) |
//! | 4 | reserved flags (u32, 0) |
//! | 8 | payload length (u64) |
//! | 4 | CRC-32 (IEEE) of the payload |
//! | n | payload |
//!
//! The payload holds the producer string, the camera (intrinsics, distortion, `bf`,
//! `th_depth`, fps, max depth, depth factor), the identity of the vocabulary the BoW vectors
//! were computed with, and the [`MapSnapshot`]: pyramid, sequence counters, keyframes (pose,
//! keypoints raw and undistorted, descriptors, depth, uR, weights, dynamic flags, matches, BoW
//! and feature vectors, covisibility, spanning tree, loop edges, ids and timestamp) and map
//! points (position, normal, distances, descriptor, observations, reference, counters,
//! weight). Ids become dense indices; grids are rebuilt on load. Culled-keyframe links and the
//! replaced-point table are not saved: they only serve to recompose the trajectory of the
//! run that built the map.
//!
//! [`decode`] never panics and never allocates more than the input can hold: every byte string
//! gives a validated [`SavedMap`] or a typed [`PersistError`].

mod codec;
mod snapshot;

#[cfg(test)]
mod tests;

use std::path::PathBuf;

use dynapix_geometry::{PinholeCamera, Se3};
use nalgebra::{Quaternion, Translation3, UnitQuaternion, Vector3};

use crate::features::KeyPoint;
use crate::frame::{RgbdCamera, ScalePyramid};
use crate::map::{Map, MapParams};
use crate::vocab::Vocabulary;
use codec::{Reader, Writer};

pub use snapshot::{KeyFrameSnapshot, MapPointSnapshot, MapSnapshot};

/// Magic bytes opening every map file.
pub const MAGIC: [u8; 8] = *b"DPXMAP\0\0";
/// Format version this build writes and reads.
pub const FORMAT_VERSION: u32 = 1;
/// Size of the fixed header before the payload.
pub const HEADER_LEN: usize = 28;

/// Errors of map loading (and of the caller's file access, for one error type end to end).
#[derive(Debug, thiserror::Error)]
pub enum PersistError {
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
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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

/// Everything a map file holds.
#[derive(Clone, Debug, PartialEq)]
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
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut w = Writer::new();
        write_payload(&mut w, self);
        let payload = w.buf;
        let mut out = Vec::with_capacity(HEADER_LEN + payload.len());
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
        out.extend_from_slice(&0u32.to_le_bytes());
        out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        out.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
        out.extend_from_slice(&payload);
        out
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
) -> Vec<u8> {
    SavedMap::from_map(map, camera, depth_factor, vocab).to_bytes()
}

/// Decodes and validates a map file's bytes.
pub fn decode(bytes: &[u8]) -> Result<SavedMap, PersistError> {
    let mut r = Reader::new(bytes);
    let magic = r.take(MAGIC.len()).map_err(|_| {
        // A short prefix of a real map file is a truncation, anything else is not a map.
        if MAGIC.starts_with(bytes) {
            PersistError::Truncated
        } else {
            PersistError::BadMagic
        }
    })?;
    if magic != MAGIC {
        return Err(PersistError::BadMagic);
    }
    let version = r.u32()?;
    if version != FORMAT_VERSION {
        return Err(PersistError::UnsupportedVersion {
            found: version,
            supported: FORMAT_VERSION,
        });
    }
    let flags = r.u32()?;
    let len = r.u64()?;
    let crc = r.u32()?;
    if flags != 0 {
        return Err(PersistError::corrupt(format!(
            "unknown header flags {flags:#x}"
        )));
    }
    let have = r.remaining() as u64;
    if have < len {
        return Err(PersistError::Truncated);
    }
    if have > len {
        return Err(PersistError::corrupt(format!(
            "{} bytes after the {len}-byte payload",
            have - len
        )));
    }
    let payload = r.take(r.remaining())?;
    if crc32fast::hash(payload) != crc {
        return Err(PersistError::Checksum);
    }
    decode_payload(payload)
}

/// Parses and validates a payload without the header checks (also the fuzzing entry point:
/// a payload that passes the checksum must still never panic).
fn decode_payload(payload: &[u8]) -> Result<SavedMap, PersistError> {
    let mut r = Reader::new(payload);
    let saved = read_payload(&mut r)?;
    if r.remaining() != 0 {
        return Err(PersistError::corrupt(format!(
            "{} unread payload bytes",
            r.remaining()
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

// Encoded sizes used to bound lengths before allocating.
const KEYPOINT_BYTES: usize = 21;
const POSE_BYTES: usize = 56;

fn write_pose(w: &mut Writer, p: &Se3) {
    let q = p.rotation.quaternion().coords;
    for v in q.iter().chain(p.translation.vector.iter()) {
        w.f64(*v);
    }
}

fn read_pose(r: &mut Reader<'_>) -> Result<Se3, PersistError> {
    let mut v = [0.0f64; 7];
    for x in v.iter_mut() {
        *x = r.f64()?;
    }
    // Stored bit-exact; `validate` rejects a quaternion that is not unit.
    let q = UnitQuaternion::new_unchecked(Quaternion::new(v[3], v[0], v[1], v[2]));
    Ok(Se3::from_parts(Translation3::new(v[4], v[5], v[6]), q))
}

fn write_keypoint(w: &mut Writer, k: &KeyPoint) {
    w.f32(k.x);
    w.f32(k.y);
    w.f32(k.angle);
    w.f32(k.response);
    w.u8(k.octave);
    w.f32(k.size);
}

fn read_keypoint(r: &mut Reader<'_>) -> Result<KeyPoint, PersistError> {
    Ok(KeyPoint {
        x: r.f32()?,
        y: r.f32()?,
        angle: r.f32()?,
        response: r.f32()?,
        octave: r.u8()?,
        size: r.f32()?,
    })
}

fn write_vec3(w: &mut Writer, v: &Vector3<f64>) {
    for x in v.iter() {
        w.f64(*x);
    }
}

fn read_vec3(r: &mut Reader<'_>) -> Result<Vector3<f64>, PersistError> {
    Ok(Vector3::new(r.f64()?, r.f64()?, r.f64()?))
}

fn write_payload(w: &mut Writer, s: &SavedMap) {
    w.str(&s.producer);
    let c = &s.camera;
    let p = &c.pinhole;
    w.u32(p.width);
    w.u32(p.height);
    for v in [p.fx, p.fy, p.cx, p.cy] {
        w.f64(v);
    }
    for v in p.dist {
        w.f64(v);
    }
    for v in [c.bf, c.th_depth, c.fps, c.max_depth, s.depth_factor] {
        w.f64(v);
    }
    match &s.vocabulary {
        None => w.u8(0),
        Some(v) => {
            w.u8(1);
            w.u64(v.hash);
            w.u32(v.branching);
            w.u32(v.levels);
            w.u32(v.words);
        }
    }
    let m = &s.map;
    w.u32(m.pyramid_levels);
    w.f32(m.scale_factor);
    w.u64(m.next_kf_seq);
    w.u64(m.next_mp_seq);
    w.opt_index(m.origin);
    w.len(m.keyframes.len());
    for k in &m.keyframes {
        write_keyframe(w, k);
    }
    w.len(m.points.len());
    for p in &m.points {
        write_point(w, p);
    }
}

fn write_keyframe(w: &mut Writer, k: &KeyFrameSnapshot) {
    w.u64(k.seq);
    w.u64(k.frame_id);
    w.f64(k.timestamp);
    write_pose(w, &k.pose);
    // Per-keypoint arrays share one length (validated on load).
    w.len(k.keys.len());
    for kp in &k.keys {
        write_keypoint(w, kp);
    }
    w.len(k.keys_un.len());
    for kp in &k.keys_un {
        write_keypoint(w, kp);
    }
    w.len(k.descriptors.len());
    for d in &k.descriptors {
        w.bytes(d);
    }
    for arr in [&k.depth, &k.u_right, &k.weights] {
        w.len(arr.len());
        for v in arr.iter() {
            w.f32(*v);
        }
    }
    w.len(k.dynamic_class.len());
    for &b in &k.dynamic_class {
        w.bool(b);
    }
    w.len(k.map_points.len());
    for &m in &k.map_points {
        w.opt_index(m);
    }
    w.len(k.bow.len());
    for &(word, weight) in &k.bow {
        w.u32(word);
        w.f64(weight);
    }
    w.len(k.feat.len());
    for (node, idx) in &k.feat {
        w.u32(*node);
        w.len(idx.len());
        for &i in idx {
            w.u32(i);
        }
    }
    w.len(k.covisibility.len());
    for &(o, weight) in &k.covisibility {
        w.u32(o);
        w.u64(weight);
    }
    w.opt_index(k.parent);
    for list in [&k.children, &k.loop_edges] {
        w.len(list.len());
        for &i in list.iter() {
            w.u32(i);
        }
    }
}

fn write_point(w: &mut Writer, p: &MapPointSnapshot) {
    w.u64(p.seq);
    write_vec3(w, &p.position);
    write_vec3(w, &p.normal);
    w.f64(p.min_distance);
    w.f64(p.max_distance);
    w.bytes(&p.descriptor);
    w.len(p.observations.len());
    for &(k, i) in &p.observations {
        w.u32(k);
        w.u32(i);
    }
    w.u64(p.num_obs);
    w.opt_index(p.reference);
    w.u64(p.first_kf_seq);
    w.u32(p.visible);
    w.u32(p.found);
    w.f32(p.weight);
}

fn read_payload(r: &mut Reader<'_>) -> Result<SavedMap, PersistError> {
    let producer = r.str("producer")?;
    let (width, height) = (r.u32()?, r.u32()?);
    let (fx, fy, cx, cy) = (r.f64()?, r.f64()?, r.f64()?, r.f64()?);
    let mut dist = [0.0f64; 5];
    for d in dist.iter_mut() {
        *d = r.f64()?;
    }
    let (bf, th_depth, fps, max_depth, depth_factor) =
        (r.f64()?, r.f64()?, r.f64()?, r.f64()?, r.f64()?);
    let camera = RgbdCamera {
        pinhole: PinholeCamera {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            dist,
        },
        bf,
        th_depth,
        fps,
        max_depth,
    };
    let vocabulary = match r.u8()? {
        0 => None,
        1 => Some(VocabularyId {
            hash: r.u64()?,
            branching: r.u32()?,
            levels: r.u32()?,
            words: r.u32()?,
        }),
        t => return Err(PersistError::corrupt(format!("vocabulary tag {t}"))),
    };
    let pyramid_levels = r.u32()?;
    let scale_factor = r.f32()?;
    let next_kf_seq = r.u64()?;
    let next_mp_seq = r.u64()?;
    let origin = r.opt_index()?;
    // Minimum encoded sizes: a keyframe has at least its fixed fields and 14 length/index
    // words, a point its fixed fields.
    let keyframes = r.vec(24 + POSE_BYTES + 4 * 14, read_keyframe)?;
    let points = r.vec(8 + 48 + 16 + 32 + 4 + 8 + 4 + 8 + 12, read_point)?;
    Ok(SavedMap {
        producer,
        camera,
        depth_factor,
        vocabulary,
        map: MapSnapshot {
            pyramid_levels,
            scale_factor,
            next_kf_seq,
            next_mp_seq,
            origin,
            keyframes,
            points,
        },
    })
}

fn read_keyframe(r: &mut Reader<'_>) -> Result<KeyFrameSnapshot, PersistError> {
    let seq = r.u64()?;
    let frame_id = r.u64()?;
    let timestamp = r.f64()?;
    let pose = read_pose(r)?;
    let keys = r.vec(KEYPOINT_BYTES, read_keypoint)?;
    let keys_un = r.vec(KEYPOINT_BYTES, read_keypoint)?;
    let descriptors = r.vec(32, |r| r.descriptor())?;
    let depth = r.vec(4, |r| r.f32())?;
    let u_right = r.vec(4, |r| r.f32())?;
    let weights = r.vec(4, |r| r.f32())?;
    let dynamic_class = r.vec(1, |r| r.bool("dynamic flag"))?;
    let map_points = r.vec(4, |r| r.opt_index())?;
    let bow = r.vec(12, |r| Ok((r.u32()?, r.f64()?)))?;
    let feat = r.vec(8, |r| Ok((r.u32()?, r.vec(4, |r| r.u32())?)))?;
    let covisibility = r.vec(12, |r| Ok((r.u32()?, r.u64()?)))?;
    let parent = r.opt_index()?;
    let children = r.vec(4, |r| r.u32())?;
    let loop_edges = r.vec(4, |r| r.u32())?;
    Ok(KeyFrameSnapshot {
        seq,
        frame_id,
        timestamp,
        pose,
        keys,
        keys_un,
        descriptors,
        depth,
        u_right,
        weights,
        dynamic_class,
        map_points,
        bow,
        feat,
        covisibility,
        parent,
        children,
        loop_edges,
    })
}

fn read_point(r: &mut Reader<'_>) -> Result<MapPointSnapshot, PersistError> {
    Ok(MapPointSnapshot {
        seq: r.u64()?,
        position: read_vec3(r)?,
        normal: read_vec3(r)?,
        min_distance: r.f64()?,
        max_distance: r.f64()?,
        descriptor: r.descriptor()?,
        observations: r.vec(8, |r| Ok((r.u32()?, r.u32()?)))?,
        num_obs: r.u64()?,
        reference: r.opt_index()?,
        first_kf_seq: r.u64()?,
        visible: r.u32()?,
        found: r.u32()?,
        weight: r.f32()?,
    })
}
