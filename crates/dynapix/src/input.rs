//! A sequence folder opened for a run: the frames of the one reader
//! ([`dynapix_io::Sequence`], one association policy) and the camera, resolved in one order
//! for every command: an explicit settings file, else a preset, else the folder's
//! `camera.yaml`, else the preset of the folder's dataset (`rgbd_dataset_freiburgN_*`,
//! `rgbd_bonn_*`) or the GRADE layout, else an error that says how to give it (design §6).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use dynapix_io::settings::SEQUENCE_SETTINGS_FILE;
use dynapix_io::{Sequence, SequenceOptions, Settings};
use dynapix_slam::RgbdCamera;
use dynapix_slam::orb::{FastCorners, OrbParams};
use image::RgbImage;
use serde::Serialize;

use crate::config::SequenceConfig;
use crate::error::{BadFrame, Error, Result};
use crate::hash::Fnv64;

/// Camera presets (ORB-SLAM2 settings files).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum CameraPreset {
    /// TUM fr1 (`TUM1.yaml`, distorted).
    Tum1,
    /// TUM fr2 (`TUM2.yaml`, distorted, depth factor 5208).
    Tum2,
    /// TUM fr3 (`TUM3.yaml`).
    Tum3,
    /// GRADE (`GRADE.yaml`, depth in mm, 3000 features).
    Grade,
    /// Bonn RGB-D Dynamic (the dataset's Kinect calibration, distorted).
    Bonn,
}

impl CameraPreset {
    /// Every preset.
    pub const ALL: [CameraPreset; 5] = [
        CameraPreset::Tum1,
        CameraPreset::Tum2,
        CameraPreset::Tum3,
        CameraPreset::Grade,
        CameraPreset::Bonn,
    ];

    /// The preset's name.
    pub fn name(self) -> &'static str {
        match self {
            CameraPreset::Tum1 => "tum1",
            CameraPreset::Tum2 => "tum2",
            CameraPreset::Tum3 => "tum3",
            CameraPreset::Grade => "grade",
            CameraPreset::Bonn => "bonn",
        }
    }

    /// The settings of the preset.
    pub fn settings(self) -> Settings {
        match self {
            CameraPreset::Tum1 => Settings::tum1(),
            CameraPreset::Tum2 => Settings::tum2(),
            CameraPreset::Tum3 => Settings::tum3(),
            CameraPreset::Grade => Settings::grade(),
            CameraPreset::Bonn => Settings::bonn(),
        }
    }
}

/// How the camera of a run is chosen.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum CameraChoice {
    /// From the sequence folder (`camera.yaml`, folder name, GRADE layout).
    #[default]
    Sequence,
    /// A preset.
    Preset(CameraPreset),
    /// An ORB-SLAM2 settings file (missing keys take the TUM values).
    Settings(PathBuf),
}

/// Where the camera of a run came from (recorded in outputs).
#[derive(Clone, Debug, PartialEq, Serialize)]
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

/// The camera of a run.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    /// The settings (intrinsics, distortion, depth factor, ORB parameters).
    pub settings: Settings,
    /// Where they came from.
    pub source: CameraSource,
    /// The settings stated no image size and the first frame's size was used.
    pub size_from_frames: bool,
}

impl Camera {
    /// The SLAM camera (intrinsics, distortion, `bf`, `ThDepth`, fps).
    pub fn rgbd(&self) -> RgbdCamera {
        let s = &self.settings;
        RgbdCamera::new(s.camera(), s.bf, s.th_depth, s.fps)
    }

    /// The pinhole camera of the motion maps.
    pub fn pinhole(&self) -> dynapix_geometry::PinholeCamera {
        self.settings.camera()
    }

    /// The ORB extractor parameters of the settings.
    pub fn orb_params(&self) -> Result<OrbParams> {
        let o = &self.settings.orb;
        let fast = |v: u32, key: &str| {
            u8::try_from(v)
                .map_err(|_| Error::Input(format!("ORBextractor.{key} {v} does not fit 0..=255")))
        };
        Ok(OrbParams {
            nfeatures: o.n_features,
            scale_factor: o.scale_factor as f32,
            nlevels: o.n_levels,
            ini_th_fast: fast(o.ini_th_fast, "iniThFAST")?,
            min_th_fast: fast(o.min_th_fast, "minThFAST")?,
        })
    }

    /// What outputs record about the camera.
    pub fn record(&self) -> serde_json::Value {
        let s = &self.settings;
        serde_json::json!({
            "source": self.source,
            "pinhole": s.camera(),
            "bf": s.bf,
            "th_depth": s.th_depth,
            "fps": s.fps,
            "depth_map_factor": s.depth_map_factor,
            "orb": {
                "n_features": s.orb.n_features,
                "scale_factor": s.orb.scale_factor,
                "n_levels": s.orb.n_levels,
                "ini_th_fast": s.orb.ini_th_fast,
                "min_th_fast": s.orb.min_th_fast,
            },
            "size_from_frames": self.size_from_frames,
        })
    }
}

/// A sequence opened for a run.
#[derive(Clone, Debug)]
pub struct Input {
    /// The frames (the one reader).
    pub sequence: Sequence,
    /// The camera.
    pub camera: Camera,
    /// Frames whose files cannot be used are skipped instead of stopping the run
    /// ([`SequenceConfig::skip_bad_frames`]).
    pub skip_bad_frames: bool,
    /// The bad frames, found on first use when skipping.
    bad: OnceLock<Vec<BadFrame>>,
    /// Decoded frames kept between passes ([`SequenceConfig::decoded_cache_mib`]); clones of
    /// an input share it.
    decoded: DecodedFrames,
}

/// One decoded frame: colour image and depth (metres).
type DecodedFrame = Arc<(RgbImage, dynapix_io::DepthImage)>;

/// Decoded frames kept in memory up to a byte budget, first read first kept.
#[derive(Clone)]
struct DecodedFrames {
    budget: usize,
    /// Off until a multi-pass run asks for it ([`Input::keep_decoded_frames`]).
    enabled: Arc<std::sync::atomic::AtomicBool>,
    /// Bytes used and the frames kept, by index.
    kept: Arc<Mutex<(usize, HashMap<usize, DecodedFrame>)>>,
    /// The FAST corners of the frames' grey images, by index (kept while `enabled`, a few
    /// tens of kilobytes per frame counted in the budget).
    corners: Arc<Mutex<HashMap<usize, Arc<FastCorners>>>>,
    /// The most bytes kept at once since the input was opened.
    peak: Arc<std::sync::atomic::AtomicUsize>,
}

impl std::fmt::Debug for DecodedFrames {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (used, n) = self.kept.lock().map(|k| (k.0, k.1.len())).unwrap_or((0, 0));
        write!(
            f,
            "DecodedFrames {{ budget: {}, used: {used}, frames: {n} }}",
            self.budget
        )
    }
}

impl DecodedFrames {
    fn new(budget_mib: usize) -> Self {
        Self {
            budget: budget_mib.saturating_mul(1 << 20),
            enabled: Arc::new(std::sync::atomic::AtomicBool::new(false)),
            kept: Arc::new(Mutex::new((0, HashMap::new()))),
            corners: Arc::new(Mutex::new(HashMap::new())),
            peak: Arc::new(std::sync::atomic::AtomicUsize::new(0)),
        }
    }

    /// Takes `bytes` of the budget when they fit (the lock on the kept frames held).
    fn charge(&self, used: &mut usize, bytes: usize) -> bool {
        if *used + bytes > self.budget {
            return false;
        }
        *used += bytes;
        self.peak
            .fetch_max(*used, std::sync::atomic::Ordering::Relaxed);
        true
    }

    fn get(&self, i: usize) -> Option<DecodedFrame> {
        self.kept.lock().ok()?.1.get(&i).cloned()
    }

    /// Keeps frame `i` when it fits the budget.
    fn offer(&self, i: usize, rgb: &RgbImage, depth: &dynapix_io::DepthImage) {
        if !self.enabled.load(std::sync::atomic::Ordering::Relaxed) {
            return;
        }
        let bytes = rgb.as_raw().len() + std::mem::size_of_val(depth.as_raw().as_slice());
        let Ok(mut k) = self.kept.lock() else { return };
        if k.1.contains_key(&i) || !self.charge(&mut k.0, bytes) {
            return;
        }
        k.1.insert(i, Arc::new((rgb.clone(), depth.clone())));
    }
}

/// Reads a settings file leniently (missing keys take the TUM values).
fn read_settings(path: &Path) -> Result<(Settings, Vec<String>)> {
    let (s, missing) = Settings::read_lenient(path)?;
    if !missing.is_empty() {
        // Not silent: a wrong DepthMapFactor scales every depth.
        tracing::warn!(
            "{}: missing keys take the TUM values: {}",
            path.display(),
            missing.join(", ")
        );
    }
    Ok((s, missing.iter().map(|k| k.to_string()).collect()))
}

fn size_missing(missing: &[String]) -> bool {
    missing
        .iter()
        .any(|k| k == "Camera.width" || k == "Camera.height")
}

impl Input {
    /// Opens the sequence folder `dir` with the sequence options of `config` and resolves the
    /// camera. The depth factor of the frames is the camera's `DepthMapFactor`.
    pub fn open(
        dir: impl AsRef<Path>,
        config: &SequenceConfig,
        camera: &CameraChoice,
    ) -> Result<Self> {
        Self::open_with(dir, config, camera, None)
    }

    /// [`Input::open`] with an explicit association file (4 columns) instead of the folder's
    /// own frame list.
    pub fn open_with(
        dir: impl AsRef<Path>,
        config: &SequenceConfig,
        camera: &CameraChoice,
        association: Option<&Path>,
    ) -> Result<Self> {
        let dir = dir.as_ref();
        let opts = SequenceOptions {
            max_diff: config.max_diff,
            pairing: config.pairing,
            association_file: association.map(Path::to_path_buf),
            depth_validity: config.depth_validity(),
            ..Default::default()
        };
        let mut sequence = Sequence::open_with(dir, &opts)?;
        if let Some(n) = config.max_frames {
            sequence.truncate(n);
        }
        let (mut settings, source) = match camera {
            CameraChoice::Settings(p) => {
                let (s, missing_keys) = read_settings(p)?;
                let src = CameraSource::SettingsFile {
                    path: p.clone(),
                    missing_keys,
                };
                (s, src)
            }
            CameraChoice::Preset(p) => (
                p.settings(),
                CameraSource::Preset {
                    name: p.name().to_string(),
                },
            ),
            CameraChoice::Sequence => {
                let own = dir.join(SEQUENCE_SETTINGS_FILE);
                match &sequence.settings {
                    Some(s) if own.is_file() => (
                        s.clone(),
                        CameraSource::SequenceFile {
                            path: own,
                            missing_keys: sequence
                                .settings_missing_keys
                                .iter()
                                .map(|k| k.to_string())
                                .collect(),
                        },
                    ),
                    Some(s) => {
                        let preset = dynapix_io::settings::PRESET_NAMES
                            .iter()
                            .find(|n| Settings::preset(n).as_ref() == Some(s))
                            .map_or("unknown", |n| n)
                            .to_string();
                        (s.clone(), CameraSource::FolderName { preset })
                    }
                    None => {
                        return Err(Error::Input(format!(
                            "cannot tell the camera of {}: give --camera PRESET or --settings \
                             FILE (or add {SEQUENCE_SETTINGS_FILE})",
                            dir.display()
                        )));
                    }
                }
            }
        };
        let missing = match &source {
            CameraSource::SettingsFile { missing_keys, .. }
            | CameraSource::SequenceFile { missing_keys, .. } => missing_keys.clone(),
            _ => Vec::new(),
        };
        let size_from_frames = size_missing(&missing);
        if size_from_frames {
            let first = &sequence.info(0)?.rgb;
            let (w, h) = dynapix_io::images::image_size(first)?;
            settings.width = w;
            settings.height = h;
        }
        if !(100.0..=100_000.0).contains(&settings.depth_map_factor) {
            tracing::warn!(
                "implausible DepthMapFactor {} (expected about 1000-5208)",
                settings.depth_map_factor
            );
        }
        sequence.depth_factor = settings.depth_map_factor;
        Ok(Self {
            sequence,
            camera: Camera {
                settings,
                source,
                size_from_frames,
            },
            skip_bad_frames: config.skip_bad_frames,
            bad: OnceLock::new(),
            decoded: DecodedFrames::new(config.decoded_cache_mib),
        })
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.sequence.len()
    }

    /// True when there is no frame (never after a successful open).
    pub fn is_empty(&self) -> bool {
        self.sequence.is_empty()
    }

    /// Frame times (s).
    pub fn timestamps(&self) -> Vec<f64> {
        self.sequence.timestamps()
    }

    /// Streams frames `0..len()` in order as a camera driver would: `load(i)` runs on a reader
    /// thread up to `ahead` frames before `consume` takes frame `i`, so decoding overlaps the
    /// processing of the frames before. The first error of `consume` stops the stream and is
    /// returned (the reader stops at the next frame).
    pub fn stream<T: Send, E>(
        &self,
        ahead: usize,
        load: impl FnMut(usize) -> T + Send,
        mut consume: impl FnMut(usize, T) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E> {
        self.stream_inner(ahead, load, false, |i, item, _| consume(i, item))
    }

    /// [`Input::stream`] that also shows `consume` the next frame's item when the reader has
    /// already delivered it (`None` when it has not, or at the end): never waits for it, so
    /// a consumer that uses it to start on the next frame early (e.g.
    /// [`crate::OnlineDynaPix::push_before`]) adds no latency.
    pub fn stream_with_next<T: Send, E>(
        &self,
        ahead: usize,
        load: impl FnMut(usize) -> T + Send,
        consume: impl FnMut(usize, T, Option<&T>) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E> {
        self.stream_inner(ahead, load, true, consume)
    }

    /// The reader thread and the consuming loop of [`Input::stream`] and
    /// [`Input::stream_with_next`]; `peek`: take the next item if it has arrived.
    fn stream_inner<T: Send, E>(
        &self,
        ahead: usize,
        mut load: impl FnMut(usize) -> T + Send,
        peek: bool,
        mut consume: impl FnMut(usize, T, Option<&T>) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E> {
        let n = self.len();
        std::thread::scope(|scope| {
            let (tx, rx) = std::sync::mpsc::sync_channel::<(usize, T)>(ahead.max(1));
            scope.spawn(move || {
                for i in 0..n {
                    if tx.send((i, load(i))).is_err() {
                        break;
                    }
                }
            });
            let mut held: Option<(usize, T)> = None;
            loop {
                let (i, item) = match held.take() {
                    Some(x) => x,
                    None => match rx.recv() {
                        Ok(x) => x,
                        Err(_) => break,
                    },
                };
                let next = if peek { rx.try_recv().ok() } else { None };
                consume(i, item, next.as_ref().map(|(_, t)| t))?;
                held = next;
            }
            Ok(())
        })
    }

    /// [`Input::stream`] with `readers` reader threads: reader `r` loads the frames
    /// `r, r + readers, …` with its own `make_load()`, each up to `ahead` frames before
    /// `consume` takes them, so the loading of consecutive frames overlaps when one reader
    /// cannot keep up (decoding, weight maps, feature extraction of a SLAM pass). `consume`
    /// still takes every frame in order, so the result depends only on what `load` returns
    /// for each frame, never on the number of readers or on timing. The first error of
    /// `consume` stops the stream and is returned (each reader stops at its next frame).
    pub fn stream_parallel<T: Send, L, E>(
        &self,
        ahead: usize,
        readers: usize,
        make_load: impl Fn() -> L,
        mut consume: impl FnMut(usize, T) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E>
    where
        L: FnMut(usize) -> T + Send,
    {
        let n = self.len();
        let readers = readers.clamp(1, n.max(1));
        std::thread::scope(|scope| {
            let mut rxs = Vec::with_capacity(readers);
            for r in 0..readers {
                let (tx, rx) = std::sync::mpsc::sync_channel::<(usize, T)>(ahead.max(1));
                let mut load = make_load();
                scope.spawn(move || {
                    for i in (r..n).step_by(readers) {
                        if tx.send((i, load(i))).is_err() {
                            break;
                        }
                    }
                });
                rxs.push(rx);
            }
            for i in 0..n {
                let Ok((j, item)) = rxs[i % readers].recv() else {
                    break;
                };
                debug_assert_eq!(i, j, "reader {} sent frame {j} for {i}", i % readers);
                consume(i, item)?;
            }
            Ok(())
        })
    }

    /// The colour image and depth (metres) of frame `i`. A file that cannot be used
    /// (missing, truncated, undecodable, rgb and depth of different sizes, a size other than
    /// the camera's) is an [`Error::Frame`] naming the frame, its time and the file.
    pub fn load_rgbd(&self, i: usize) -> Result<(RgbImage, dynapix_io::DepthImage)> {
        if let Some(f) = self.decoded.get(i) {
            return Ok((f.0.clone(), f.1.clone()));
        }
        let _stage = tracing::info_span!(target: "dynapix::stage", "decode images").entered();
        let info = self.sequence.info(i)?;
        let bad = |file: &Path, reason: String| {
            Error::Frame(BadFrame {
                index: i,
                timestamp: info.t,
                file: file.to_path_buf(),
                reason,
            })
        };
        let (rgb, depth) = self
            .sequence
            .load_rgbd(i)
            .map_err(|e| bad(e.path(), e.reason()))?;
        let s = &self.camera.settings;
        if rgb.dimensions() != (s.width, s.height) {
            return Err(bad(
                &info.rgb,
                format!(
                    "size {}x{} differs from the camera's {}x{}",
                    rgb.width(),
                    rgb.height(),
                    s.width,
                    s.height
                ),
            ));
        }
        self.decoded.offer(i, &rgb, &depth);
        Ok((rgb, depth))
    }

    /// Starts (`true`) or stops keeping decoded frames in memory up to the budget
    /// [`SequenceConfig::decoded_cache_mib`]; stopping frees them. Off after
    /// [`Input::open`]: the offline runner turns it on for the runs that read the frames more
    /// than once (every DynaPix run) and off at their end.
    pub fn keep_decoded_frames(&self, on: bool) {
        self.decoded
            .enabled
            .store(on, std::sync::atomic::Ordering::Relaxed);
        if !on && let Ok(mut k) = self.decoded.kept.lock() {
            *k = (0, HashMap::new());
        }
        if !on && let Ok(mut c) = self.decoded.corners.lock() {
            c.clear();
        }
    }

    /// The FAST corners of frame `i`'s grey image kept by an earlier pass of this run
    /// ([`Input::keep_fast_corners`]), if any.
    pub fn fast_corners(&self, i: usize) -> Option<Arc<FastCorners>> {
        self.decoded.corners.lock().ok()?.get(&i).cloned()
    }

    /// Keeps the FAST corners of frame `i`'s grey image for the later passes of a run, while
    /// decoded frames are kept ([`Input::keep_decoded_frames`]) and they fit the budget
    /// [`SequenceConfig::decoded_cache_mib`] (shared with the frames): the corners do not
    /// depend on a pass's weights, so every pass after the first only applies its own mask to
    /// them (a frame whose corners were not kept detects them again, the same ones).
    pub fn keep_fast_corners(&self, i: usize, corners: Arc<FastCorners>) {
        let d = &self.decoded;
        if !d.enabled.load(std::sync::atomic::Ordering::Relaxed) {
            return;
        }
        // Three f32 (x, y, response) per corner.
        let bytes = corners.len() * std::mem::size_of::<[f32; 3]>();
        let (Ok(mut k), Ok(mut c)) = (d.kept.lock(), d.corners.lock()) else {
            return;
        };
        if c.contains_key(&i) || !d.charge(&mut k.0, bytes) {
            return;
        }
        c.insert(i, corners);
    }

    /// The most bytes of decoded frames and FAST corners kept at once since the input was
    /// opened (at most [`SequenceConfig::decoded_cache_mib`]).
    pub fn decoded_peak_bytes(&self) -> usize {
        self.decoded.peak.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Number of decoded frames kept in memory between passes
    /// ([`SequenceConfig::decoded_cache_mib`]).
    pub fn decoded_frames_kept(&self) -> usize {
        self.decoded.kept.lock().map_or(0, |k| k.1.len())
    }

    /// The depth (metres) of frame `i`: from the decoded frames kept between passes when
    /// there, else read from its file (without keeping it).
    pub fn load_depth(&self, i: usize) -> Result<dynapix_io::DepthImage> {
        if let Some(f) = self.decoded.get(i) {
            return Ok(f.1.clone());
        }
        let _stage = tracing::info_span!(target: "dynapix::stage", "decode images").entered();
        Ok(self.sequence.load_depth(i)?)
    }

    /// The frames whose files cannot be used, in frame order, when this input skips them
    /// ([`Input::skip_bad_frames`]; every frame is decoded once, in parallel, on the first
    /// call); empty otherwise. Motion maps leave these frames out, and their neighbours do
    /// without them.
    pub fn bad_frames(&self) -> &[BadFrame] {
        if !self.skip_bad_frames {
            return &[];
        }
        self.bad.get_or_init(|| {
            use rayon::prelude::*;
            (0..self.len())
                .into_par_iter()
                .filter_map(|i| match self.load_rgbd(i) {
                    Err(Error::Frame(b)) => Some(b),
                    _ => None,
                })
                .collect()
        })
    }

    /// True when frame `i` is one of [`Input::bad_frames`].
    pub fn is_bad(&self, i: usize) -> bool {
        self.bad_frames()
            .binary_search_by_key(&i, |b| b.index)
            .is_ok()
    }

    /// The indices of [`Input::bad_frames`] for the records of whatever they change (first
    /// pass, motion maps); `None` when there is none, so records without them keep their keys.
    pub fn bad_frames_record(&self) -> Option<serde_json::Value> {
        let bad = self.bad_frames();
        (!bad.is_empty())
            .then(|| serde_json::json!(bad.iter().map(|b| b.index).collect::<Vec<_>>()))
    }

    /// The file name of frame `i`'s probability map or mask: the rgb file name with `.png`.
    pub fn map_name(&self, i: usize) -> Option<PathBuf> {
        Some(PathBuf::from(self.sequence.rgb_name(i)?).with_extension("png"))
    }

    /// A hash of the frame list (times and file paths as resolved): two runs on the same
    /// frames have the same hash.
    pub fn frames_hash(&self) -> String {
        let mut h = Fnv64::new();
        for f in &self.sequence.frames {
            h.write(&f.t.to_le_bytes());
            h.write(f.rgb.as_os_str().as_encoded_bytes());
            h.write(&f.t_depth.to_le_bytes());
            h.write(f.depth.as_os_str().as_encoded_bytes());
        }
        h.hex()
    }

    /// What outputs record about the sequence: folder, frame list and its policy, camera.
    pub fn record(&self) -> serde_json::Value {
        let s = &self.sequence;
        serde_json::json!({
            "dir": s.dir,
            "frames": s.len(),
            "frame_list": s.frame_list,
            "frames_hash": self.frames_hash(),
            "first_t": s.frames.first().map(|f| f.t),
            "last_t": s.frames.last().map(|f| f.t),
            "depth_factor": s.depth_factor,
            "groundtruth": s.groundtruth.is_some(),
            "groundtruth_convention": self.ground_truth_record(),
            "camera": self.camera.record(),
        })
    }

    /// Which convention the sequence's `groundtruth.txt` was read in (`null` without one):
    /// what the file holds, how it was used, and the rule that chose it.
    pub fn ground_truth_record(&self) -> serde_json::Value {
        let s = &self.sequence;
        if s.groundtruth.is_none() {
            return serde_json::Value::Null;
        }
        let path = s.dir.join("groundtruth.txt");
        let convention = dynapix_io::GroundTruthConvention::of_file(&path);
        let used = dynapix_io::GroundTruth {
            trajectory: dynapix_io::Trajectory::default(),
            convention,
            frame: dynapix_io::GtFrame::Camera,
        };
        serde_json::json!({
            "file": path,
            "file_holds": convention.as_str(),
            "used_as": used.description(),
            "rule": "the groundtruth.txt of a folder named rgbd_bonn_* (links resolved) holds \
                     Bonn marker-body poses and is converted to camera poses; any other file \
                     holds camera poses",
        })
    }
}
