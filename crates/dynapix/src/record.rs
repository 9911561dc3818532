//! The typed records of a run's outputs: `run.json` ([`RunRecord`], the provenance and
//! results of one `dynapix run`) and a map folder's `motion.json` ([`MotionRecord`], what made
//! the maps and the checksum of every map file). Both are written and read through these
//! types; their JSON keys are the ones the records always had (the schema is in
//! `docs/architecture.md`, "On-disk formats").
//!
//! The documents that key a cache (the `config` of a `motion.json`, the key document of a
//! first pass) stay [`serde_json::Value`]s: their hash names the cache folder, so they are
//! built exactly as before and compared as values.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use dynapix_io::FrameList;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::error::{Error, Result};
use crate::pass::{BadFrame, PassStats};

/// The record file of a map folder.
pub(crate) const MOTION_RECORD_FILE: &str = "motion.json";

/// `run.json`: what a run read (sequence, camera, configuration), how it ran (method, passes,
/// the maps' provenance) and what it gave (per-run results). Fields of one schedule only
/// (offline passes, the online schedule) are absent from the other's record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    /// The sequence as read.
    pub sequence: SequenceRecord,
    /// The method's name (`orbslam2`, `dynapix`, `dynapix+`).
    pub method: String,
    /// `paper` or `reference`.
    pub mode: String,
    /// `online` for an online run; absent offline.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub schedule: Option<String>,
    /// The cues of the motion maps (offline DynaPix runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cues: Option<String>,
    /// The kind of the first pass (offline DynaPix runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub first_pass_kind: Option<String>,
    /// The number of weighted passes (offline DynaPix runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weighted_passes: Option<usize>,
    /// The maps were made with ground-truth poses by configuration (offline runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub oracle_poses: Option<bool>,
    /// Whether ground truth made anything the run used (`null`: unknown, e.g. maps without a
    /// record).
    pub ground_truth_used_at_run_time: Option<bool>,
    /// Loop closing was on (offline runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loop_closing: Option<bool>,
    /// The DynaPix+ mask folder, when the method uses masks.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub masks: Option<PathBuf>,
    /// The SLAM weighting's parameters as the passes used them (offline runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dynapix: Option<WeightingRecord>,
    /// The whole resolved configuration ([`crate::Config`] as JSON).
    pub config: Value,
    /// What each output file of an online run holds.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub outputs: Option<BTreeMap<String, String>>,
    /// Where the first pass came from (cache, computed, given) and its counters.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub first_pass: Option<Value>,
    /// The provenance of the first weighted pass's maps.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prob: Option<Value>,
    /// The passes of the (first) run: their maps' provenance and counters.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub passes: Option<Vec<PassRecord>>,
    /// Why the run ended early: a pass (the first, or a weighted one whose poses the next
    /// needed) tracked no frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nothing_tracked: Option<String>,
    /// The depth read as missing because it was no measurement (saturated or out of range).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub invalid_depth: Option<dynapix_io::InvalidDepth>,
    /// Runs of the method (relocalisation seeds `seed`, `seed + 1`, …).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub runs: Option<usize>,
    /// The relocalisation seed of the first run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// The decoded-frame cache of an offline DynaPix run (`sequence.decoded_cache_mib`):
    /// budget, the most bytes it held at once (measured from its buffers) and what it held
    /// at the end of the passes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub decoded_cache: Option<Value>,
    /// The passes before the final one, evaluated (`passes/first`, `passes/pass_K`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub earlier_passes: Option<Vec<Value>>,
    /// The bad frames the (first) run skipped.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub skipped_frames: Option<Vec<BadFrame>>,
    /// One row per run: the pass counters, timings and, with ground truth, the evaluation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub results: Option<Vec<Value>>,
    /// `true` when the run finished, `false` when it stopped (absent while it runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub complete: Option<bool>,
    /// Why the run stopped.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The frame that stopped the run, when a frame did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub failed_frame: Option<BadFrame>,
}

impl RunRecord {
    /// The fields every run's record has (sequence, method, mode, configuration), nothing
    /// used from ground truth yet, every optional field absent.
    pub(crate) fn new(sequence: SequenceRecord, config: &crate::Config) -> Self {
        Self {
            sequence,
            method: config.method.name().to_string(),
            mode: config.mode.name().to_string(),
            schedule: None,
            cues: None,
            first_pass_kind: None,
            weighted_passes: None,
            oracle_poses: None,
            ground_truth_used_at_run_time: Some(false),
            loop_closing: None,
            masks: None,
            dynapix: None,
            config: config.to_json_value(),
            outputs: None,
            first_pass: None,
            prob: None,
            passes: None,
            nothing_tracked: None,
            invalid_depth: None,
            runs: None,
            seed: None,
            decoded_cache: None,
            earlier_passes: None,
            skipped_frames: None,
            results: None,
            complete: None,
            error: None,
            failed_frame: None,
        }
    }

    /// The record of the `run.json` at `path`.
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| dynapix_io::IoError::io(path, e))?;
        serde_json::from_str(&text).map_err(|e| Error::file(path, format!("not a run record: {e}")))
    }

    /// Writes the record to `path` atomically (pretty JSON).
    pub fn write(&self, path: impl AsRef<Path>) -> Result<()> {
        write_pretty(path.as_ref(), self)
    }

    /// Marks the record finished.
    pub fn mark_complete(&mut self) {
        self.complete = Some(true);
        self.error = None;
        self.failed_frame = None;
    }

    /// Marks the record stopped by `error` (at `failed_frame` when a frame stopped it).
    pub fn mark_incomplete(&mut self, error: String, failed_frame: Option<BadFrame>) {
        self.complete = Some(false);
        self.error = Some(error);
        self.failed_frame = failed_frame;
    }
}

/// `slam.json`: what one `dynapix slam` pass read (sequence, configuration, the map it loaded
/// or saves) and what it gave (the pass's counters, the skipped frames), and whether it
/// finished.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SlamRecord {
    /// The tool that wrote the record (`slam`).
    pub command: String,
    /// The method (`orbslam2`).
    pub method: String,
    /// The sequence as read.
    pub sequence: SequenceRecord,
    /// The map loaded for localisation (`null`: none).
    pub localize: Option<PathBuf>,
    /// Where the final map is saved (`null`: nowhere).
    pub save_map: Option<PathBuf>,
    /// The whole resolved configuration.
    pub config: Value,
    /// The pass's counters (also of a pass that stopped, up to where it stopped).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stats: Option<PassStats>,
    /// The bad frames skipped.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub skipped_frames: Option<Vec<BadFrame>>,
    /// `true` when the pass finished.
    pub complete: bool,
    /// What stopped an incomplete pass.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The frame that stopped it, when a frame did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub failed_frame: Option<BadFrame>,
}

impl SlamRecord {
    /// The record of a `slam` pass of `config` on `input` before it ran: no map loaded or
    /// saved, no results, not complete.
    pub fn new(input: &crate::Input, config: &crate::Config) -> Self {
        Self {
            command: "slam".into(),
            method: crate::Method::Orbslam2.name().into(),
            sequence: input.record(),
            localize: None,
            save_map: None,
            config: config.to_json_value(),
            stats: None,
            skipped_frames: None,
            complete: false,
            error: None,
            failed_frame: None,
        }
    }

    /// The record of the `slam.json` at `path`.
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| dynapix_io::IoError::io(path, e))?;
        serde_json::from_str(&text)
            .map_err(|e| Error::file(path, format!("not a slam record: {e}")))
    }

    /// Writes the record to `path` atomically (pretty JSON).
    pub fn write(&self, path: impl AsRef<Path>) -> Result<()> {
        write_pretty(path.as_ref(), self)
    }

    /// Records what `pass` gave (its counters and skipped frames); `complete` when it
    /// finished.
    pub fn set_pass(&mut self, pass: &crate::PassOutput, complete: bool) {
        self.stats = Some(pass.stats);
        self.skipped_frames = Some(pass.skipped.clone());
        self.complete = complete;
    }

    /// Marks the record stopped by `error` (at `failed_frame` when a frame stopped it).
    pub fn mark_incomplete(&mut self, error: String, failed_frame: Option<BadFrame>) {
        self.complete = false;
        self.error = Some(error);
        self.failed_frame = failed_frame;
    }
}

/// `pass.json` in a first-pass cache folder: the completion record of the cached
/// `trajectory.txt` (the key document, the pose count, the file's size and checksum).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct PassCacheRecord {
    /// The key document (its hash names the folder).
    pub config: Value,
    /// `complete` (the only state written).
    pub status: MapsStatus,
    /// The pass's counters.
    pub stats: PassStats,
    /// Poses in `trajectory.txt` (absent in records of older versions).
    #[serde(default)]
    pub poses: Option<u64>,
    /// Size and checksum of `trajectory.txt` (absent in records of older versions).
    #[serde(default)]
    pub trajectory: Option<FileFingerprint>,
}

impl PassCacheRecord {
    /// The record file in a first-pass cache folder.
    pub const FILE: &'static str = "pass.json";

    /// The record in `dir`, when there is one: `Err` says why it does not parse.
    pub fn read_in(dir: &Path) -> Option<std::result::Result<Self, String>> {
        let path = dir.join(Self::FILE);
        let text = std::fs::read_to_string(&path).ok()?;
        Some(serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display())))
    }

    /// Writes the record into `dir` atomically (compact JSON, as it always was).
    pub fn write_in(&self, dir: &Path) -> Result<()> {
        let path = dir.join(Self::FILE);
        let text = serde_json::to_string(self).map_err(|e| Error::file(&path, e.to_string()))?;
        dynapix_io::write_atomic(&path, text.as_bytes())?;
        Ok(())
    }
}

/// One pass of an offline run in [`RunRecord::passes`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PassRecord {
    /// The provenance of the pass's maps (`null` for an unweighted pass).
    pub maps: Option<Value>,
    /// The pass's counters.
    pub stats: PassStats,
}

/// The SLAM weighting of an offline run (`run.json` → `dynapix`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WeightingRecord {
    /// The weighting (`Debug` name).
    pub weighting: String,
    /// γ_add (the parameter's `f32` value, widened).
    pub gamma_add: f64,
    /// γ_del (the parameter's `f32` value, widened).
    pub gamma_del: f64,
    /// The map-point probability update rule (`Debug` name).
    pub update: String,
    /// The clamp of the bundle-adjustment weights, when the weighting has one.
    pub ba_weight_clamp: Option<(f64, f64)>,
    /// The threshold of a thresholding method (γ_add, widened), else `null`.
    pub threshold: Option<f64>,
}

/// The sequence as a run read it (`run.json` → `sequence`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SequenceRecord {
    /// The folder.
    pub dir: PathBuf,
    /// Number of frames.
    pub frames: usize,
    /// Where the frame list came from.
    pub frame_list: FrameList,
    /// A hash of the frame list (times and paths).
    pub frames_hash: String,
    /// Time of the first frame (s).
    pub first_t: Option<f64>,
    /// Time of the last frame (s).
    pub last_t: Option<f64>,
    /// Depth units per metre.
    pub depth_factor: f64,
    /// The folder has a `groundtruth.txt`.
    pub groundtruth: bool,
    /// How the ground truth was read (`null` without one).
    pub groundtruth_convention: Option<GroundTruthRecord>,
    /// The camera.
    pub camera: CameraRecord,
    /// Which depth values were read as measurements (absent in records written before the
    /// rule was per camera).
    #[serde(default)]
    pub depth_validity: Option<DepthValidityRecord>,
}

/// The depth-validity rule of a run and where each limit came from
/// (`run.json` → `sequence.depth_validity`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DepthValidityRecord {
    /// The raw value read as missing (the sensor's saturation value; `null`: none).
    pub saturation: Option<u16>,
    /// Depths beyond this many metres were read as missing.
    pub max_depth_m: f32,
    /// Where `saturation` came from: `config` (`sequence.depth_saturation`), `camera` (the
    /// camera's settings file, key `depth_saturation`) or `default`.
    pub saturation_from: String,
    /// Where `max_depth_m` came from: `config` (`sequence.max_depth`), `camera` (key
    /// `depth_max_m`) or `default`.
    pub max_depth_from: String,
}

impl DepthValidityRecord {
    /// The rule of a run whose configuration states `config` and whose camera states
    /// `camera` (the configuration wins key by key, the defaults fill the rest).
    pub fn resolve(config: dynapix_io::DepthLimits, camera: dynapix_io::DepthLimits) -> Self {
        let v = config.or(camera).validity();
        let from = |c: bool, k: bool| {
            match (c, k) {
                (true, _) => "config",
                (false, true) => "camera",
                _ => "default",
            }
            .to_string()
        };
        Self {
            saturation: v.saturation,
            max_depth_m: v.max_depth,
            saturation_from: from(config.saturation.is_some(), camera.saturation.is_some()),
            max_depth_from: from(config.max_depth.is_some(), camera.max_depth.is_some()),
        }
    }

    /// The rule itself.
    pub fn validity(&self) -> dynapix_io::DepthValidity {
        dynapix_io::DepthValidity {
            saturation: self.saturation,
            max_depth: self.max_depth_m,
        }
    }
}

/// How a sequence's `groundtruth.txt` was read.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GroundTruthRecord {
    /// The file.
    pub file: PathBuf,
    /// What the file holds.
    pub file_holds: String,
    /// How it was used.
    pub used_as: String,
    /// The rule that chose the convention.
    pub rule: String,
}

/// The camera of a run as recorded (also part of the first pass's cache key).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraRecord {
    /// Where the settings came from.
    pub source: CameraSource,
    /// Intrinsics and distortion.
    pub pinhole: dynapix_geometry::PinholeCamera,
    /// Baseline times fx.
    pub bf: f64,
    /// Close/far depth threshold (baselines).
    pub th_depth: f64,
    /// Frame rate.
    pub fps: f64,
    /// Depth units per metre.
    pub depth_map_factor: f64,
    /// The ORB extractor settings.
    pub orb: OrbRecord,
    /// The image size was taken from the first frame.
    pub size_from_frames: bool,
}

/// Where the camera of a run came from (recorded in outputs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "source", rename_all = "snake_case")]
pub enum CameraSource {
    /// A settings file given by the caller.
    SettingsFile {
        /// The file.
        path: PathBuf,
        /// Keys that took the TUM values.
        missing_keys: Vec<String>,
    },
    /// A preset given by the caller.
    Preset {
        /// Its name.
        name: String,
    },
    /// The sequence folder's `camera.yaml`.
    SequenceFile {
        /// The file.
        path: PathBuf,
        /// Keys that took the TUM values.
        missing_keys: Vec<String>,
    },
    /// The preset implied by the folder name or layout.
    FolderName {
        /// The preset's name.
        preset: String,
    },
}

/// The ORB extractor settings of a camera record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OrbRecord {
    /// Features per image.
    pub n_features: usize,
    /// Scale between pyramid levels.
    pub scale_factor: f64,
    /// Pyramid levels.
    pub n_levels: usize,
    /// Initial FAST threshold.
    pub ini_th_fast: u32,
    /// Fallback FAST threshold.
    pub min_th_fast: u32,
}

/// `motion.json`: the record of a folder of motion (or rigidity) maps.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MotionRecord {
    /// The sequence folder the maps belong to.
    pub sequence: PathBuf,
    /// Everything that determines the maps (its hash keys the cache folder).
    pub config: Value,
    /// Whether every map has been written.
    pub status: MapsStatus,
    /// What the computation reported (frames, seconds, threads, …; `null` while running).
    pub results: Value,
    /// Size and checksum of every map file, by file name (a complete record).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub files: Option<BTreeMap<String, FileFingerprint>>,
}

impl MotionRecord {
    /// The record file of a map folder (`motion.json`).
    pub const FILE: &'static str = MOTION_RECORD_FILE;

    /// Whether the record's `config` is `config` (compared after the same JSON text round
    /// trip the record went through: the parser may read a number one unit in the last place
    /// away from the value that was written).
    pub fn describes(&self, config: &Value) -> bool {
        self.config == as_read_back(config)
    }

    /// The record in the map folder `dir`, when it has one.
    pub fn read_in(dir: &Path) -> Option<Result<Self>> {
        let path = dir.join(MOTION_RECORD_FILE);
        let text = std::fs::read_to_string(&path).ok()?;
        Some(
            serde_json::from_str(&text)
                .map_err(|e| Error::file(&path, format!("not a motion record: {e}"))),
        )
    }

    /// Writes the record into the map folder `dir` atomically (pretty JSON).
    pub fn write_in(&self, dir: &Path) -> Result<()> {
        write_pretty(&dir.join(MOTION_RECORD_FILE), self)
    }

    /// Whether the record says its maps were made with ground-truth poses (`None` when it
    /// does not say).
    pub fn uses_ground_truth(&self) -> Option<bool> {
        let poses = self.config.get("poses")?;
        if let Some(src) = poses.pointer("/origin/source").and_then(Value::as_str) {
            return Some(src == "ground_truth");
        }
        // Records written before provenance was structured: `"source": "gt" | "file"`.
        match poses.get("source").and_then(Value::as_str)? {
            "gt" => Some(true),
            "file" => Some(false),
            _ => None,
        }
    }
}

/// The state of a map folder's computation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MapsStatus {
    /// Being computed (or interrupted).
    Running,
    /// Every map written and listed in `files`.
    Complete,
}

/// Size and FNV-64 checksum of a file, as cache records list them.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileFingerprint {
    /// Size in bytes.
    pub bytes: usize,
    /// FNV-64 of the bytes (16 hex digits).
    pub fnv64: String,
}

impl FileFingerprint {
    /// The fingerprint of `bytes`.
    pub fn of(bytes: &[u8]) -> Self {
        Self {
            bytes: bytes.len(),
            fnv64: crate::hash::Fnv64::of(bytes),
        }
    }
}

/// `v` as it reads back from its JSON text: the JSON parser may read a number one unit in
/// the last place away from the value that was written, so a record read from a file is
/// compared with the expected record after the same round trip.
pub(crate) fn as_read_back(v: &Value) -> Value {
    serde_json::from_str(&v.to_string()).unwrap_or(Value::Null)
}

/// Writes `value` as pretty JSON to `path` atomically.
fn write_pretty(path: &Path, value: &impl Serialize) -> Result<()> {
    let text = serde_json::to_string_pretty(value).map_err(|e| Error::file(path, e.to_string()))?;
    dynapix_io::write_atomic(path, text.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_pass_record_round_trips_and_reads_older_records() {
        let dir = tempfile::tempdir().unwrap();
        let rec = PassCacheRecord {
            config: serde_json::json!({"kind": "orbslam2", "frames": 30, "slam_pass_version": 2}),
            status: MapsStatus::Complete,
            stats: PassStats {
                frames: 30,
                tracked: 29,
                keyframes: 4,
                map_points: 812,
                loops_closed: 0,
                seconds: 1.5,
                frames_without_prob_map: 0,
                frames_skipped: 1,
            },
            poses: Some(29),
            trajectory: Some(FileFingerprint::of(b"1.0 0 0 0 0 0 0 1\n")),
        };
        rec.write_in(dir.path()).unwrap();
        let text = std::fs::read_to_string(dir.path().join(PassCacheRecord::FILE)).unwrap();
        let v: Value = serde_json::from_str(&text).unwrap();
        for key in ["config", "status", "stats", "poses", "trajectory"] {
            assert!(v.get(key).is_some(), "{key} missing in {text}");
        }
        assert_eq!(v["status"], "complete");
        let back = PassCacheRecord::read_in(dir.path()).unwrap().unwrap();
        assert_eq!(back, rec);
        // A record of an older version, without pose count and checksum, still parses (and
        // is then refused by its reader); a damaged one says why.
        std::fs::write(
            dir.path().join(PassCacheRecord::FILE),
            serde_json::json!({"config": rec.config, "status": "complete", "stats": rec.stats})
                .to_string(),
        )
        .unwrap();
        let old = PassCacheRecord::read_in(dir.path()).unwrap().unwrap();
        assert_eq!((old.poses, old.trajectory), (None, None));
        std::fs::write(dir.path().join(PassCacheRecord::FILE), "{").unwrap();
        assert!(PassCacheRecord::read_in(dir.path()).unwrap().is_err());
        assert!(PassCacheRecord::read_in(&dir.path().join("none")).is_none());
    }
}
