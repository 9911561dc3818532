//! One `Sequence` type over the three folder layouts dynapix reads (spec §5, design.md §1):
//!
//! - **TUM RGB-D**: a 4-column association file, else `rgb.txt` + `depth.txt` paired by the
//!   [`Pairing`] policy (default [`Pairing::Nearest`]: every rgb frame with its nearest depth
//!   image within 0.02 s), images under `rgb/` and `depth/`, `groundtruth.txt`.
//! - **DynaPix**: the same lists plus optional per-frame folders `background/` (static
//!   background), `depth_bg/` (its depth), `prob/` (motion probability, reference PNG or
//!   lossless PFM) and `mask/` (8-bit, non-zero = dynamic), each file named like the rgb image
//!   (`depth_bg/` like the depth image, falling back to the rgb name).
//! - **GRADE**: numbered frames `rgb/1.png … rgb/N.png`, `depth/i.png` in millimetres,
//!   `background/`, `depth_bg/`; frame i at t = (i − 1)/30 s unless an association file gives
//!   the times.
//!
//! This is the one reader of a sequence folder: every command and the `dynapix` library see the
//! same frames, and [`Sequence::frame_list`] says where they came from (recorded in outputs).
//!
//! Ground truth is held as camera-to-world poses: the marker poses of a Bonn RGB-D Dynamic
//! folder (`rgbd_bonn_*`) are converted on opening ([`crate::ground_truth`]).
//!
//! Opening reads only the text files and checks which optional files exist; images are loaded
//! per frame by [`Sequence::load_frame`], which takes `&self` and holds no lock, so frames can
//! be loaded from rayon in parallel.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use dynapix_geometry::Se3;
use image::{GrayImage, RgbImage};

use crate::datasets::ASSOCIATION_FILES;
use crate::depth::{DepthLimits, DepthValidity, depth_to_metres_valid};
use crate::error::{IoError, Result};
use crate::ground_truth::{GROUNDTRUTH_FILE, GroundTruthConvention, GtFrame, read_ground_truth};
use crate::images::{self, DepthImage, ProbMap};
use crate::settings::{SEQUENCE_SETTINGS_FILE, Settings};
use crate::trajectory::{DEFAULT_MAX_GAP, Trajectory};
use crate::tum::{self, DEFAULT_MAX_DIFF};
use crate::weights;

/// Frame rate of GRADE sequences, which gives t = (i − 1)/30 for frame i.
pub const GRADE_FPS: f64 = 30.0;

/// Depth units per metre when neither `camera.yaml` nor the folder name tells it: TUM
/// (0.2 mm units).
pub const TUM_DEPTH_FACTOR: f64 = 5000.0;

/// The folder layout a sequence was recognised as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// TUM RGB-D: lists or association file, no per-frame extra folders.
    Tum,
    /// DynaPix: TUM-style lists plus `background/`, `depth_bg/`, `prob/` or `mask/`.
    DynaPix,
    /// GRADE: frames numbered `rgb/1.png …` (depth in mm by default).
    Grade,
}

/// How `rgb.txt` and `depth.txt` are paired when the folder has no association file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Pairing {
    /// Every rgb frame with the depth image nearest in time within `max_diff`; a depth image
    /// may serve two rgb frames ([`tum::associate_nearest`]). No rgb frame is dropped, so the
    /// tracking rate is measured against the full rgb list. The default.
    #[default]
    Nearest,
    /// One-to-one like the TUM `associate.py` ([`tum::associate_lists`]): rgb frames whose
    /// nearest depth went to a neighbour are dropped.
    OneToOne,
}

/// Where the frame list of a [`Sequence`] came from (recorded in every output).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "source", rename_all = "snake_case")]
pub enum FrameList {
    /// A 4-column association file.
    AssociationFile {
        /// The file.
        path: PathBuf,
    },
    /// `rgb.txt` + `depth.txt`, paired by `pairing` within `max_diff_s` seconds.
    Lists {
        /// The pairing policy.
        pairing: Pairing,
        /// Largest rgb/depth time difference (s).
        max_diff_s: f64,
        /// rgb frames listed in `rgb.txt`.
        rgb_listed: usize,
    },
    /// Numbered `rgb/1.png …` (GRADE), t = (i − 1)/30 s.
    Numbered,
}

/// Options of [`Sequence::open_with`]; `Default` gives the reference values.
#[derive(Clone, Debug, PartialEq)]
pub struct SequenceOptions {
    /// Depth units per metre; `None` = from the sequence settings (`camera.yaml`, folder
    /// name), else 1000 for GRADE and 5000 otherwise.
    pub depth_factor: Option<f64>,
    /// Maximal rgb/depth time difference when associating `rgb.txt` and `depth.txt` (0.02 s).
    pub max_diff: f64,
    /// How `rgb.txt` and `depth.txt` are paired (nearest depth per rgb frame).
    pub pairing: Pairing,
    /// An explicit association file (4 columns) instead of the folder's own frame list.
    pub association_file: Option<PathBuf>,
    /// Maximal gap between two ground-truth poses to interpolate between them (0.05 s).
    pub gt_max_gap: f64,
    /// Folder of the probability maps (named like the rgb images); `None` = `<dir>/prob`.
    /// Lets a read-only dataset use maps computed elsewhere.
    pub prob_dir: Option<PathBuf>,
    /// Depth limits that override the sequence's own camera (`camera.yaml`, keys
    /// `depth_saturation` and `depth_max_m`) key by key; what neither states takes the
    /// default ([`DepthValidity::default`]). Depth outside the limits is read as missing.
    pub depth_limits: DepthLimits,
}

impl Default for SequenceOptions {
    fn default() -> Self {
        Self {
            depth_factor: None,
            max_diff: DEFAULT_MAX_DIFF,
            pairing: Pairing::Nearest,
            association_file: None,
            gt_max_gap: DEFAULT_MAX_GAP,
            prob_dir: None,
            depth_limits: DepthLimits::default(),
        }
    }
}

/// Where the files of one frame are (paths resolved against the sequence folder).
#[derive(Clone, Debug, PartialEq)]
pub struct FrameInfo {
    /// Frame time in seconds (the rgb timestamp).
    pub t: f64,
    /// Timestamp of the associated depth image.
    pub t_depth: f64,
    /// Colour image.
    pub rgb: PathBuf,
    /// Depth image (16-bit).
    pub depth: PathBuf,
    /// Static-background colour image, if present.
    pub background: Option<PathBuf>,
    /// Static-background depth image, if present.
    pub depth_bg: Option<PathBuf>,
    /// Motion mask (8-bit, non-zero = dynamic), if present.
    pub mask: Option<PathBuf>,
    /// Motion probability map (`.pfm` preferred over the reference `.png`), if present.
    pub prob: Option<PathBuf>,
}

/// Everything loaded for one frame.
#[derive(Clone, Debug)]
pub struct FrameData {
    /// Index of the frame in the sequence (0-based).
    pub index: usize,
    /// Frame time in seconds.
    pub t: f64,
    /// Colour image.
    pub rgb: RgbImage,
    /// Depth in metres (0 = no depth).
    pub depth: DepthImage,
    /// Static-background colour image.
    pub background: Option<RgbImage>,
    /// Static-background depth in metres.
    pub depth_bg: Option<DepthImage>,
    /// Motion mask, non-zero = dynamic.
    pub mask: Option<GrayImage>,
    /// Motion probability P ∈ [0, 1].
    pub prob: Option<ProbMap>,
    /// Ground-truth camera-to-world pose, SLERP-interpolated at `t`; `None` without ground
    /// truth or when the two surrounding ground-truth poses are too far apart.
    pub gt_pose: Option<Se3>,
}

/// A dataset sequence on disk: frame list, optional ground truth, camera settings.
#[derive(Clone, Debug)]
pub struct Sequence {
    /// The sequence folder.
    pub dir: PathBuf,
    /// The recognised layout.
    pub layout: Layout,
    /// The frames in time order.
    pub frames: Vec<FrameInfo>,
    /// Where the frame list came from.
    pub frame_list: FrameList,
    /// `groundtruth.txt`, when present, as camera-to-world poses (converted from the file
    /// when [`Self::gt_convention`] says it holds marker poses).
    pub groundtruth: Option<Trajectory>,
    /// What the poses of `groundtruth.txt` are in the file (Bonn: marker body).
    pub gt_convention: GroundTruthConvention,
    /// Camera settings from `camera.yaml` (read leniently: missing keys take the TUM values,
    /// see [`Sequence::settings_missing_keys`]), the folder's dataset
    /// (`rgbd_dataset_freiburgN_*`, `rgbd_bonn_*`) or the GRADE layout; `None` when they
    /// cannot be told (see [`Sequence::settings`]).
    pub settings: Option<Settings>,
    /// Keys missing from the folder's `camera.yaml` (they took the TUM values).
    pub settings_missing_keys: Vec<&'static str>,
    /// Depth units per metre used by [`Sequence::load_frame`].
    pub depth_factor: f64,
    /// Maximal ground-truth gap for interpolation (s).
    pub gt_max_gap: f64,
    /// Folder of the probability maps (`<dir>/prob` unless [`SequenceOptions::prob_dir`]).
    pub prob_dir: PathBuf,
    /// Which depth values are measurements: the others (the sensor's saturation value,
    /// implausible ranges) are read as missing by every depth reader of this sequence.
    pub depth_validity: DepthValidity,
    /// Frames whose depth had values that are no measurement: frame index → pixels. Shared
    /// by the clones of the sequence, so each frame is reported once per run.
    invalid_depth: Arc<Mutex<BTreeMap<usize, usize>>>,
}

/// Depth pixels read as missing because they were no measurement ([`DepthValidity`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct InvalidDepth {
    /// Frames with at least one such pixel.
    pub frames: usize,
    /// Such pixels, over those frames.
    pub pixels: usize,
}

/// `dir/<sub>/<name>` if that file exists.
fn existing(dir: &Path, sub: &str, name: Option<&std::ffi::OsStr>) -> Option<PathBuf> {
    let p = dir.join(sub).join(name?);
    p.is_file().then_some(p)
}

/// The probability-map paths (reference PNG, lossless PFM) of an rgb image in `prob_dir`.
fn prob_paths(prob_dir: &Path, rgb: &Path) -> (PathBuf, PathBuf) {
    let png = prob_dir.join(rgb.file_name().unwrap_or(rgb.as_os_str()));
    let pfm = png.with_extension("pfm");
    (png, pfm)
}

/// True when the file stem is a decimal frame number (GRADE naming).
fn is_numbered(path: &Path) -> bool {
    path.file_stem()
        .and_then(|s| s.to_str())
        .is_some_and(|s| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit()))
}

impl Sequence {
    /// Opens a sequence folder with default options (see [`Sequence::open_with`]).
    pub fn open(dir: impl AsRef<Path>) -> Result<Self> {
        Self::open_with(dir, &SequenceOptions::default())
    }

    /// Opens a sequence folder: finds the frame list (association file, else `rgb.txt` +
    /// `depth.txt`, else numbered `rgb/1.png …`), the optional per-frame files, the ground
    /// truth and the settings.
    pub fn open_with(dir: impl AsRef<Path>, opts: &SequenceOptions) -> Result<Self> {
        let dir = dir.as_ref().to_path_buf();
        if !dir.is_dir() {
            return Err(IoError::invalid(&dir, "not a folder"));
        }
        let (pairs, frame_list) = Self::read_frame_list(&dir, opts)?;
        if pairs.is_empty() {
            return Err(IoError::invalid(&dir, "the sequence has no frames"));
        }
        let numbered = pairs.iter().all(|a| is_numbered(Path::new(&a.rgb)));
        let has = |sub: &str| dir.join(sub).is_dir();
        let (has_bg, has_dbg, has_mask) = (has("background"), has("depth_bg"), has("mask"));
        let prob_dir = opts.prob_dir.clone().unwrap_or_else(|| dir.join("prob"));
        let has_prob = prob_dir.is_dir();
        let layout = if numbered {
            Layout::Grade
        } else if has_bg || has_dbg || has("prob") || has_mask {
            Layout::DynaPix
        } else {
            Layout::Tum
        };
        let frames = pairs
            .iter()
            .map(|a| {
                let rgb = tum::resolve_path(&dir, &a.rgb);
                let depth = tum::resolve_path(&dir, &a.depth);
                let rgb_name = rgb.file_name();
                let prob = if has_prob {
                    let (png, pfm) = prob_paths(&prob_dir, &rgb);
                    [pfm, png].into_iter().find(|p| p.is_file())
                } else {
                    None
                };
                FrameInfo {
                    t: a.t_rgb,
                    t_depth: a.t_depth,
                    background: has_bg
                        .then(|| existing(&dir, "background", rgb_name))
                        .flatten(),
                    depth_bg: has_dbg
                        .then(|| {
                            existing(&dir, "depth_bg", depth.file_name())
                                .or_else(|| existing(&dir, "depth_bg", rgb_name))
                        })
                        .flatten(),
                    mask: has_mask.then(|| existing(&dir, "mask", rgb_name)).flatten(),
                    prob,
                    rgb,
                    depth,
                }
            })
            .collect();
        let gt_path = dir.join(GROUNDTRUTH_FILE);
        let gt_convention = GroundTruthConvention::of_file(&gt_path);
        let groundtruth = if gt_path.is_file() {
            Some(read_ground_truth(&gt_path, GtFrame::Camera)?.trajectory)
        } else {
            None
        };
        let own = dir.join(SEQUENCE_SETTINGS_FILE);
        let (settings, settings_missing_keys) = if own.is_file() {
            // A broken camera.yaml must be reported, not replaced by a guess; short files
            // (only the intrinsics) are accepted as the commands always did.
            let (s, missing) = Settings::read_lenient(&own)?;
            (Some(s), missing)
        } else {
            match Settings::for_sequence_dir(&dir) {
                Ok(s) => (Some(s), Vec::new()),
                Err(_) if layout == Layout::Grade => (Some(Settings::grade()), Vec::new()),
                Err(_) => (None, Vec::new()),
            }
        };
        let depth_factor = match (opts.depth_factor, &settings) {
            (Some(f), _) => f,
            (None, Some(s)) => s.depth_map_factor,
            (None, None) => TUM_DEPTH_FACTOR,
        };
        if !(depth_factor.is_finite() && depth_factor > 0.0) {
            return Err(IoError::invalid(
                &dir,
                format!("depth factor must be positive, got {depth_factor}"),
            ));
        }
        // The caller's limits win key by key over the camera's own (`camera.yaml`).
        let depth_validity = opts
            .depth_limits
            .or(settings
                .as_ref()
                .map(|s| s.depth_limits)
                .unwrap_or_default())
            .validity();
        Ok(Self {
            dir,
            layout,
            frames,
            frame_list,
            groundtruth,
            gt_convention,
            settings,
            settings_missing_keys,
            depth_factor,
            gt_max_gap: opts.gt_max_gap,
            prob_dir,
            depth_validity,
            invalid_depth: Arc::default(),
        })
    }

    /// The rgb/depth pairs of the folder, as written (paths not yet resolved), and where
    /// they came from.
    fn read_frame_list(
        dir: &Path,
        opts: &SequenceOptions,
    ) -> Result<(Vec<tum::Association>, FrameList)> {
        if let Some(f) = opts.association_file.clone().or_else(|| {
            ASSOCIATION_FILES
                .iter()
                .map(|n| dir.join(n))
                .find(|p| p.is_file())
        }) {
            let pairs = tum::read_associations(&f)?;
            return Ok((pairs, FrameList::AssociationFile { path: f }));
        }
        let (rgb_txt, depth_txt) = (dir.join("rgb.txt"), dir.join("depth.txt"));
        if rgb_txt.is_file() || depth_txt.is_file() {
            let rgb = tum::read_list(&rgb_txt)?;
            let depth = tum::read_list(&depth_txt)?;
            let pairs = match opts.pairing {
                Pairing::Nearest => tum::associate_nearest(&rgb, &depth, opts.max_diff),
                Pairing::OneToOne => tum::associate_lists(&rgb, &depth, 0.0, opts.max_diff),
            };
            let list = FrameList::Lists {
                pairing: opts.pairing,
                max_diff_s: opts.max_diff,
                rgb_listed: rgb.len(),
            };
            return Ok((pairs, list));
        }
        if dir.join("rgb").join("1.png").is_file() {
            let mut out = Vec::new();
            for i in 1usize.. {
                let rgb = format!("rgb/{i}.png");
                if !dir.join(&rgb).is_file() {
                    break;
                }
                let depth = format!("depth/{i}.png");
                if !dir.join(&depth).is_file() {
                    return Err(IoError::invalid(
                        dir.join(&depth),
                        format!("missing: {rgb} exists but its depth image does not"),
                    ));
                }
                let t = (i - 1) as f64 / GRADE_FPS;
                out.push(tum::Association {
                    t_rgb: t,
                    rgb,
                    t_depth: t,
                    depth,
                });
            }
            return Ok((out, FrameList::Numbered));
        }
        Err(IoError::invalid(
            dir,
            format!(
                "no frame list: expected one of {}, rgb.txt + depth.txt, or numbered rgb/1.png …",
                ASSOCIATION_FILES.join(", ")
            ),
        ))
    }

    /// Keeps only the first `n` frames (`n ≥ 1`; more than the sequence has changes nothing).
    pub fn truncate(&mut self, n: usize) {
        self.frames.truncate(n.max(1));
    }

    /// The file name of frame `i`'s rgb image (probability maps and masks are named like it).
    pub fn rgb_name(&self, i: usize) -> Option<&std::ffi::OsStr> {
        self.frames.get(i)?.rgb.file_name()
    }

    /// Loads the rgb image and the depth (metres) of frame `i`, checking that their sizes
    /// agree; nothing else is read.
    pub fn load_rgbd(&self, i: usize) -> Result<(RgbImage, DepthImage)> {
        let info = self.info(i)?;
        let rgb = images::read_rgb(&info.rgb)?;
        let depth = self.load_depth(i)?;
        images::check_same_size(&info.rgb, rgb.dimensions(), &info.depth, depth.dimensions())?;
        Ok((rgb, depth))
    }

    /// The depth (metres) of frame `i`, values that are no measurement read as missing
    /// ([`Sequence::depth_validity`]). The first time a frame has such values, a warning
    /// names it with their count, and [`Sequence::invalid_depth`] counts it.
    pub fn load_depth(&self, i: usize) -> Result<DepthImage> {
        let info = self.info(i)?;
        let (depth, invalid) = self.decode_depth(&info.depth)?;
        if invalid > 0
            && let Ok(mut seen) = self.invalid_depth.lock()
            && seen.insert(i, invalid).is_none()
        {
            tracing::warn!(
                "frame {i} ({}): {invalid} depth pixels at the sensor's saturation value {} or \
                 beyond {} m are no measurement: read as missing",
                info.depth.display(),
                self.depth_validity
                    .saturation
                    .map_or("(none)".to_string(), |v| v.to_string()),
                self.depth_validity.max_depth
            );
        }
        Ok(depth)
    }

    /// Reads any depth image of this sequence (e.g. a background depth) in metres, values
    /// that are no measurement read as missing ([`Sequence::depth_validity`]).
    pub fn read_depth(&self, path: &Path) -> Result<DepthImage> {
        Ok(self.decode_depth(path)?.0)
    }

    fn decode_depth(&self, path: &Path) -> Result<(DepthImage, usize)> {
        let raw = images::read_depth_raw(path)?;
        Ok(depth_to_metres_valid(
            &raw,
            self.depth_factor,
            &self.depth_validity,
        ))
    }

    /// The frames read so far whose depth had values that are no measurement, and how many
    /// pixels (each frame counted once, however often it was read).
    pub fn invalid_depth(&self) -> InvalidDepth {
        self.invalid_depth
            .lock()
            .map(|seen| InvalidDepth {
                frames: seen.len(),
                pixels: seen.values().sum(),
            })
            .unwrap_or_default()
    }

    /// The files of frame `i`, or an "out of range" error.
    pub fn info(&self, i: usize) -> Result<&FrameInfo> {
        self.frames.get(i).ok_or_else(|| {
            IoError::invalid(
                &self.dir,
                format!(
                    "frame {i} out of range (sequence has {})",
                    self.frames.len()
                ),
            )
        })
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// True when the sequence has no frame (never the case after a successful open).
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Frame times in seconds.
    pub fn timestamps(&self) -> Vec<f64> {
        self.frames.iter().map(|f| f.t).collect()
    }

    /// The camera settings, or the "cannot tell the camera" error of
    /// [`Settings::for_sequence_dir`].
    pub fn settings(&self) -> Result<&Settings> {
        match &self.settings {
            Some(s) => Ok(s),
            None => Err(Settings::for_sequence_dir(&self.dir)
                .err()
                .unwrap_or_else(|| IoError::invalid(&self.dir, "cannot tell the camera"))),
        }
    }

    /// Ground-truth camera pose (camera-to-world; Bonn marker poses converted) at time `t`,
    /// SLERP-interpolated between the two surrounding converted poses.
    pub fn gt_pose_at(&self, t: f64) -> Option<Se3> {
        self.groundtruth.as_ref()?.interpolate(t, self.gt_max_gap)
    }

    /// Loads frame `i`: images (depth in metres), optional maps and the interpolated
    /// ground-truth pose. Every image must have the rgb image's size.
    pub fn load_frame(&self, i: usize) -> Result<FrameData> {
        let info = self.info(i)?;
        let rgb = images::read_rgb(&info.rgb)?;
        let size = rgb.dimensions();
        let same = |p: &Path, s: (u32, u32)| images::check_same_size(p, s, &info.rgb, size);
        let depth = self.load_depth(i)?;
        same(&info.depth, depth.dimensions())?;
        let background = match &info.background {
            Some(p) => {
                let img = images::read_rgb(p)?;
                same(p, img.dimensions())?;
                Some(img)
            }
            None => None,
        };
        let depth_bg = match &info.depth_bg {
            Some(p) => {
                let img = self.read_depth(p)?;
                same(p, img.dimensions())?;
                Some(img)
            }
            None => None,
        };
        let mask = match &info.mask {
            Some(p) => {
                let img = images::read_mask(p)?;
                same(p, img.dimensions())?;
                Some(img)
            }
            None => None,
        };
        let prob = match &info.prob {
            Some(p) => {
                let img = if p.extension().is_some_and(|e| e == "pfm") {
                    weights::read_prob_pfm(p)?
                } else {
                    weights::read_prob_png(p)?
                };
                same(p, img.dimensions())?;
                Some(img)
            }
            None => None,
        };
        Ok(FrameData {
            index: i,
            t: info.t,
            rgb,
            depth,
            background,
            depth_bg,
            mask,
            prob,
            gt_pose: self.gt_pose_at(info.t),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::StampedPose;
    use crate::tum::Association;
    use image::{Luma, Rgb};
    use nalgebra::Vector3;

    use crate::testutil::data_dir;

    #[test]
    fn sequence_is_shareable_across_threads() {
        fn assert_sync<T: Send + Sync>() {}
        assert_sync::<Sequence>();
        assert_sync::<FrameData>();
    }

    fn mkdirs(dir: &Path, subs: &[&str]) {
        for s in subs {
            std::fs::create_dir_all(dir.join(s)).unwrap();
        }
    }

    /// A 3-frame DynaPix-layout sequence with every optional folder (frame 1 has no mask).
    fn write_dynapix(dir: &Path) {
        mkdirs(
            dir,
            &["rgb", "depth", "background", "depth_bg", "prob", "mask"],
        );
        let mut assoc = Vec::new();
        let mut gt = Vec::new();
        for k in 0..3 {
            let t = 100.0 + k as f64 * 0.5;
            let (rn, dn) = (format!("{t:.6}.png"), format!("{:.6}.png", t + 0.01));
            let rgb = RgbImage::from_pixel(8, 6, Rgb([k as u8, 2, 3]));
            images::write_rgb(dir.join("rgb").join(&rn), &rgb).unwrap();
            images::write_rgb(dir.join("background").join(&rn), &rgb).unwrap();
            let d = DepthImage::from_pixel(8, 6, Luma([1.0 + k as f32]));
            images::write_depth(dir.join("depth").join(&dn), &d, 5000.0).unwrap();
            images::write_depth(dir.join("depth_bg").join(&dn), &d, 5000.0).unwrap();
            if k != 1 {
                images::write_mask(dir.join("mask").join(&rn), &GrayImage::new(8, 6)).unwrap();
            }
            let p = ProbMap::from_pixel(8, 6, Luma([0.25 * k as f32]));
            if k == 2 {
                let pfm = dir.join("prob").join(&rn).with_extension("pfm");
                weights::write_prob_pfm(pfm, &p).unwrap();
            } else {
                weights::write_prob_png(dir.join("prob").join(&rn), &p).unwrap();
            }
            assoc.push(Association {
                t_rgb: t,
                rgb: format!("rgb/{rn}"),
                t_depth: t + 0.01,
                depth: format!("depth/{dn}"),
            });
        }
        // Ground truth every 0.04 s from 100.0 to 100.6 along x at 1 m/s, except a gap
        // around 101.0 so the last frame has none.
        for k in 0..=15 {
            let t = 100.0 + k as f64 * 0.04;
            gt.push(StampedPose::new(t, Se3::translation(t - 100.0, 0.0, 0.0)));
        }
        gt.push(StampedPose::new(101.5, Se3::identity()));
        tum::write_associations(dir.join("association.txt"), &assoc).unwrap();
        Trajectory::new(gt)
            .write_tum(dir.join("groundtruth.txt"))
            .unwrap();
    }

    #[test]
    fn dynapix_layout_loads_every_map() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        write_dynapix(dir);
        let seq = Sequence::open(dir).unwrap();
        assert_eq!(seq.layout, Layout::DynaPix);
        assert_eq!(seq.len(), 3);
        assert_eq!(seq.depth_factor, TUM_DEPTH_FACTOR);
        assert!(
            seq.settings().is_err(),
            "no camera.yaml and no TUM folder name"
        );
        assert!(seq.frames[1].mask.is_none());
        assert!(
            seq.frames[2]
                .prob
                .as_ref()
                .unwrap()
                .ends_with("prob/101.000000.pfm")
        );
        let f = seq.load_frame(1).unwrap();
        assert_eq!(f.t, 100.5);
        assert_eq!(f.rgb.get_pixel(0, 0)[0], 1);
        assert_eq!(f.depth.get_pixel(3, 3)[0], 2.0);
        assert_eq!(f.depth_bg.unwrap().get_pixel(0, 0)[0], 2.0);
        assert!(f.background.is_some() && f.mask.is_none());
        assert!((f.prob.unwrap().get_pixel(0, 0)[0] - 0.25).abs() < 1e-6);
        let gt = f.gt_pose.unwrap();
        assert!((gt.translation.vector - Vector3::new(0.5, 0.0, 0.0)).norm() < 1e-9);
        let last = seq.load_frame(2).unwrap();
        assert_eq!(last.prob.unwrap().get_pixel(0, 0)[0], 0.5);
        assert!(
            last.gt_pose.is_none(),
            "GT gap 100.6 → 101.5 exceeds 0.05 s"
        );
        let e = seq.load_frame(3).unwrap_err().to_string();
        assert!(e.contains("out of range"), "{e}");
        assert_eq!(
            seq.frames[0].prob.as_deref(),
            Some(dir.join("prob").join("100.000000.png").as_path())
        );
    }

    #[test]
    fn frames_load_in_parallel_with_the_same_result() {
        use rayon::prelude::*;
        let tmp = tempfile::tempdir().unwrap();
        write_dynapix(tmp.path());
        let seq = Sequence::open(tmp.path()).unwrap();
        let par: Vec<FrameData> = (0..seq.len())
            .into_par_iter()
            .map(|i| seq.load_frame(i).unwrap())
            .collect();
        for (i, f) in par.iter().enumerate() {
            let s = seq.load_frame(i).unwrap();
            assert_eq!((f.index, f.t), (i, s.t));
            assert_eq!(f.depth, s.depth);
        }
    }

    #[test]
    fn size_mismatch_and_missing_files_name_the_files() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        write_dynapix(dir);
        let bad_bg = dir.join("background/100.500000.png");
        images::write_rgb(&bad_bg, &RgbImage::new(4, 4)).unwrap();
        let seq = Sequence::open(dir).unwrap();
        let e = seq.load_frame(1).unwrap_err().to_string();
        assert!(
            e.contains("background/100.500000.png") && e.contains("rgb/100.500000.png"),
            "{e}"
        );
        std::fs::remove_file(dir.join("depth/100.010000.png")).unwrap();
        let e = seq.load_frame(0).unwrap_err();
        assert!(matches!(e, IoError::Io { .. }) && e.to_string().contains("depth/100.010000.png"));
        // Broken ground truth or camera.yaml stops the opening with file and line.
        std::fs::write(dir.join("groundtruth.txt"), "1 2 3\n").unwrap();
        let e = Sequence::open(dir).unwrap_err().to_string();
        assert!(e.contains("groundtruth.txt:1"), "{e}");
        std::fs::remove_file(dir.join("groundtruth.txt")).unwrap();
        std::fs::write(dir.join("camera.yaml"), "%YAML:1.0\nCamera.fx: 1\n").unwrap();
        let e = Sequence::open(dir).unwrap_err().to_string();
        assert!(e.contains("camera.yaml"), "{e}");
        let empty = tempfile::tempdir().unwrap();
        let e = Sequence::open(empty.path()).unwrap_err().to_string();
        assert!(e.contains("no frame list"), "{e}");
        assert!(Sequence::open(empty.path().join("nope")).is_err());
    }

    #[test]
    fn grade_numbered_layout() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        mkdirs(dir, &["rgb", "depth", "depth_bg"]);
        for i in 1..=4 {
            images::write_rgb(dir.join(format!("rgb/{i}.png")), &RgbImage::new(5, 4)).unwrap();
            let mm = crate::images::Gray16Image::from_pixel(5, 4, Luma([1500 + i as u16]));
            images::write_gray16(dir.join(format!("depth/{i}.png")), &mm).unwrap();
        }
        images::write_gray16(
            dir.join("depth_bg/2.png"),
            &crate::images::Gray16Image::from_pixel(5, 4, Luma([3000])),
        )
        .unwrap();
        let seq = Sequence::open(dir).unwrap();
        assert_eq!(seq.layout, Layout::Grade);
        assert_eq!(seq.len(), 4);
        assert_eq!(
            seq.timestamps(),
            vec![0.0, 1.0 / 30.0, 2.0 / 30.0, 3.0 / 30.0]
        );
        assert_eq!(seq.depth_factor, 1000.0);
        assert_eq!(seq.settings().unwrap(), &Settings::grade());
        let f = seq.load_frame(1).unwrap();
        assert!((f.depth.get_pixel(0, 0)[0] - 1.502).abs() < 1e-6);
        assert!((f.depth_bg.unwrap().get_pixel(0, 0)[0] - 3.0).abs() < 1e-6);
        assert!(f.gt_pose.is_none());
        // A GRADE association with leading slashes gives the times instead.
        std::fs::write(
            dir.join("rgbd_assoc.txt"),
            "0.5 /rgb/1.png 0.5 /depth/1.png\n0.6 /rgb/2.png 0.6 /depth/2.png\n",
        )
        .unwrap();
        let seq = Sequence::open(dir).unwrap();
        assert_eq!((seq.layout, seq.len()), (Layout::Grade, 2));
        assert_eq!(seq.load_frame(1).unwrap().t, 0.6);
        // A numbered frame without depth is an error naming the depth file.
        std::fs::remove_file(dir.join("rgbd_assoc.txt")).unwrap();
        std::fs::remove_file(dir.join("depth/3.png")).unwrap();
        let e = Sequence::open(dir).unwrap_err().to_string();
        assert!(e.contains("depth/3.png"), "{e}");
        // An explicit depth factor wins.
        std::fs::remove_file(dir.join("rgb/3.png")).unwrap();
        let opts = SequenceOptions {
            depth_factor: Some(5000.0),
            ..Default::default()
        };
        assert_eq!(
            Sequence::open_with(dir, &opts).unwrap().depth_factor,
            5000.0
        );
        assert_eq!(Sequence::open(dir).unwrap().len(), 2);
    }

    #[test]
    fn real_fr1_xyz_sequence() {
        let Some(d) = data_dir() else { return };
        let dir = d.join("tum/rgbd_dataset_freiburg1_xyz");
        // 300 rgb and 300 depth frames; associate.py (run on the same lists) pairs 294, the
        // default nearest pairing keeps every rgb frame.
        let one_to_one = SequenceOptions {
            pairing: Pairing::OneToOne,
            ..Default::default()
        };
        assert_eq!(Sequence::open_with(&dir, &one_to_one).unwrap().len(), 294);
        let seq = Sequence::open(&dir).unwrap();
        assert_eq!(seq.layout, Layout::Tum);
        assert_eq!(seq.len(), 300);
        assert_eq!(
            seq.frame_list,
            FrameList::Lists {
                pairing: Pairing::Nearest,
                max_diff_s: 0.02,
                rgb_listed: 300
            }
        );
        assert_eq!(seq.settings().unwrap(), &Settings::tum1());
        assert_eq!(seq.depth_factor, 5000.0);
        assert_eq!(seq.groundtruth.as_ref().unwrap().len(), 3000);
        assert!(seq.frames.windows(2).all(|w| w[0].t < w[1].t));
        assert!(seq.frames.iter().all(|f| (f.t - f.t_depth).abs() < 0.02));
        let f = seq.load_frame(0).unwrap();
        assert_eq!(format!("{:.6}", f.t), "1305031102.175304");
        assert_eq!(f.rgb.dimensions(), (640, 480));
        assert_eq!(f.depth.dimensions(), (640, 480));
        let valid: Vec<f32> = f
            .depth
            .pixels()
            .map(|p| p[0])
            .filter(|&v| v > 0.0)
            .collect();
        let max = valid.iter().cloned().fold(0.0f32, f32::max);
        let min = valid.iter().cloned().fold(f32::INFINITY, f32::min);
        assert!(
            min > 0.3 && max < 10.0 && valid.len() > 100_000,
            "{min} {max} {}",
            valid.len()
        );
        assert!(f.background.is_none() && f.prob.is_none() && f.mask.is_none());
        // GT at 100 Hz: the interpolated pose lies between its two neighbours.
        let gt = seq.groundtruth.as_ref().unwrap();
        let k = gt.poses.partition_point(|p| p.t <= f.t);
        let (a, b) = (&gt.poses[k - 1], &gt.poses[k]);
        let pose = f.gt_pose.unwrap();
        let s = (f.t - a.t) / (b.t - a.t);
        let expect = a.pose.translation.vector * (1.0 - s) + b.pose.translation.vector * s;
        assert!((pose.translation.vector - expect).norm() < 1e-12);
        assert!(
            pose.rotation.angle_to(&a.pose.rotation)
                <= a.pose.rotation.angle_to(&b.pose.rotation) + 1e-12
        );
    }
    /// Median |z predicted − z measured| of the depth of frame `a` reprojected into frame `b`
    /// (every 4th pixel, distortion-aware), with poses `pa`, `pb` (camera-to-world).
    fn reprojection_residual(
        a: &FrameData,
        b: &FrameData,
        pa: &Se3,
        pb: &Se3,
        cam: &dynapix_geometry::PinholeCamera,
    ) -> f64 {
        use nalgebra::Point2;
        let t_ba = pb.inverse() * pa;
        let mut res = Vec::new();
        for y in (0..cam.height).step_by(4) {
            for x in (0..cam.width).step_by(4) {
                let z = a.depth.get_pixel(x, y)[0] as f64;
                if z <= 0.0 {
                    continue;
                }
                let ray = cam.undistort_point(&Point2::new(x as f64, y as f64));
                let q = t_ba * cam.unproject(&ray, z);
                let Some(uv) = cam.project_distorted(&q) else {
                    continue;
                };
                let (u, v) = (uv.x.round(), uv.y.round());
                if u < 0.0 || v < 0.0 || u >= cam.width as f64 || v >= cam.height as f64 {
                    continue;
                }
                let zb = b.depth.get_pixel(u as u32, v as u32)[0] as f64;
                if zb > 0.0 {
                    res.push((q.z - zb).abs());
                }
            }
        }
        assert!(res.len() > 5000, "{} pixels", res.len());
        let mid = res.len() / 2;
        *res.select_nth_unstable_by(mid, f64::total_cmp).1
    }

    /// The Bonn window opens with its camera preset and camera-frame ground truth: depth
    /// reprojected between frames with the converted poses lands on the measured depth, with
    /// the raw (marker) poses it does not.
    #[test]
    fn real_bonn_window_has_camera_ground_truth() {
        let Some(d) = data_dir() else { return };
        let dir = d.join("bonn/rgbd_bonn_crowd");
        let seq = Sequence::open(&dir).unwrap();
        assert_eq!(seq.layout, Layout::Tum);
        assert_eq!(seq.settings().unwrap(), &Settings::bonn());
        assert_eq!(seq.gt_convention, GroundTruthConvention::BonnMarker);
        assert_eq!(seq.len(), 150);
        let raw = Trajectory::read_tum(dir.join(GROUNDTRUTH_FILE)).unwrap();
        assert_eq!(seq.groundtruth.as_ref().unwrap().len(), raw.len());
        let cam = seq.settings().unwrap().camera();
        let mut converted = Vec::new();
        let mut marker = Vec::new();
        // Frames 10 apart (a third of a second), every 20 frames through the window.
        for (i, j) in (0..150 - 10).step_by(20).map(|i| (i, i + 10)) {
            let (a, b) = (seq.load_frame(i).unwrap(), seq.load_frame(j).unwrap());
            let (pa, pb) = (a.gt_pose.unwrap(), b.gt_pose.unwrap());
            converted.push(reprojection_residual(&a, &b, &pa, &pb, &cam));
            let (ra, rb) = (
                raw.interpolate(a.t, seq.gt_max_gap).unwrap(),
                raw.interpolate(b.t, seq.gt_max_gap).unwrap(),
            );
            marker.push(reprojection_residual(&a, &b, &ra, &rb, &cam));
        }
        eprintln!("median depth residual, converted {converted:.3?} m, raw {marker:.3?} m");
        // People cross the view, so one pair may match badly either way: judge the median
        // over the pairs, and the pairs one by one by majority.
        let better = converted.iter().zip(&marker).filter(|(c, m)| c < m).count();
        assert!(
            better + 1 >= converted.len(),
            "{better} of {}",
            converted.len()
        );
        let median = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let (c, m) = (median(&mut converted), median(&mut marker));
        assert!(c < 0.08 && m > 2.0 * c, "converted {c}, raw {m}");
    }
}

#[cfg(test)]
mod writer_tests {
    use super::*;
    use crate::trajectory::StampedPose;
    use crate::tum::Association;
    use image::{Luma, Rgb};

    fn frame(k: usize) -> FrameData {
        let t = 1000.0 + k as f64 / 30.0;
        FrameData {
            index: k,
            t,
            rgb: RgbImage::from_fn(6, 4, |x, y| Rgb([x as u8, y as u8, k as u8])),
            depth: DepthImage::from_fn(6, 4, |x, _| Luma([0.5 + x as f32 * 0.25])),
            background: Some(RgbImage::from_pixel(6, 4, Rgb([9, 9, 9]))),
            depth_bg: (k == 0).then(|| DepthImage::from_pixel(6, 4, Luma([3.0]))),
            mask: Some(GrayImage::from_fn(6, 4, |x, _| {
                Luma([if x < 2 { 255 } else { 0 }])
            })),
            prob: Some(ProbMap::from_fn(6, 4, |x, y| {
                Luma([(x + 6 * y) as f32 / 23.0])
            })),
            gt_pose: None,
        }
    }

    /// Writes `frames` as a DynaPix-layout folder (what `dynapix synth` produces): `camera.yaml`,
    /// `rgb/`, `depth/`, the optional per-frame folders (probability maps in both formats),
    /// `association.txt` and, when given, `groundtruth.txt`.
    fn write_dynapix_sequence(dir: &Path, frames: &[FrameData], gt: Option<&Trajectory>) {
        let settings = Settings::tum3();
        std::fs::create_dir_all(dir).unwrap();
        settings.write(dir.join(SEQUENCE_SETTINGS_FILE)).unwrap();
        let sub = |s: &str, name: &str| {
            std::fs::create_dir_all(dir.join(s)).unwrap();
            dir.join(s).join(name)
        };
        let mut assoc = Vec::new();
        for f in frames {
            let name = format!("{:.6}.png", f.t);
            let factor = settings.depth_map_factor;
            images::write_rgb(sub("rgb", &name), &f.rgb).unwrap();
            images::write_depth(sub("depth", &name), &f.depth, factor).unwrap();
            if let Some(bg) = &f.background {
                images::write_rgb(sub("background", &name), bg).unwrap();
            }
            if let Some(d) = &f.depth_bg {
                images::write_depth(sub("depth_bg", &name), d, factor).unwrap();
            }
            if let Some(m) = &f.mask {
                images::write_mask(sub("mask", &name), m).unwrap();
            }
            if let Some(p) = &f.prob {
                let png = sub("prob", &name);
                weights::write_prob_png(&png, p).unwrap();
                weights::write_prob_pfm(png.with_extension("pfm"), p).unwrap();
            }
            assoc.push(Association {
                t_rgb: f.t,
                rgb: format!("rgb/{name}"),
                t_depth: f.t,
                depth: format!("depth/{name}"),
            });
        }
        tum::write_associations(dir.join(ASSOCIATION_FILES[0]), &assoc).unwrap();
        if let Some(gt) = gt {
            gt.write_tum(dir.join("groundtruth.txt")).unwrap();
        }
    }

    #[test]
    fn written_sequences_read_back_identically() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("synth_seq");
        let frames: Vec<FrameData> = (0..3).map(frame).collect();
        let gt = Trajectory::new(
            (0..30)
                .map(|i| {
                    StampedPose::new(
                        1000.0 + i as f64 * 0.01,
                        Se3::translation(i as f64, 0.0, 0.0),
                    )
                })
                .collect(),
        );
        write_dynapix_sequence(&dir, &frames, Some(&gt));
        let seq = Sequence::open(&dir).unwrap();
        assert_eq!(seq.layout, Layout::DynaPix);
        assert_eq!(seq.settings().unwrap(), &Settings::tum3());
        assert_eq!(seq.len(), 3);
        for (k, orig) in frames.iter().enumerate() {
            let f = seq.load_frame(k).unwrap();
            assert!((f.t - orig.t).abs() < 5e-7);
            assert_eq!(f.rgb, orig.rgb);
            assert_eq!(f.background, orig.background);
            assert_eq!(f.mask, orig.mask);
            assert_eq!(f.prob, orig.prob, "PFM is preferred and lossless");
            for (a, b) in f.depth.pixels().zip(orig.depth.pixels()) {
                assert!((a[0] - b[0]).abs() <= 0.5 / 5000.0 + 1e-7);
            }
            assert_eq!(f.depth_bg.is_some(), k == 0);
            let x = f.gt_pose.unwrap().translation.x;
            assert!((x - (f.t - 1000.0) * 100.0).abs() < 1e-6, "{x}");
        }
    }

    #[test]
    fn probability_maps_read_from_beside_a_read_only_dataset() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("seq");
        let mut f = frame(0);
        f.prob = None;
        write_dynapix_sequence(&dir, std::slice::from_ref(&f), None);
        let out = tmp.path().join("motion_out");
        let opts = SequenceOptions {
            prob_dir: Some(out.clone()),
            ..Default::default()
        };
        let seq = Sequence::open_with(&dir, &opts).unwrap();
        assert!(seq.load_frame(0).unwrap().prob.is_none());
        let p = ProbMap::from_pixel(6, 4, Luma([0.3]));
        std::fs::create_dir_all(&out).unwrap();
        let png = out.join(format!("{:.6}.png", f.t));
        weights::write_prob_png(&png, &p).unwrap();
        weights::write_prob_pfm(png.with_extension("pfm"), &p).unwrap();
        assert!(!dir.join("prob").exists());
        let again = Sequence::open_with(&dir, &opts).unwrap();
        assert_eq!(again.load_frame(0).unwrap().prob.unwrap(), p);
    }
}
