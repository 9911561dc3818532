//! Where the maps of a pass live: in a folder (a cache hit, a sequence's own `prob/`, or
//! computed by this run and written to its cache as they come), or, for a run without a
//! cache, in a temporary file the run owns ([`SpilledMaps`], their stored 16-bit form). None
//! is kept in memory: a pass reads each frame's map when it reaches the frame, so the memory
//! of a run does not grow with the number of frames.
//!
//! A folder holds one 16-bit PNG per frame, named like the rgb image (`trunc((1 − P)·1000)`,
//! the reference format), and `motion.json`: `{"sequence", "config", "status", "results"}`.
//! Spilled maps hold the same 16-bit values, so a pass reads the same weights from a fresh
//! run, a cached run and a run without any folder.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use dynapix_io::weights::read_prob_png_raw;
use dynapix_io::weights::write_motion_probability;
use dynapix_io::{Gray16Image, MotionProbability, StaticWeights};
use rayon::prelude::*;
use serde_json::{Value, json};

use crate::error::{Error, Result};
use crate::hash::Fnv64;
use crate::input::Input;
use crate::record::{FileFingerprint, MapsStatus, MotionRecord};
use crate::spill::SpilledMaps;

/// The record file of a map folder.
pub const RECORD_FILE: &str = crate::record::MOTION_RECORD_FILE;

/// A folder of motion maps with its `motion.json`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MapFolder {
    /// The folder.
    pub dir: PathBuf,
}

impl MapFolder {
    /// The folder `dir`.
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }

    /// The map file of frame `i` of `input` (`<rgb name>.png`).
    pub fn map_path(&self, input: &Input, i: usize) -> Option<PathBuf> {
        Some(self.dir.join(input.map_name(i)?))
    }

    /// The motion probability stored in the map file `path` (P = 1 − stored/1000).
    pub fn read_probability(path: &Path) -> Result<MotionProbability> {
        Ok(dynapix_io::weights::read_motion_probability(path)?)
    }

    /// The record, when the folder has one.
    pub fn read_record(&self) -> Option<Result<MotionRecord>> {
        MotionRecord::read_in(&self.dir)
    }

    /// Writes the record atomically; a `complete` one lists every map file with its size and
    /// checksum ([`MapFolder::file_checksums`]).
    pub fn write_record(
        &self,
        input: &Input,
        config: &Value,
        status: MapsStatus,
        results: Value,
    ) -> Result<()> {
        std::fs::create_dir_all(&self.dir).map_err(|e| dynapix_io::IoError::io(&self.dir, e))?;
        let files = match status {
            MapsStatus::Complete => Some(self.file_checksums(input)?),
            MapsStatus::Running => None,
        };
        MotionRecord {
            sequence: input.sequence.dir.clone(),
            config: config.clone(),
            status,
            results,
            files,
        }
        .write_in(&self.dir)
    }

    /// The cache folder `<root>/<prefix>-<key>` of the maps that `config` (their record's
    /// `config` document) describes, its key, and whether it already holds them complete.
    pub fn in_cache(
        root: &Path,
        prefix: &str,
        input: &Input,
        config: &Value,
    ) -> (Self, String, bool) {
        let key = Fnv64::of(config.to_string().as_bytes());
        let folder = Self::new(root.join(format!("{prefix}-{key}")));
        let reused = match folder.check_cache(input, config) {
            CacheCheck::Valid => true,
            CacheCheck::Absent => false,
            CacheCheck::Damaged(why) => {
                tracing::warn!(
                    "the cached maps in {} are damaged ({why}); recomputing them",
                    folder.dir.display()
                );
                false
            }
        };
        (folder, key, reused)
    }

    /// True when the record says `config`, the run completed, and every frame's map is the
    /// file that was recorded ([`MapFolder::check_cache`]).
    pub fn is_complete(&self, input: &Input, config: &Value) -> bool {
        self.check_cache(input, config) == CacheCheck::Valid
    }

    /// Size and FNV-64 checksum of every frame's map file (bad frames of a run that skips
    /// them have none), by file name: `{"<name>.png": {"bytes": n, "fnv64": "…"}}`.
    pub fn file_checksums(&self, input: &Input) -> Result<BTreeMap<String, FileFingerprint>> {
        let files = (0..input.len())
            .into_par_iter()
            .filter(|&i| !input.is_bad(i))
            .map(|i| {
                let path = self
                    .map_path(input, i)
                    .ok_or_else(|| Error::Input(format!("frame {i} has no file name")))?;
                let bytes = std::fs::read(&path).map_err(|e| dynapix_io::IoError::io(&path, e))?;
                let name = path
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                Ok((name, FileFingerprint::of(&bytes)))
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(files.into_iter().collect())
    }

    /// Whether this folder holds the complete maps of `config`: its record says `config` and
    /// `complete`, and every frame's map has the size and checksum the record lists.
    pub fn check_cache(&self, input: &Input, config: &Value) -> CacheCheck {
        let rec = match self.read_record() {
            None => return CacheCheck::Absent,
            Some(Err(e)) => return CacheCheck::Damaged(e.to_string()),
            Some(Ok(rec)) => rec,
        };
        if !rec.describes(config) {
            return CacheCheck::Damaged(format!(
                "{} describes other maps than its key",
                self.dir.join(RECORD_FILE).display()
            ));
        }
        if rec.status != MapsStatus::Complete {
            // An interrupted computation: not damage, just unfinished.
            return CacheCheck::Absent;
        }
        let Some(files) = &rec.files else {
            return CacheCheck::Damaged(format!(
                "{} lists no checksums (written by an older version)",
                self.dir.join(RECORD_FILE).display()
            ));
        };
        let problem = (0..input.len())
            .into_par_iter()
            .filter(|&i| !input.is_bad(i))
            .filter_map(|i| {
                let path = self.map_path(input, i)?;
                let name = path.file_name()?.to_string_lossy().into_owned();
                let Some(expected) = files.get(&name) else {
                    return Some((i, format!("{}: not in the record", path.display())));
                };
                match std::fs::read(&path) {
                    Err(e) => Some((i, format!("{}: {e}", path.display()))),
                    Ok(bytes) if &FileFingerprint::of(&bytes) != expected => Some((
                        i,
                        format!(
                            "{}: {} bytes, not the {} bytes with the checksum the record lists",
                            path.display(),
                            bytes.len(),
                            expected.bytes
                        ),
                    )),
                    Ok(_) => None,
                }
            })
            .min_by_key(|(i, _)| *i);
        match problem {
            Some((_, why)) => CacheCheck::Damaged(why),
            None => CacheCheck::Valid,
        }
    }

    /// Writes the map of one frame atomically.
    pub fn write_map(&self, input: &Input, i: usize, p: &MotionProbability) -> Result<()> {
        let path = self
            .map_path(input, i)
            .ok_or_else(|| Error::Input(format!("frame {i} has no file name")))?;
        let _stage = tracing::info_span!(target: "dynapix::stage", "write maps").entered();
        write_motion_probability(path, p)?;
        Ok(())
    }

    /// The stored form of frame `i`'s map, `None` when its file does not exist.
    pub fn read_map(&self, input: &Input, i: usize) -> Result<Option<Gray16Image>> {
        let path = self
            .map_path(input, i)
            .ok_or_else(|| Error::Input(format!("frame {i} has no file name")))?;
        if !path.exists() {
            return Ok(None);
        }
        read_map_file(&path).map(Some)
    }
}

/// Reads one map file of a folder (its stored 16-bit values).
fn read_map_file(path: &Path) -> Result<Gray16Image> {
    let _stage = tracing::info_span!(target: "dynapix::stage", "read maps").entered();
    Ok(read_prob_png_raw(path)?)
}

/// What [`MapFolder::check_cache`] found.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum CacheCheck {
    /// No maps of this job yet (no record, or an interrupted computation).
    Absent,
    /// The record and every map file match: the folder can be used as it is.
    Valid,
    /// A complete record whose files (or the record itself) do not match; why.
    Damaged(String),
}

/// The stored 16-bit form of `p` (the quantisation of the map files); a NaN probability is
/// refused like the file writer refuses it, so a run with and without a cache fail alike.
pub fn stored_map(p: &MotionProbability, i: usize) -> Result<Gray16Image> {
    if p.as_image().as_raw().iter().any(|v| v.is_nan()) {
        return Err(Error::Input(format!(
            "motion map of frame {i} has a NaN probability"
        )));
    }
    Ok(p.to_stored())
}

/// Where the maps of a pass came from, what made them, and where they are.
#[derive(Clone, Debug, PartialEq)]
pub struct MapSet {
    /// The folder of the maps, when they are on disk.
    pub(crate) folder: Option<MapFolder>,
    /// The maps in a temporary file, when this run computed them without a cache folder
    /// (`None` too once the run released them, see [`MapSet::release`]).
    pub(crate) spilled: Option<SpilledMaps>,
    /// Provenance (written into `run.json`).
    pub record: Value,
    /// Whether ground-truth poses made the maps (`None`: unknown, e.g. external maps without
    /// a record).
    pub ground_truth: Option<bool>,
}

impl MapSet {
    /// The maps of a folder made elsewhere (a sequence's own `prob/`): provenance from its
    /// `motion.json` when it has one.
    pub fn existing(folder: MapFolder, source: &str) -> Result<Self> {
        let mut record = json!({"source": source, "dir": folder.dir});
        let ground_truth = match folder.read_record() {
            None => {
                record["provenance"] = json!("unknown: no motion.json beside the maps");
                None
            }
            Some(Err(e)) => return Err(e),
            Some(Ok(rec)) => {
                let gt = rec.uses_ground_truth();
                record["poses"] = json!(match gt {
                    Some(true) => "ground truth",
                    Some(false) => "not ground truth",
                    None => "unknown",
                });
                record["motion_json"] = serde_json::to_value(&rec)
                    .map_err(|e| Error::file(folder.dir.join(RECORD_FILE), e.to_string()))?;
                gt
            }
        };
        Ok(Self {
            folder: Some(folder),
            spilled: None,
            record,
            ground_truth,
        })
    }

    /// The folder of the maps, when they are on disk.
    pub fn dir(&self) -> Option<&Path> {
        self.folder.as_ref().map(|f| f.dir.as_path())
    }

    /// The file of frame `i`'s map in the folder, when the maps are in a folder.
    pub fn map_path(&self, input: &Input, i: usize) -> Option<PathBuf> {
        self.folder.as_ref()?.map_path(input, i)
    }

    /// Bytes of the temporary file that holds the maps of a run without a cache folder (0
    /// when the maps are in a folder, or once released, [`MapSet::release`]).
    pub fn bytes_on_disk(&self) -> u64 {
        self.spilled.as_ref().map_or(0, SpilledMaps::bytes_on_disk)
    }

    /// The stored 16-bit map of frame `i` of `input`: from the temporary file when this run
    /// computed it without a cache, else from the folder; `None` when the set has no map for
    /// the frame (or no longer has its maps, [`MapSet::release`]).
    pub fn stored(&self, input: &Input, i: usize) -> Result<Option<Gray16Image>> {
        if let Some(m) = &self.spilled {
            return m.get(i);
        }
        match &self.folder {
            Some(f) => f.read_map(input, i),
            None => Ok(None),
        }
    }

    /// Drops this handle on the maps of a run without a cache (their temporary file is
    /// removed when no other handle holds it); the record stays. An offline run releases the
    /// maps of each weighted pass once the next one has its own.
    pub fn release(&mut self) {
        self.spilled = None;
    }

    /// Bytes the maps of this set hold in memory (not on disk): O(1) per frame.
    pub fn bytes_in_memory(&self) -> usize {
        self.spilled
            .as_ref()
            .map_or(0, SpilledMaps::bytes_in_memory)
    }

    /// The static weights of frame `i` (w = stored/1000), `None` when the set has none.
    pub fn static_weights(&self, input: &Input, i: usize) -> Result<Option<StaticWeights>> {
        Ok(self
            .stored(input, i)?
            .map(|s| StaticWeights::from_stored(&s)))
    }

    /// The motion probability of frame `i` (P = 1 − stored/1000), or an error naming the
    /// frame when the set has none.
    pub fn probability(&self, input: &Input, i: usize) -> Result<MotionProbability> {
        match self.stored(input, i)? {
            Some(s) => Ok(MotionProbability::from_stored(&s)),
            None => Err(self.missing(input, i)),
        }
    }

    /// The error of a frame without a map.
    pub(crate) fn missing(&self, input: &Input, i: usize) -> Error {
        match self.folder.as_ref().and_then(|f| f.map_path(input, i)) {
            Some(p) => Error::file(p, "no such map (motion map missing)"),
            None => Error::Input(format!("frame {i} has no motion map")),
        }
    }
}

/// Collects the maps of a computation frame by frame (from any thread): into a folder when
/// one is given (the cache, written as they come), else into a temporary file.
pub(crate) struct MapSink<'a> {
    input: &'a Input,
    folder: Option<&'a MapFolder>,
    spill: Option<SpilledMaps>,
}

impl<'a> MapSink<'a> {
    /// A sink for the frames of `input`, writing into `folder` when given, else into a new
    /// temporary file.
    pub(crate) fn new(input: &'a Input, folder: Option<&'a MapFolder>) -> Result<Self> {
        let spill = match folder {
            Some(_) => None,
            None => {
                let s = &input.camera.settings;
                Some(SpilledMaps::new(input.len(), s.width, s.height)?)
            }
        };
        Ok(Self {
            input,
            folder,
            spill,
        })
    }

    /// Keeps the map of frame `i`: writes it to the folder or the temporary file.
    pub(crate) fn put(&self, i: usize, p: &MotionProbability) -> Result<()> {
        if let Some(f) = self.folder {
            return f.write_map(self.input, i, p);
        }
        let stored = stored_map(p, i)?;
        match &self.spill {
            Some(s) => s.put(i, &stored),
            None => Err(Error::Input(format!(
                "motion maps: nowhere to keep frame {i}"
            ))),
        }
    }

    /// The temporary file of the maps (`None` when they went to a folder).
    pub(crate) fn finish(self) -> Option<SpilledMaps> {
        self.spill
    }
}
