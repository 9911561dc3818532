//! File formats and dataset layouts for dynapix: TUM RGB-D lists and association, the
//! DynaPix and GRADE folder layouts, ORB-SLAM2 settings, trajectories and probability maps.
//! Every parser reports errors with the file and line; every writer is atomic.
//!
//! Map of the crate:
//! - [`trajectory`]: [`Trajectory`] (TUM and KITTI read/write, SLERP interpolation) and the
//!   per-frame status file ([`FrameStatus`]).
//! - [`tum`]: `rgb.txt`/`depth.txt` lists, [`associate`] (exactly like `associate.py`),
//!   4-column association files.
//! - [`depth`]: which raw depth values are measurements ([`DepthValidity`]: the sensor's
//!   saturation value and implausible depths are read as missing).
//! - [`images`]: rgb, depth (metres), masks, probability maps (reference 16-bit PNG and
//!   lossless PFM).
//! - [`settings`]: ORB-SLAM2 settings YAML, presets `tum1 tum2 tum3 grade bonn`, the camera
//!   of a sequence folder.
//! - [`datasets`]: which public dataset a folder is (TUM `rgbd_dataset_freiburgN_*`, Bonn
//!   `rgbd_bonn_*`), which decides its camera preset and ground-truth convention, and the
//!   association-file names looked for in a sequence folder.
//! - [`ground_truth`]: ground truth as camera poses ([`camera_trajectory`]; the Bonn marker
//!   poses converted), or the raw file ([`GtFrame`]).
//! - [`sequence`]: [`Sequence`] over the TUM, DynaPix and GRADE layouts, and [`FrameData`].
//! - [`weights`]: [`MotionProbability`] P and [`StaticWeights`] w = 1 − P as distinct types,
//!   with the one 16-bit codec of the reference `prob/*.png` files, and the probability
//!   files (reference PNG, lossless PFM).
//! - [`atomic`]: [`write_atomic`] (temporary file + rename) for any other writer.
//! - [`output`]: [`OutputFolder`], a command's result set written beside its output folder
//!   and swapped in as a whole.
//! - [`usage`]: CPU time and peak memory of this process (for benchmarks).

#![forbid(unsafe_code)]

pub mod atomic;
pub mod datasets;
pub mod depth;
pub mod error;
pub mod ground_truth;
pub mod images;
pub mod output;
pub mod sequence;
pub mod settings;
#[cfg(test)]
mod testutil;
mod text;
pub mod trajectory;
pub mod tum;
pub mod usage;
pub mod weights;

pub use atomic::write_atomic;
pub use datasets::Dataset;
pub use depth::{DepthLimits, DepthValidity};
pub use error::{IoError, Result};
pub use ground_truth::{
    GroundTruth, GroundTruthConvention, GtFrame, camera_trajectory, read_ground_truth,
};
pub use images::{DepthImage, Gray16Image, ProbMap};
pub use output::{OutputFolder, OutputLock};
pub use sequence::{
    FrameData, FrameInfo, FrameList, InvalidDepth, Layout, Pairing, Sequence, SequenceOptions,
};
pub use settings::{OrbSettings, Settings};
pub use trajectory::{FrameStatus, StampedPose, StampedStatus, Trajectory};
pub use tum::{Association, ListEntry, associate};
pub use weights::{MotionProbability, StaticWeights, WeightImage};
