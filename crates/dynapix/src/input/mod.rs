//! A sequence folder opened for a run: the frames of the one reader
//! ([`dynapix_io::Sequence`], one association policy) and the camera, resolved in one order
//! for every command: an explicit settings file, else a preset, else the folder's
//! `camera.yaml`, else the preset of the folder's dataset (`rgbd_dataset_freiburgN_*`,
//! `rgbd_bonn_*`) or the GRADE layout, else an error that says how to give it (design §6).

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use dynapix_io::settings::SEQUENCE_SETTINGS_FILE;
use dynapix_io::{Sequence, SequenceOptions, Settings};
use dynapix_slam::orb::FastCorners;
use image::RgbImage;

use crate::config::SequenceConfig;
use crate::error::{BadFrame, Error, Result};
use crate::hash::Fnv64;
use crate::record::{DepthValidityRecord, GroundTruthRecord, SequenceRecord};

mod cache;
mod camera;
mod read_ahead;

pub use crate::record::CameraSource;
use cache::DecodedFrames;
pub use camera::{Camera, CameraChoice, CameraPreset};

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
    /// The bad frames, found on first use when skipping (shared by the copies of an input).
    bad: Arc<OnceLock<Vec<BadFrame>>>,
    /// Decoded frames kept between passes ([`SequenceConfig::decoded_cache_mib`]); clones of
    /// an input share it.
    decoded: DecodedFrames,
    /// The depth-validity rule of the sequence and where its limits came from.
    depth_validity: DepthValidityRecord,
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
            depth_limits: config.depth_limits(),
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
        // The configuration's limits win key by key over the camera's (its settings file).
        let depth_validity =
            DepthValidityRecord::resolve(config.depth_limits(), settings.depth_limits);
        sequence.depth_validity = depth_validity.validity();
        Ok(Self {
            sequence,
            camera: Camera {
                settings,
                source,
                size_from_frames,
            },
            skip_bad_frames: config.skip_bad_frames,
            bad: Arc::new(OnceLock::new()),
            decoded: DecodedFrames::new(config.decoded_cache_mib),
            depth_validity,
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

    /// The colour image and depth (metres) of frame `i`. A file that cannot be used
    /// (missing, truncated, undecodable, rgb and depth of different sizes, a size other than
    /// the camera's) is an [`Error::Frame`] naming the frame, its time and the file.
    pub fn load_rgbd(&self, i: usize) -> Result<(RgbImage, dynapix_io::DepthImage)> {
        if let Some(f) = self.decoded.rgbd(i) {
            return Ok(f);
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
        self.decoded.set_enabled(on);
    }

    /// The FAST corners of frame `i`'s grey image kept by an earlier pass of this run
    /// ([`Input::keep_fast_corners`]), if any.
    pub fn fast_corners(&self, i: usize) -> Option<Arc<FastCorners>> {
        self.decoded.corners(i)
    }

    /// Keeps the FAST corners of frame `i`'s grey image for the later passes of a run, while
    /// decoded frames are kept ([`Input::keep_decoded_frames`]) and they fit the budget
    /// [`SequenceConfig::decoded_cache_mib`] (shared with the frames): the corners do not
    /// depend on a pass's weights, so every pass after the first only applies its own mask to
    /// them (a frame whose corners were not kept detects them again, the same ones).
    pub fn keep_fast_corners(&self, i: usize, corners: Arc<FastCorners>) {
        self.decoded.keep_corners(i, corners);
    }

    /// The most bytes of decoded frames and FAST corners kept at once since this input's
    /// cache was made (at most [`SequenceConfig::decoded_cache_mib`]).
    pub fn decoded_peak_bytes(&self) -> usize {
        self.decoded.peak_bytes()
    }

    /// What the decoded-frame cache held (`run.json` → `decoded_cache`): budget, peak bytes,
    /// frames and corner sets kept now.
    pub fn decoded_record(&self) -> serde_json::Value {
        self.decoded.record()
    }

    /// Number of decoded frames kept in memory between passes
    /// ([`SequenceConfig::decoded_cache_mib`]).
    pub fn decoded_frames_kept(&self) -> usize {
        self.decoded.frames_kept()
    }

    /// The depth image of frame `i` as stored (raw 16-bit units, before the depth factor and
    /// the validity rule).
    pub fn load_depth_raw(
        &self,
        i: usize,
    ) -> Result<image::ImageBuffer<image::Luma<u16>, Vec<u16>>> {
        let path = &self.sequence.info(i)?.depth;
        Ok(dynapix_io::images::read_depth_raw(path)?)
    }

    /// A copy of this input with a decoded-frame cache of its own (empty, off): the input of
    /// one run, whose cache no other run switches or fills.
    pub fn for_run(&self) -> Input {
        Input {
            decoded: self.decoded.fresh(),
            ..self.clone()
        }
    }

    /// The depth (metres) of frame `i`: from the decoded frames kept between passes when
    /// there, else read from its file (without keeping it).
    pub fn load_depth(&self, i: usize) -> Result<dynapix_io::DepthImage> {
        if let Some(d) = self.decoded.depth(i) {
            return Ok(d);
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
    pub fn record(&self) -> SequenceRecord {
        let s = &self.sequence;
        SequenceRecord {
            dir: s.dir.clone(),
            frames: s.len(),
            frame_list: s.frame_list.clone(),
            frames_hash: self.frames_hash(),
            first_t: s.frames.first().map(|f| f.t),
            last_t: s.frames.last().map(|f| f.t),
            depth_factor: s.depth_factor,
            groundtruth: s.groundtruth.is_some(),
            groundtruth_convention: self.ground_truth_record(),
            camera: self.camera.record(),
            depth_validity: Some(self.depth_validity.clone()),
        }
    }

    /// Which convention the sequence's `groundtruth.txt` was read in (`None` without one):
    /// what the file holds, how it was used, and the rule that chose it.
    pub fn ground_truth_record(&self) -> Option<GroundTruthRecord> {
        let s = &self.sequence;
        s.groundtruth.as_ref()?;
        let path = s.dir.join("groundtruth.txt");
        let convention = dynapix_io::GroundTruthConvention::of_file(&path);
        let used = dynapix_io::GroundTruth {
            trajectory: dynapix_io::Trajectory::default(),
            convention,
            frame: dynapix_io::GtFrame::Camera,
        };
        Some(GroundTruthRecord {
            file: path,
            file_holds: convention.as_str().to_string(),
            used_as: used.description().to_string(),
            rule: "the groundtruth.txt of a folder named rgbd_bonn_* (links resolved) holds \
                   Bonn marker-body poses and is converted to camera poses; any other file \
                   holds camera poses"
                .to_string(),
        })
    }
}
